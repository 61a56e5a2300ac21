//! `cmsckf evaluate`: simulated flights through every mode, summarised as an
//! accuracy table (or JSON, or CSV). Needs the `sim` feature.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use cmsckf::estimator::Mode;
use cmsckf::eval;

// The arguments of `cmsckf evaluate` (a plain comment: a doc comment here
// would replace the subcommand's own help line).
#[derive(clap::Args)]
pub struct EvaluateArgs {
    /// racetrack | figure8 | hover | tum:<path>
    #[arg(long, default_value = "racetrack")]
    scenario: String,
    /// Comma-separated modes: msckf,schmidt,full,compressed.
    #[arg(long, default_value = "msckf,schmidt,full,compressed")]
    modes: String,
    /// Seeds 1..=N.
    #[arg(long, default_value_t = 10)]
    seeds: u64,
    /// Flight length (s); a TUM file defaults to its own span.
    #[arg(long)]
    duration_s: Option<f64>,
    /// Config file (TOML); the defaults otherwise.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Simulator settings (TOML) overriding the defaults.
    #[arg(long)]
    sim_config: Option<PathBuf>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
    /// Also write the per-mode rows as CSV.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Fuse the simulated GNSS pseudoranges and range rates: on | off.
    #[arg(long, default_value = "off")]
    gnss: String,
}

/// Runs `cmsckf evaluate`: checks the arguments, flies every seed in every
/// mode, then prints the table (or JSON) and writes the CSV if asked.
pub fn evaluate(args: EvaluateArgs) -> anyhow::Result<()> {
    let EvaluateArgs {
        scenario,
        modes,
        seeds,
        duration_s,
        config,
        sim_config,
        json,
        csv,
        gnss,
    } = args;
    super::check_duration(duration_s)?;
    let gnss = gnss_switch(&gnss)?;
    if seeds == 0 {
        bail!("--seeds must be at least 1");
    }
    let cfg = super::load_config(&config)?;
    let modes = parse_modes(&modes)?;
    let mut sim = eval::sim_config_for(&cfg);
    if let Some(p) = sim_config {
        sim = load_sim_config(&p)?;
    }
    let quiet = json;
    let spec = eval::EvalSpec {
        scenario,
        modes,
        seeds,
        duration_s,
        gnss,
    };
    let ev = eval::evaluate(&spec, &cfg, &sim, |msg| {
        if !quiet {
            eprintln!("{msg}");
        }
    })?;
    if json {
        println!("{}", serde_json::to_string(&ev)?);
    } else {
        print!("{}", ev.table());
    }
    if let Some(p) = csv {
        std::fs::write(&p, csv_rows(&ev)).with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}

/// `--gnss on | off`.
fn gnss_switch(gnss: &str) -> anyhow::Result<bool> {
    Ok(match gnss {
        "on" => true,
        "off" => false,
        other => bail!("--gnss {other}: use on or off"),
    })
}

/// `--modes`: comma-separated mode names.
fn parse_modes(modes: &str) -> anyhow::Result<Vec<Mode>> {
    modes
        .split(',')
        .map(|m| m.trim().parse::<Mode>().map_err(anyhow::Error::msg))
        .collect::<anyhow::Result<_>>()
}

/// `--sim-config`: simulator settings replacing those derived from the config.
fn load_sim_config(p: &Path) -> anyhow::Result<cmsckf_sitl::config::SimConfig> {
    let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
    let over = cmsckf_sitl::config::SimConfig::from_toml(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
    Ok(over)
}

/// The CSV of `--csv`: a header and one row per mode.
fn csv_rows(ev: &eval::Evaluation) -> String {
    let mut s = String::from("mode,ate_unaligned_m,ate_aligned_m,rot_rmse_deg,nees_mean,nees_in_bounds,keyframes,loop_closure_updates,global_updates,frame_us_mean,frame_us_p99,max_rel_diff_vs_full\n");
    for (m, r) in &ev.modes {
        s += &format!(
            "{m},{},{},{},{},{},{},{},{},{},{},{}\n",
            r.ate_unaligned_m,
            r.ate_aligned_m,
            r.rot_rmse_deg,
            r.nees_mean,
            r.nees_in_bounds,
            r.keyframes,
            r.loop_closure_updates,
            r.global_updates,
            r.frame_us_mean,
            r.frame_us_p99,
            r.max_rel_diff_vs_full.map_or(String::new(), |d| d.to_string())
        );
    }
    s
}
