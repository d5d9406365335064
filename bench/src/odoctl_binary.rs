//! The host tool the benchmarks run: `$ODOCTL`, else the `odoctl` built beside `odo-bench`.

use std::path::PathBuf;

/// The path of the `odoctl` binary to run.
pub fn odoctl() -> PathBuf {
    std::env::var_os("ODOCTL").map_or_else(
        || {
            std::env::current_exe()
                .expect("the path of odo-bench")
                .with_file_name("odoctl")
        },
        PathBuf::from,
    )
}
