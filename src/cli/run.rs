//! `cmsckf run`: the daemon beside the autopilot, until SIGINT or SIGTERM.

use std::path::PathBuf;

use cmsckf::config::Config;

// The arguments of `cmsckf run` (a plain comment: a doc comment here would
// replace the subcommand's own help line).
#[derive(clap::Args)]
pub struct RunArgs {
    #[arg(long, default_value = "config/default.toml")]
    config: PathBuf,
    /// Load and check the config, print where it puts its log and socket,
    /// and exit (0 when it would start, non-zero naming the field).
    #[arg(long)]
    check: bool,
}

/// Runs the daemon with the config file until a termination signal, then
/// logs its counters.
pub fn run(args: &RunArgs) -> anyhow::Result<()> {
    super::init_tracing("info");
    let cfg = Config::load(&args.config)?;
    if args.check {
        println!(
            "{}: ok (autopilot {}, feature socket {}, log {})",
            args.config.display(),
            cfg.mavlink.address,
            cfg.features.socket,
            if cfg.log.path.is_empty() {
                "off"
            } else {
                cfg.log.path.as_str()
            }
        );
        return Ok(());
    }
    let rt = tokio::runtime::Runtime::new()?;
    let summary = rt.block_on(cmsckf::daemon::run(cfg, termination()))?;
    tracing::info!(counters = ?summary.counters, "cmsckf stopped");
    Ok(())
}

/// Completes on SIGINT or SIGTERM.
async fn termination() {
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = term => {}
    }
}
