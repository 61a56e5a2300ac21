//! The subcommands of the `cmsckf` binary, one module each: its arguments
//! (a `clap` struct) and the function that runs it. Binary-only: the library
//! does not see these modules.
//!
//! `evaluate` and `demo` drive the simulator, so they exist only with the
//! `sim` feature.

pub mod calib;
pub mod completions;
#[cfg(feature = "sim")]
pub mod demo;
#[cfg(feature = "sim")]
pub mod evaluate;
pub mod gnss;
pub mod log;
pub mod replay;
pub mod review;
pub mod run;

#[cfg(feature = "sim")]
use std::path::PathBuf;

#[cfg(feature = "sim")]
use anyhow::bail;

#[cfg(feature = "sim")]
use cmsckf::config::Config;

/// A progress bar with an ETA on stderr when it is a terminal, hidden
/// otherwise (a journal gets no control codes). `hidden` also hides it.
/// Without a length it is a spinner until [`bar_style`] is set on it.
fn progress_bar(len: Option<u64>, what: &str, hidden: bool) -> indicatif::ProgressBar {
    if hidden || !std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        return indicatif::ProgressBar::hidden();
    }
    match len {
        Some(n) => indicatif::ProgressBar::new(n).with_style(bar_style(what)),
        None => {
            let template = format!("{{spinner}} {what}: {{pos}} ({{per_sec}}) {{elapsed}}");
            indicatif::ProgressBar::new_spinner().with_style(
                indicatif::ProgressStyle::with_template(&template)
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
            )
        }
    }
}

/// The bar of [`progress_bar`]: position, elapsed time and ETA.
fn bar_style(what: &str) -> indicatif::ProgressStyle {
    let template = format!("{what} [{{bar:30}}] {{pos}}/{{len}} · {{elapsed}} · ETA {{eta}} · {{msg}}");
    indicatif::ProgressStyle::with_template(&template).unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
}

/// Logs to stderr, filtered by `RUST_LOG` or else by `default`.
fn init_tracing(default: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    // Colour codes only on a terminal: in a journal or a file they are noise.
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(ansi)
        .try_init();
}

/// The config at `path`, or the defaults.
#[cfg(feature = "sim")]
fn load_config(path: &Option<PathBuf>) -> anyhow::Result<Config> {
    Ok(match path {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    })
}

/// `--sim-config`: simulator settings (TOML) over `derived`, those derived
/// from the config: what the file leaves out stays as the config says (its
/// camera and IMU among them, so that the simulated sensors are the ones
/// the filter is told of unless the file says otherwise).
#[cfg(feature = "sim")]
fn load_sim_config(
    p: &std::path::Path,
    derived: &cmsckf_sitl::config::SimConfig,
) -> anyhow::Result<cmsckf_sitl::config::SimConfig> {
    use anyhow::Context;
    let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
    cmsckf_sitl::config::SimConfig::from_toml_onto(derived, &text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
}

/// Refuses a flight length outside (1, 86400] s.
#[cfg(feature = "sim")]
fn check_duration(d: Option<f64>) -> anyhow::Result<()> {
    if let Some(d) = d {
        if !(d.is_finite() && d > 1.0 && d <= 86_400.0) {
            bail!("--duration-s {d}: give a number of seconds in (1, 86400]");
        }
    }
    Ok(())
}
