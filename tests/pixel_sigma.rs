//! Features with a σ of their own, as `cmsckf-frontend` sends them
//! (docs/design.md, "Feature pipe"; estimator README W1): a loose
//! observation weighs almost nothing and costs its track nothing.
//!
//! The parallax bound of a track (five times an observation's angular σ)
//! once took the largest σ among its observations, so one observation sent
//! with σ = 1000 px turned its whole track away as "poor parallax": on a
//! replayed front-end log with each landmark's third observation so marked,
//! the tracks used fell from 2449 to 109. It now takes the σ of the track's
//! mean information.

use std::collections::HashMap;

use cmsckf::config::Config;
use cmsckf::estimator::{Mode, Reject};
use cmsckf::eval::{sim_config_for, Runner};
use cmsckf_sitl::dataset::Dataset;

/// Tracks used and turned away for poor parallax over a flight, with each
/// feature's σ from `sigma_px(landmark, its observation count so far)`.
fn fly(ds: &Dataset, cfg: &Config, mut sigma_px: impl FnMut(usize) -> Option<f64>) -> (usize, u64) {
    let mut run = Runner::new(ds, cfg, Mode::Compressed, 1);
    let mut seen: HashMap<u64, usize> = HashMap::new();
    let (mut used, mut poor) = (0, 0);
    for k in 0..ds.frames.len() {
        let (_, rep) = run.step_frame_weighted(k, |id| {
            let n = seen.entry(id).or_insert(0);
            *n += 1;
            sigma_px(*n)
        });
        used += rep.tracks_used;
        poor += rep.rejected.get(&Reject::PoorParallax).copied().unwrap_or(0);
    }
    assert_eq!(run.resets, 0);
    (used, poor)
}

#[test]
fn one_loose_observation_does_not_turn_its_track_away() {
    let mut cfg = Config::default();
    cfg.camera.frontend_sigma = true; // off by default
    let ds = Dataset::generate("racetrack", 1, Some(20.0), &sim_config_for(&cfg)).unwrap();
    // The oracle's 1 px, sent as each feature's σ (plus the model noise's
    // 0.01 px in quadrature) ...
    let (used, poor) = fly(&ds, &cfg, |_| Some(1.0));
    // ... and the same with every landmark's third observation sent as
    // weighing nothing.
    let (used_loose, poor_loose) = fly(&ds, &cfg, |n| Some(if n == 3 { 1000.0 } else { 1.0 }));
    eprintln!("tracks used {used} -> {used_loose}; poor parallax {poor} -> {poor_loose}");
    assert!(used > 500, "{used} tracks used");
    assert!(used_loose * 10 >= used * 9, "tracks used {used} -> {used_loose}");
    assert!(
        poor_loose <= poor + poor / 10 + 5,
        "poor parallax {poor} -> {poor_loose}"
    );
}
