//! `cmsckf replay`: re-runs the filter on a flight log's inputs (see
//! [`cmsckf::replay`]) with a progress bar on a terminal, and prints the
//! throughput.

use std::path::PathBuf;

use cmsckf::config::Config;
use cmsckf::estimator::Mode;

// The arguments of `cmsckf replay` (a plain comment: a doc comment here would
// replace the subcommand's own help line).
#[derive(clap::Args)]
pub struct ReplayArgs {
    input: PathBuf,
    #[arg(long)]
    out: PathBuf,
    /// Another mode (msckf, full, schmidt, compressed).
    #[arg(long)]
    mode: Option<String>,
    /// Another config (the log's own otherwise).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Replace OUT if it exists (never the input itself).
    #[arg(long)]
    force: bool,
    /// Print {"messages_in","estimates_out","flight_s","wall_s","realtime_factor","malformed_inputs"}.
    #[arg(long)]
    json: bool,
}

/// Runs `cmsckf replay` and prints its report (a line, or JSON).
pub fn replay(args: ReplayArgs) -> anyhow::Result<()> {
    let ReplayArgs {
        input,
        out,
        mode,
        config,
        force,
        json,
    } = args;
    super::init_tracing("warn");
    let mode = mode
        .map(|m| m.parse::<Mode>())
        .transpose()
        .map_err(anyhow::Error::msg)?;
    let cfg = config.map(|p| Config::load(&p)).transpose()?;
    // A bar with an ETA on a terminal when the log's summary gives the
    // number of inputs, else a spinner; nothing in a journal or with --json.
    let bar = super::progress_bar(None, "replaying", json);
    let mut sized = false;
    let r = cmsckf::replay::replay(&input, &out, mode, cfg, force, |n, total| {
        if let (Some(t), false) = (total, sized) {
            bar.set_length(t);
            bar.set_style(super::bar_style("replaying inputs"));
            sized = true;
        }
        bar.set_position(n);
    })?;
    bar.finish_and_clear();
    if json {
        println!("{}", serde_json::to_string(&r)?);
    } else {
        println!(
            "{} inputs, {} estimates, {:.1} s of flight in {:.2} s: {:.0}x real time -> {}",
            r.messages_in,
            r.estimates_out,
            r.flight_s,
            r.wall_s,
            r.realtime_factor,
            out.display()
        );
        if r.malformed_inputs > 0 {
            println!(
                "{} input records did not parse and were skipped (each named in a warning)",
                r.malformed_inputs
            );
        }
    }
    Ok(())
}
