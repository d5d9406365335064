//! Settings tests (in progress).
