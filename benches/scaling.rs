//! Criterion benchmarks of how the filter scales with the keyframes it holds.
//! Workloads (racetrack, seed 1, 100 features per frame, GNSS off):
//! - `mode_scaling/MODE/N`: one camera frame (the next one of the flight) in
//!   `full`, `schmidt` and `compressed` mode with N = 10, 100 and 1000
//!   keyframes in the state. N is reached by the keyframe interval: 4 s over
//!   40 s, 0.4 s over 40 s, 0.1 s over 100 s. The filter is built once, in
//!   compressed mode; the full and Schmidt filters are that same filter with
//!   its global part merged (`Estimator::into_mode`), so all three modes
//!   process the same frame from the same state. Compressed's frame includes
//!   whatever promotions it needs, and any rebase it starts runs inline.
//! - `global_update/N`: the rebase job alone (what the daemon's worker thread
//!   computes) for a forced rebase with N keyframes.
//!
//! `CMSCKF_BENCH_MAX_KEYFRAMES=100` skips the 1000-keyframe size.
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

/// Runs compressed mode up to `duration_s`; returns the runner and the next frame.
fn built<'a>(ds: &'a Dataset, cfg: &Config, duration_s: f64) -> (Runner<'a>, usize) {
    let mut run = Runner::new(ds, cfg, Mode::Compressed, 1);
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
        let t0 = std::time::Instant::now();
        let (run, k) = built(&ds, &cfg, dur);
        eprintln!(
            "built {} keyframes ({} global, local dimension {}) in {:.1} s",
            run.est.keyframes().count(),
            run.est.n_global_keyframes(),
            run.est.local_dim(),
            t0.elapsed().as_secs_f64()
        );
        for mode in [Mode::Full, Mode::Schmidt, Mode::Compressed] {
            let mut r = run.clone();
            if mode != Mode::Compressed {
                r.est = run.est.clone().into_mode(mode);
            }
            g.bench_function(format!("{}/{n}", mode.name()), |b| {
                b.iter_batched(
                    || r.clone(),
                    |mut r| {
                        r.step_frame(k);
                        r
                    },
                    BatchSize::LargeInput,
                )
            });
        }
        gu.push((n, run.est.clone()));
    }
    g.finish();
    let mut g = c.benchmark_group("global_update");
    g.sample_size(10);
    for (n, est) in &mut gu {
        let Some(job) = est.forced_rebase_job() else { continue };
        eprintln!("rebase job over {} global keyframes", job.n_global());
        g.bench_function(format!("{n}"), |b| b.iter(|| job.run()));
    }
    g.finish();
}

criterion_group!(benches, bench_scaling);
criterion_main!(benches);
