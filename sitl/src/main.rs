//! `cmsckf-sitl`: generate simulated flights (and, later, act as the mock
//! autopilot).

use std::path::PathBuf;

use anyhow::Context;
use clap::{Parser, Subcommand};
use cmsckf_sitl::config::SimConfig;
use cmsckf_sitl::dataset::Dataset;

#[derive(Parser)]
#[command(name = "cmsckf-sitl", version, about = "Simulator and mock autopilot for cmsckf")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Write a simulated flight as CSV: truth.csv, imu.csv, features.csv, gnss.csv.
    Generate {
        /// racetrack | figure8 | hover | tum:<path>
        #[arg(long, default_value = "racetrack")]
        scenario: String,
        /// Flight length (s); a TUM file defaults to its own span.
        #[arg(long)]
        duration_s: Option<f64>,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Simulator settings (TOML); defaults apply to anything left out.
        #[arg(long)]
        config: Option<PathBuf>,
    },
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Generate {
            scenario,
            duration_s,
            seed,
            out,
            config,
        } => {
            if let Some(d) = duration_s {
                anyhow::ensure!(
                    d.is_finite() && d > 0.0 && d <= 86_400.0,
                    "--duration-s {d} must be in (0, 86400]"
                );
            }
            let cfg = match config {
                Some(p) => {
                    let text = std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
                    SimConfig::from_toml(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?
                }
                None => SimConfig::new(),
            };
            let ds = Dataset::generate(&scenario, seed, duration_s, &cfg)?;
            ds.write_csv(&out)
                .with_context(|| format!("writing {}", out.display()))?;
            for line in ds.summary() {
                println!("{line}");
            }
            println!("wrote {}", out.display());
        }
    }
    Ok(())
}
