//! Estimator tests on simulated flights.

use crate::config::{Config, Mode};
use crate::eval;
use cmsckf_sitl::dataset::Dataset;

fn racetrack(seed: u64, duration_s: f64) -> (Dataset, Config) {
    let cfg = Config::default();
    let ds = Dataset::generate("racetrack", seed, Some(duration_s), &eval::sim_config_for(&cfg)).unwrap();
    (ds, cfg)
}

#[test]
fn compressed_equals_full_after_every_global_update() {
    let (ds, cfg) = racetrack(1, 75.0);
    let (c, f) = eval::run_compressed_vs_full(&ds, &cfg, 1);
    let d = c.max_rel_diff_vs_full.unwrap();
    assert!(c.stats.global_updates > 10, "global updates {}", c.stats.global_updates);
    assert!(c.stats.loop_closure_updates > 0, "no loop closures");
    assert!(d <= 1e-9, "compressed differs from full by {d:e}");
    assert_eq!(c.stats.tracks_used, f.stats.tracks_used);
}

#[test]
#[ignore]
fn debug_exactness_trace() {
    let (ds, cfg) = racetrack(1, 75.0);
    let mut rc = eval::Runner::new(&ds, &cfg, Mode::Compressed, 1);
    let mut rf = eval::Runner::new(&ds, &cfg, Mode::Full, 1);
    for k in 0..ds.frames.len() {
        let (_, rep) = rc.step_frame(k);
        let (_, repf) = rf.step_frame(k);
        if rep.global_updates > 0 && k % 7 == 0 {
            let a = rc.est.snapshot();
            let b = rf.est.snapshot();
            let dx = (&a.x - &b.x).amax();
            let dm = &a.P - &b.P;
            let dp = dm.amax();
            let (mut bi, mut bj) = (0, 0);
            for i in 0..dm.nrows() {
                for j in 0..dm.ncols() {
                    if dm[(i, j)].abs() == dp {
                        bi = i;
                        bj = j;
                    }
                }
            }
            if rep.global_updates > 0 && k % 7 == 0 {
                println!(
                    "   argmax ({bi},{bj}) a {:e} b {:e} nclones {} kfs {} glob {}",
                    a.P[(bi, bj)],
                    b.P[(bi, bj)],
                    rc.est.n_clones(),
                    rc.est.keyframes().count(),
                    rc.est.n_global_keyframes()
                );
            }
            let mut cn: f64 = 0.0;
            for i in 0..dm.nrows() {
                for j in 0..dm.ncols() {
                    cn = cn.max(dm[(i, j)].abs() / (b.P[(i, i)] * b.P[(j, j)]).sqrt());
                }
            }
            println!("corrnorm {cn:.3e} psi {:.3e}", rc.est.debug_psi_max());
            println!(
                "k {k} t {:.2} glob {} lc {} tracks {} {} dx {dx:.3e} dP {dp:.3e} Pmax {:.3e} nP {}",
                ds.frames[k].t_s,
                rep.global_updates,
                rep.loop_closure_tracks,
                rep.tracks_used,
                repf.tracks_used,
                b.P.amax(),
                b.P.nrows()
            );
        }
    }
}
