//! Text command lines from the host (work in progress).
