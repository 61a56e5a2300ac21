//! `cmsckf log`: tools for flight logs as files. `log recover IN OUT`
//! rewrites a log that was never finished (a killed daemon, a power loss)
//! with full indexes and a summary, so that any MCAP reader opens it (see
//! [`cmsckf::io::mcap_log::recover`]).

use std::path::PathBuf;

use anyhow::Context;

// The arguments of `cmsckf log` (a plain comment: a doc comment here would
// replace the subcommand's own help line).
#[derive(clap::Args)]
pub struct LogArgs {
    #[command(subcommand)]
    cmd: LogCmd,
}

#[derive(clap::Subcommand)]
enum LogCmd {
    /// Rewrite a truncated or killed log with full indexes and a summary,
    /// keeping every complete record; report what was kept and dropped.
    Recover {
        input: PathBuf,
        output: PathBuf,
        /// Replace OUTPUT if it exists (never the input itself).
        #[arg(long)]
        force: bool,
        /// Print the report as one JSON object.
        #[arg(long)]
        json: bool,
    },
}

/// Runs `cmsckf log`.
pub fn log(args: LogArgs) -> anyhow::Result<()> {
    super::init_tracing("warn");
    match args.cmd {
        LogCmd::Recover {
            input,
            output,
            force,
            json,
        } => {
            let r = cmsckf::io::mcap_log::recover(&input, &output, force)
                .with_context(|| format!("recovering '{}'", input.display()))?;
            if json {
                println!("{}", serde_json::to_string(&r)?);
                return Ok(());
            }
            let span = match (r.first_log_time_ns, r.last_log_time_ns) {
                (Some(a), Some(b)) => format!("{:.3} s to {:.3} s of log time", a as f64 * 1e-9, b as f64 * 1e-9),
                _ => "no messages".into(),
            };
            println!(
                "{} -> {}: {}",
                input.display(),
                output.display(),
                if r.input_was_complete {
                    "the input was already complete; rewritten as it was"
                } else if r.input_was_damaged {
                    "the input was damaged: what could be read was kept"
                } else {
                    "the input was unfinished (no summary)"
                }
            );
            println!(
                "kept: {} messages ({span}) in {} chunks, {} channels, {} schemas, {} metadata records, {} attachments",
                r.messages_kept, r.chunks_kept, r.channels, r.schemas, r.metadata, r.attachments
            );
            for (topic, n) in &r.messages_by_topic {
                println!("  {topic}: {n}");
            }
            println!(
                "dropped: {} bytes of a record cut off at the end, {} damaged chunks, {} messages on undeclared channels",
                r.tail_bytes_dropped, r.chunks_dropped, r.messages_dropped_unknown_channel
            );
            println!("wrote {} bytes with indexes and a summary", r.output_bytes);
        }
    }
    Ok(())
}
