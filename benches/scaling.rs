//! Criterion benchmarks of how the filter scales with the keyframes it holds.
//! Workloads (racetrack, seed 1, 100 features per frame, GNSS off):
//! - `mode_scaling/MODE/N`: one camera frame (the next one of the flight) in
//!   `full`, `schmidt` and `compressed` mode with N keyframes in the state,
//!   N = 10, 100 (every mode) and 1000 (compressed only: building a
//!   1000-keyframe full filter takes many minutes). N is reached by the
//!   keyframe interval: 4 s over 40 s, 0.4 s over 40 s, 0.1 s over 100 s.
//! - `global_update/N`: one forced compressed global update with N keyframes.
//!
//! `CMSCKF_BENCH_MAX_KEYFRAMES=100` skips the 1000-keyframe size (building it
//! takes longer than 8 minutes here).
//!
//! Each measured step runs on a clone of the built state, so every sample
//! sees the same filter. Run: `cargo bench --bench scaling`; results are in
//! docs/performance.md.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};

use cmsckf::config::{Config, Mode};
use cmsckf::eval::{sim_config_for, Runner};
use cmsckf_sitl::dataset::Dataset;

/// `(keyframes wanted, keyframe interval s, flight s)`.
const SIZES: [(usize, f64, f64); 3] = [(10, 4.0, 40.0), (100, 0.4, 40.0), (1000, 0.1, 100.0)];

fn flight(interval_s: f64, duration_s: f64) -> (Config, Dataset) {
    let mut cfg = Config::default();
    cfg.keyframe.interval_s = interval_s;
    cfg.keyframe.max = 1000;
    let ds = Dataset::generate("racetrack", 1, Some(duration_s + 1.0), &sim_config_for(&cfg)).expect("dataset");
    (cfg, ds)
}

/// Runs `mode` up to `duration_s`; returns the runner and the next frame.
fn built<'a>(ds: &'a Dataset, cfg: &Config, mode: Mode, duration_s: f64) -> (Runner<'a>, usize) {
    let mut run = Runner::new(ds, cfg, mode, 1);
    let mut k = 0;
    while k < ds.frames.len() && ds.frames[k].t_s < duration_s {
        run.step_frame(k);
        k += 1;
    }
    (run, k)
}

fn bench_scaling(c: &mut Criterion) {
    let mut g = c.benchmark_group("mode_scaling");
    g.sample_size(10);
    let mut gu = Vec::new();
    let max_n: usize = std::env::var("CMSCKF_BENCH_MAX_KEYFRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1000);
    for (n, interval, dur) in SIZES.into_iter().filter(|s| s.0 <= max_n) {
        let (cfg, ds) = flight(interval, dur);
        for mode in [Mode::Full, Mode::Schmidt, Mode::Compressed] {
            if n >= 1000 && mode != Mode::Compressed {
                continue;
            }
            let (run, k) = built(&ds, &cfg, mode, dur);
            let kfs = run.est.keyframes().count();
            eprintln!("{} with {kfs} keyframes", mode.name());
            g.bench_function(format!("{}/{n}", mode.name()), |b| {
                b.iter_batched(
                    || run.clone(),
                    |mut r| {
                        r.step_frame(k);
                        r
                    },
                    BatchSize::LargeInput,
                )
            });
            if mode == Mode::Compressed {
                gu.push((n, run.est.clone()));
            }
        }
    }
    g.finish();
    let mut g = c.benchmark_group("global_update");
    g.sample_size(10);
    for (n, est) in &gu {
        eprintln!("global part: {} keyframes", est.n_global_keyframes());
        g.bench_function(format!("{n}"), |b| {
            b.iter_batched(
                || est.clone(),
                |mut e| {
                    e.force_global_update();
                    e
                },
                BatchSize::LargeInput,
            )
        });
    }
    g.finish();
}

criterion_group!(benches, bench_scaling);
criterion_main!(benches);
