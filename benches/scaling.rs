//! Criterion benchmarks of how the filter scales with the keyframes it holds.
//!
//! Workload (racetrack, seed 1, 100 features per frame, GNSS off, a keyframe
//! every 0.5 s, at most 1000): a 500 s flight builds about 950 keyframes in
//! compressed mode (956 on 2026-12-06; none is made on the ground; 3–6
//! minutes), the size called 1000 below, and a forced rebase leaves
//! `max_local_keyframes / 2` (10) of them local. The maps of 10, 100 and
//! 1000 keyframes are that one filter with its oldest global keyframes
//! marginalised (§5 G5) and the base compacted
//! by a second forced rebase: the local part (IMU, clones, the 10 local
//! keyframes and their covariance) is the same in all three, so only the
//! map's size differs.
//!
//! - `mode_scaling/MODE/N`: the mean estimator time per camera frame over
//!   the next `FRAMES` frames of the flight (IMU between them not timed),
//!   in `full`, `schmidt` and `compressed` mode with N keyframes. Full and
//!   Schmidt are the same filter with its global part merged
//!   (`Estimator::into_mode`). Compressed includes its promotions; the
//!   rebase jobs it starts are timed apart, as the daemon runs them on its
//!   worker thread (they are `global_update`).
//!   Schmidt's downdate touches the keyframes only through their
//!   cross-covariances (`O(m·n_A·n)` against full's `O(m·n²)`, README §6),
//!   so with many keyframes a Schmidt frame costs less than a full one; both
//!   share the rest of the update (`H P`, the factor, the solve) and the
//!   clone bookkeeping.
//!   The window is the first after the flight in which the largest map
//!   (1000 keyframes, or the largest under `CMSCKF_BENCH_MAX_KEYFRAMES`)
//!   promotes keyframes for its loop closures: the flight goes on, a window
//!   at a time, until one does; if none does within `SEARCH_S`, the last
//!   window searched is timed, and printed with its 0 promoted.
//!   Before timing, each filter runs the window once and prints its workload
//!   (tracks, loop-closure tracks, promotions, local dimension), so that
//!   runs and binaries can be compared on the same work.
//! - `promotion/N`: one global keyframe (the oldest) brought into the local
//!   part (§5 P1–P3) of the map of N keyframes, from its installed base,
//!   the filter cloned before each and the clone not timed (at 1000
//!   keyframes five promotions are timed by hand and printed instead, with
//!   the next keyframe's on the same clone right after: the first reads a
//!   base its caches have not seen).
//! - `global_update/N`: the rebase job alone (what the worker thread
//!   computes) for a forced rebase with N keyframes.
//!
//! `CMSCKF_BENCH_MAX_KEYFRAMES=100` skips the 1000-keyframe size;
//! `CMSCKF_BENCH_MAX_LOCAL=N` sets `compressed.max_local_keyframes` (default 20).
//! Run: `cargo bench --bench scaling`; results are in docs/performance.md.

use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};

use cmsckf::config::Config;
use cmsckf::estimator::Mode;
use cmsckf::eval::{sim_config_for, Runner};
use cmsckf_sitl::dataset::Dataset;

const SIZES: [usize; 3] = [10, 100, 1000];
/// Frames timed per sample.
const FRAMES: usize = 10;
const KEYFRAME_INTERVAL_S: f64 = 0.5;
const FLIGHT_S: f64 = 500.0;
/// How far past the flight the timed window is looked for (s).
const SEARCH_S: f64 = 60.0;

/// The flight run in compressed mode up to `flight_s`, then a global
/// update: the map every size is cut from. Returns the runner and the first
/// frame after the flight.
fn build_map<'a>(ds: &'a Dataset, cfg: &Config, flight_s: f64) -> (Runner<'a>, usize) {
    let t0 = std::time::Instant::now();
    let mut run = Runner::new(ds, cfg, Mode::Compressed, 1);
    let mut k = 0;
    while k < ds.frames.len() && ds.frames[k].t_s < flight_s {
        run.step_frame(k);
        k += 1;
    }
    run.force_global_update();
    let local = run.est.keyframes().count() - run.est.n_global_keyframes();
    eprintln!(
        "built {} keyframes ({local} local, local dimension {}) in {:.1} s",
        run.est.keyframes().count(),
        run.est.local_dim(),
        t0.elapsed().as_secs_f64()
    );
    (run, k)
}

/// The window's workload, run on `probe`: tracks, loop-closure tracks, promotions, and
/// the runner after it.
fn workload(mut probe: Runner<'_>, k: usize) -> (usize, usize, usize, Runner<'_>) {
    let (mut closures, mut promoted, mut tracks) = (0, 0, 0);
    for f in k..k + FRAMES {
        let rep = probe.step_frame(f).1;
        closures += rep.loop_closure_tracks;
        promoted += rep.promoted;
        tracks += rep.tracks_used;
    }
    (tracks, closures, promoted, probe)
}

/// The map of `n` keyframes cut from `run` (its oldest global keyframes
/// marginalised, the base compacted by a forced rebase).
fn cut_map<'a>(run: &Runner<'a>, n: usize) -> Runner<'a> {
    let mut r = run.clone();
    let local = r.est.keyframes().count() - r.est.n_global_keyframes();
    r.est.marginalise_oldest_global_keyframes(n.saturating_sub(local));
    r.force_global_update();
    r
}

/// Prints the window's workload, so that runs can be compared: tracks, loop
/// closures, promotions and the local dimension it ends with.
fn print_workload(start: &Runner, mode: Mode, n: usize, k: usize) {
    let (tracks, closures, promoted, probe) = workload(start.clone(), k);
    eprintln!(
        "{}/{n}: {FRAMES} frames, {tracks} tracks, {closures} loop-closure tracks, {promoted} promoted, local dimension {} -> {}",
        mode.name(),
        start.est.local_dim(),
        probe.est.local_dim()
    );
}

fn bench_scaling(c: &mut Criterion) {
    let max_n: usize = std::env::var("CMSCKF_BENCH_MAX_KEYFRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1000);
    let mut cfg = Config::default();
    cfg.keyframe.interval_s = KEYFRAME_INTERVAL_S;
    cfg.keyframe.max = 1000;
    if let Some(v) = std::env::var("CMSCKF_BENCH_MAX_LOCAL")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        cfg.compressed.max_local_keyframes = v;
    }
    // Only as long a flight as the largest size needs, and up to
    // `SEARCH_S` more for the window.
    let flight_s = if max_n >= 1000 { FLIGHT_S } else { FLIGHT_S / 8.0 };
    let ds =
        Dataset::generate("racetrack", 1, Some(flight_s + SEARCH_S + 2.0), &sim_config_for(&cfg)).expect("dataset");
    let (mut run, mut k) = build_map(&ds, &cfg, flight_s);
    // The timed window: the first after the flight in which the largest
    // map promotes keyframes for its loop closures, so that the sizes are
    // compared on a frame that uses the map (a 10-keyframe map has nothing
    // to promote: that is the cost the target bounds). The flight goes on
    // a window at a time until one does.
    let largest = SIZES.into_iter().filter(|&n| n <= max_n).max().unwrap_or(10);
    loop {
        let (_, closures, promoted, _) = workload(cut_map(&run, largest), k);
        if promoted > 0
            || ds
                .frames
                .get(k + 2 * FRAMES)
                .is_none_or(|f| f.t_s > flight_s + SEARCH_S)
        {
            eprintln!(
                "window: frames {k}..{} (t = {:.1} s): {promoted} promoted and {closures} loop-closure tracks at {largest} keyframes",
                k + FRAMES,
                ds.frames[k].t_s
            );
            break;
        }
        for f in k..k + FRAMES {
            run.step_frame(f);
        }
        k += FRAMES;
    }

    let mut g = c.benchmark_group("mode_scaling");
    g.sample_size(10);
    let mut gu = Vec::new();
    for n in SIZES.into_iter().filter(|&n| n <= max_n) {
        let r = cut_map(&run, n);
        eprintln!(
            "N = {n}: {} keyframes, {} global, local dimension {}",
            r.est.keyframes().count(),
            r.est.n_global_keyframes(),
            r.est.local_dim()
        );
        for mode in [Mode::Full, Mode::Schmidt, Mode::Compressed] {
            let mut start = r.clone();
            if mode != Mode::Compressed {
                start.est = r.est.clone().into_mode(mode);
            }
            print_workload(&start, mode, n, k);
            g.bench_function(format!("{}/{n}", mode.name()), |b| {
                b.iter_custom(|iters| {
                    let mut total_us = 0.0;
                    for _ in 0..iters {
                        let mut s = start.clone();
                        for f in k..k + FRAMES {
                            total_us += s.step_frame(f).0;
                        }
                    }
                    Duration::from_secs_f64(total_us / 1e6 / FRAMES as f64)
                })
            });
        }
        gu.push((n, r.est));
    }
    g.finish();
    let mut g = c.benchmark_group("promotion");
    g.sample_size(10);
    for (n, est) in &gu {
        let Some(&id) = est.global_keyframe_ids().first() else {
            continue;
        };
        eprintln!("promotion of keyframe {id} of {} global", est.n_global_keyframes());
        if *n >= 1000 {
            // Each sample would clone the 1000-keyframe filter (a 6000² base)
            // thousands of times: five promotions, timed by hand.
            // Each clone's first promotion reads a base its caches have not
            // seen; a second one, of the next keyframe, on the same clone
            // right after, is timed apart.
            let next = est.global_keyframe_ids().get(1).copied();
            let (mut us, mut us_next) = (Vec::new(), Vec::new());
            for _ in 0..5 {
                let mut e = est.clone();
                let t0 = std::time::Instant::now();
                assert!(e.promote(&[id]), "keyframe {id} promoted");
                us.push(t0.elapsed().as_secs_f64() * 1e6);
                if let Some(id2) = next {
                    let t0 = std::time::Instant::now();
                    assert!(e.promote(&[id2]), "keyframe {id2} promoted");
                    us_next.push(t0.elapsed().as_secs_f64() * 1e6);
                }
            }
            us.sort_by(f64::total_cmp);
            us_next.sort_by(f64::total_cmp);
            eprintln!(
                "promotion/{n}: median {:.1} µs of 5, the next keyframe's right after {:.1} µs (timed by hand)",
                us[2],
                us_next.get(2).copied().unwrap_or(f64::NAN)
            );
            continue;
        }
        g.bench_function(format!("{n}"), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    let mut e = est.clone();
                    let t0 = std::time::Instant::now();
                    assert!(e.promote(&[id]), "keyframe {id} promoted");
                    total += t0.elapsed();
                }
                total
            })
        });
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
