//! The `cmsckf` command line: `evaluate` and `demo` (the daemon's `run`,
//! `replay` and `review` follow their issues).

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::{Parser, Subcommand};

use cmsckf::config::{Config, Mode};
use cmsckf::eval;

#[derive(Parser)]
#[command(name = "cmsckf", version, about = "Compressed-MSCKF visual-inertial-GNSS estimator")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run simulated flights through every mode and print the accuracy table.
    Evaluate {
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
    },
    /// Fly the racetrack and print the report. Until the daemon and the SITL
    /// autopilot land, this runs the same flight offline, in-process.
    Demo {
        #[arg(long, default_value_t = 70.0)]
        duration_s: f64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, default_value = "racetrack")]
        scenario: String,
        #[arg(long, default_value = "compressed")]
        mode: String,
        #[arg(long)]
        config: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
}

fn load_config(path: &Option<PathBuf>) -> anyhow::Result<Config> {
    Ok(match path {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    })
}

fn check_duration(d: Option<f64>) -> anyhow::Result<()> {
    if let Some(d) = d {
        if !(d.is_finite() && d > 1.0 && d <= 86_400.0) {
            bail!("--duration-s {d}: give a number of seconds in (1, 86400]");
        }
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Evaluate {
            scenario,
            modes,
            seeds,
            duration_s,
            config,
            sim_config,
            json,
            csv,
        } => {
            check_duration(duration_s)?;
            if seeds == 0 {
                bail!("--seeds must be at least 1");
            }
            let cfg = load_config(&config)?;
            let modes: Vec<Mode> = modes
                .split(',')
                .map(|m| m.trim().parse::<Mode>().map_err(anyhow::Error::msg))
                .collect::<anyhow::Result<_>>()?;
            let mut sim = eval::sim_config_for(&cfg);
            if let Some(p) = sim_config {
                let text = std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
                let over = cmsckf_sitl::config::SimConfig::from_toml(&text)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
                sim = over;
            }
            let quiet = json;
            let ev = eval::evaluate(&scenario, &modes, seeds, duration_s, &cfg, &sim, |msg| {
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
                std::fs::write(&p, s).with_context(|| format!("writing {}", p.display()))?;
            }
        }
        Cmd::Demo {
            duration_s,
            seed,
            scenario,
            mode,
            config,
            json,
        } => {
            check_duration(Some(duration_s))?;
            let cfg = load_config(&config)?;
            let mode: Mode = mode.parse().map_err(anyhow::Error::msg)?;
            let sim = eval::sim_config_for(&cfg);
            let ds = cmsckf_sitl::dataset::Dataset::generate(&scenario, seed, Some(duration_s), &sim)?;
            if !json {
                eprintln!(
                    "cmsckf demo: {scenario}, {duration_s} s, seed {seed}, mode {} (offline, in-process)",
                    mode.name()
                );
                for l in ds.summary() {
                    eprintln!("  {l}");
                }
            }
            let r = eval::run(&ds, &cfg, mode, seed);
            let s = eval::score(&r);
            let summary = eval::summarise(std::slice::from_ref(&r));
            let report = serde_json::json!({
                "scenario": scenario,
                "mode": mode.name(),
                "duration_s": ds.duration_s,
                "estimates": r.t_s.len(),
                "ate_m": s.ate.unaligned_m,
                "ate_aligned_m": s.ate.aligned_m,
                "rot_rmse_deg": s.rot_rmse_deg,
                "nees_mean": s.nees_mean,
                "keyframes": r.keyframes,
                "loop_closure_updates": r.stats.loop_closure_updates,
                "global_updates": r.stats.global_updates,
                "frame_us_mean": summary.frame_us_mean,
                "frame_us_p99": summary.frame_us_p99,
            });
            if json {
                println!("{report}");
            } else {
                println!("{}", serde_json::to_string_pretty(&report)?);
            }
        }
    }
    Ok(())
}
