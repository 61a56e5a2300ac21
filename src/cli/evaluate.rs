//! `cmsckf evaluate`: simulated flights through every mode, summarised as an
//! accuracy table (or JSON, or CSV). Needs the `sim` feature.

use std::path::PathBuf;

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
    /// Fly this one seed alone instead of 1..=N (a sweep's task; see
    /// --flights-out and --merge).
    #[arg(long, conflicts_with = "seeds")]
    seed: Option<u64>,
    /// Also write the flights themselves (CBOR), for --merge.
    #[arg(long)]
    flights_out: Option<PathBuf>,
    /// Fly nothing: summarise the --flights-out files (or folders of them)
    /// of seeds flown apart exactly as one evaluation over those seeds (the
    /// flight flags are then theirs, and ignored here).
    #[arg(long, num_args = 1.., conflicts_with_all = ["seed", "flights_out"])]
    merge: Vec<PathBuf>,
    /// Flight length (s); a TUM file defaults to its own span.
    #[arg(long)]
    duration_s: Option<f64>,
    /// Config file (TOML); the defaults otherwise.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Simulator settings (TOML) over those the config gives: the simulated
    /// camera and IMU are the config's unless the file names them
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
    /// Zero-velocity updates gated by the autopilot's landed state, as
    /// beside ArduPilot or PX4 (on), or by the IMU and camera alone, as
    /// beside an autopilot that reports none (off): on | off.
    #[arg(long, default_value = "on")]
    landed_state: String,
}

/// Runs `cmsckf evaluate`: checks the arguments, flies every seed in every
/// mode, then prints the table (or JSON) and writes the CSV if asked.
pub fn evaluate(args: EvaluateArgs) -> anyhow::Result<()> {
    let EvaluateArgs {
        scenario,
        modes,
        seeds,
        seed,
        flights_out,
        merge,
        duration_s,
        config,
        sim_config,
        json,
        csv,
        gnss,
        landed_state,
    } = args;
    if !merge.is_empty() {
        // What flew the seeds is in their files: the flight flags given
        // here would change nothing, so they are refused, not ignored.
        if seeds != 10 || duration_s.is_some() || config.is_some() || sim_config.is_some() || gnss != "off" {
            bail!("--merge takes the seeds' files alone: their scenario, modes, seeds, duration, config and GNSS are the ones they were flown with");
        }
        return report(&merge_files(&merge)?, json, csv);
    }
    super::check_duration(duration_s)?;
    let gnss = on_off("--gnss", &gnss)?;
    let landed_state = on_off("--landed-state", &landed_state)?;
    let seeds = match seed {
        Some(k) => eval::Seeds::One(k),
        None if seeds == 0 => bail!("--seeds must be at least 1"),
        None => eval::Seeds::UpTo(seeds),
    };
    let cfg = super::load_config(&config)?;
    let modes = parse_modes(&modes)?;
    let mut sim = eval::sim_config_for(&cfg);
    if let Some(p) = sim_config {
        sim = super::load_sim_config(&p, &sim)?;
    }
    let quiet = json;
    let spec = eval::EvalSpec {
        scenario,
        modes,
        seeds,
        duration_s,
        gnss,
        landed_state,
    };
    // On a terminal a bar with an ETA; elsewhere (a journal, a file) one
    // plain line per flight.
    let bar = super::progress_bar(Some(1), "flights", quiet);
    let on_terminal = !bar.is_hidden();
    let mut progress = |p: &eval::Progress| {
        if on_terminal {
            bar.set_length(p.total);
            bar.set_position(p.done);
            bar.set_message(p.message.clone());
        } else if !quiet {
            eprintln!("[{}/{}] {}", p.done, p.total, p.message);
        }
    };
    let ev = match (&spec.seeds, &flights_out) {
        // One seed whose flights are kept: flown once, written, then
        // summarised through the same merge that joins a sweep's seeds.
        (eval::Seeds::One(k), Some(path)) => {
            let flown = eval::fly_seed(&spec, &cfg, &sim, *k, |message| {
                progress(&eval::Progress {
                    done: 1,
                    total: 1,
                    message,
                })
            })?;
            write_flights(path, &[&flown])?;
            eval::merge(vec![flown])?
        }
        (_, Some(_)) => bail!("--flights-out needs --seed K: a sweep writes one file per seed"),
        (_, None) => eval::evaluate(&spec, &cfg, &sim, &mut progress)?,
    };
    bar.finish_and_clear();
    report(&ev, json, csv)
}

/// Prints the table (or JSON) and writes the CSV if asked.
fn report(ev: &eval::Evaluation, json: bool, csv: Option<PathBuf>) -> anyhow::Result<()> {
    if json {
        println!("{}", serde_json::to_string(ev)?);
    } else {
        print!("{}", ev.table());
    }
    if let Some(p) = csv {
        std::fs::write(&p, ev.csv()).with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}

/// `--flights-out`: the seed's flights in CBOR, which keeps every f64 (NaN
/// included) bit for bit. Written beside and renamed, so a task killed
/// mid-write leaves no half file for a merge to read.
fn write_flights(path: &std::path::Path, flown: &[&eval::SeedFlights]) -> anyhow::Result<()> {
    let part = path.with_extension("part");
    let file = std::fs::File::create(&part).with_context(|| format!("creating {}", part.display()))?;
    let mut w = std::io::BufWriter::new(file);
    ciborium::into_writer(&flown, &mut w).with_context(|| format!("writing {}", part.display()))?;
    std::io::Write::flush(&mut w).with_context(|| format!("writing {}", part.display()))?;
    drop(w);
    std::fs::rename(&part, path).with_context(|| format!("renaming {} to {}", part.display(), path.display()))
}

/// `--merge`: reads every file's seeds (a directory given: each `*.cbor`
/// in it, so that a sweep of many seeds needs no long command line) and
/// summarises them together.
fn merge_files(paths: &[PathBuf]) -> anyhow::Result<eval::Evaluation> {
    let mut files = Vec::new();
    for p in paths {
        if p.is_dir() {
            let mut inside: Vec<PathBuf> = std::fs::read_dir(p)
                .with_context(|| format!("reading the folder {}", p.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| f.extension().is_some_and(|x| x == "cbor") && f.is_file())
                .collect();
            if inside.is_empty() {
                bail!(
                    "{}: no .cbor file of `cmsckf evaluate --flights-out` in it",
                    p.display()
                );
            }
            inside.sort();
            files.extend(inside);
        } else {
            files.push(p.clone());
        }
    }
    let mut seeds = Vec::new();
    let mut from: std::collections::BTreeMap<u64, PathBuf> = Default::default();
    for p in &files {
        let bytes = std::fs::read(p).with_context(|| format!("reading {}", p.display()))?;
        let mut rest: &[u8] = &bytes;
        let flown: Vec<eval::SeedFlights> = ciborium::from_reader(&mut rest).map_err(|e| {
            anyhow::anyhow!(
                "{}: not a whole file of `cmsckf evaluate --flights-out` (truncated, or another file: {e}); fly its seed again",
                p.display()
            )
        })?;
        if !rest.is_empty() {
            bail!(
                "{}: {} bytes after its seeds (two files joined?): give each --flights-out file as it was written",
                p.display(),
                rest.len()
            );
        }
        for sf in flown {
            if let Some(other) = from.insert(sf.seed, p.clone()) {
                bail!(
                    "seed {} is in both {} and {}: a sweep keeps one result per seed",
                    sf.seed,
                    other.display(),
                    p.display()
                );
            }
            seeds.push(sf);
        }
    }
    eval::merge(seeds).map_err(|e| {
        let seed = match &e {
            eval::MergeError::Mismatch { seed, .. }
            | eval::MergeError::OtherSetup { seed }
            | eval::MergeError::Malformed { seed, .. }
            | eval::MergeError::Duplicate(seed) => Some(*seed),
            eval::MergeError::Empty => None,
        };
        match seed.and_then(|k| from.get(&k)) {
            Some(p) => anyhow::anyhow!("{e} (seed file {})", p.display()),
            None => anyhow::Error::from(e),
        }
    })
}

/// A switch `flag` given as `on` or `off`.
fn on_off(flag: &str, value: &str) -> anyhow::Result<bool> {
    Ok(match value {
        "on" => true,
        "off" => false,
        other => bail!("{flag} {other}: use on or off"),
    })
}

/// `--modes`: comma-separated mode names.
fn parse_modes(modes: &str) -> anyhow::Result<Vec<Mode>> {
    modes
        .split(',')
        .map(|m| m.trim().parse::<Mode>().map_err(anyhow::Error::msg))
        .collect::<anyhow::Result<_>>()
}
