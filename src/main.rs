//! The `cmsckf` command line: `run` (the daemon), `replay`, `review` and
//! `log recover` (a flight log), `gnss` (an RTCM3 file), `calib` (calibration import) and,
//! with the `sim` feature, `demo` (the daemon and the SITL autopilot over
//! loopback) and `evaluate` (offline accuracy table).
//!
//! This file only declares the subcommands and dispatches to them: each one's
//! arguments and work live in a module of [`cli`].

mod cli;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "cmsckf", version = env!("CMSCKF_BUILD"), about = "Compressed-MSCKF visual-inertial-GNSS estimator")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run simulated flights through every mode and print the accuracy table.
    #[cfg(feature = "sim")]
    Evaluate(cli::evaluate::EvaluateArgs),
    /// Import a calibration: `import-kalibr` prints config sections from Kalibr's files.
    Calib(cli::calib::CalibArgs),
    /// Print a shell completion script: bash, zsh, fish, elvish or powershell.
    Completions(cli::completions::CompletionsArgs),
    /// Decode a recorded RTCM3 file and print one single-point solution per epoch.
    Gnss(cli::gnss::GnssArgs),
    /// Flight-log files: `recover` rewrites an unfinished (killed) log with indexes and a summary.
    Log(cli::log::LogArgs),
    /// Re-run the filter on a flight log's inputs and write a new log.
    Replay(cli::replay::ReplayArgs),
    /// Summarise a flight log, draw its plots, export its trajectory.
    Review(cli::review::ReviewArgs),
    /// Run the daemon beside the autopilot until SIGINT or SIGTERM.
    Run(cli::run::RunArgs),
    /// Start the daemon and the SITL autopilot over real loopback UDP and a
    /// real Unix socket, fly the scenario, and print the SITL report.
    #[cfg(feature = "sim")]
    Demo(cli::demo::DemoArgs),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.cmd {
        #[cfg(feature = "sim")]
        Cmd::Evaluate(args) => cli::evaluate::evaluate(args)?,
        Cmd::Calib(args) => cli::calib::calib(&args)?,
        Cmd::Completions(args) => cli::completions::completions::<Cli>(&args),
        Cmd::Gnss(args) => cli::gnss::gnss(&args)?,
        Cmd::Log(args) => cli::log::log(args)?,
        Cmd::Replay(args) => cli::replay::replay(args)?,
        Cmd::Review(args) => cli::review::review(args)?,
        Cmd::Run(args) => cli::run::run(&args)?,
        #[cfg(feature = "sim")]
        Cmd::Demo(args) => cli::demo::demo(args)?,
    }
    Ok(())
}
