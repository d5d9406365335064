//! Command parser tests (in progress).
