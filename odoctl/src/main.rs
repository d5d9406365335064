//! `odoctl`: the host tool of the odometry unit. See `odoctl --help` and `odoctl/README.md`.
//!
//! Parses the command line ([`odoctl::cli`]), runs the subcommand ([`odoctl::commands`]) and
//! turns its outcome into the exit code.

use std::io::Write;
use std::process::ExitCode;

use clap::Parser;
use odoctl::cli::{Cli, Cmd};
use odoctl::commands;

fn main() -> ExitCode {
    // Freed large vectors stay in the heap (see odoctl::memory): before any thread starts.
    odoctl::memory::keep_freed_memory();
    let cli = Cli::parse();
    match run(&cli.cmd) {
        Ok(code) => code,
        Err(e) => {
            let broken_pipe = e.chain().any(|c| {
                c.downcast_ref::<std::io::Error>()
                    .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
            });
            if broken_pipe {
                // The reader of our output went away (`odoctl monitor ... | head`): not an error.
                return ExitCode::SUCCESS;
            }
            let _ = std::io::stdout().flush();
            eprintln!("odoctl: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Runs one subcommand.
fn run(cmd: &Cmd) -> anyhow::Result<ExitCode> {
    match cmd {
        Cmd::Monitor(a) => commands::monitor::run(a),
        Cmd::Record(a) => commands::record::run(a),
        Cmd::Decode(a) => commands::decode::run(a),
        Cmd::Config(a) => commands::config::run(a),
        Cmd::Replay(a) => commands::replay::run(a),
        Cmd::Calibrate(a) => commands::calibrate::run(a),
        Cmd::Validate(a) => commands::validate::run(a),
        Cmd::Simulate(a) => commands::simulate::run(a),
        Cmd::Bridge(a) => commands::bridge::run(a),
        Cmd::Umbmark(a) => commands::umbmark::run(a),
        Cmd::Reference(a) => commands::reference::run(a),
        Cmd::Pool(a) => commands::pool::run(a),
    }
}
