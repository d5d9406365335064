//! `odoctl`: the host tool of the odometry unit (work in progress, issue 5).
fn main() {}
