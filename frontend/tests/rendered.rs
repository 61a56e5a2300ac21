//! Track quality on the simulator's rendered images, against each pixel's
//! true world point: the figure8 (standstill, take-off, then one and a
//! third loops: 40 s at 20 Hz) over the textured ground and blocks of
//! `cmsckf_sitl::render`, with 2 grey levels of noise.
//!
//! - A track is one unbroken run of an id. It follows its world point if,
//!   over its whole life, it stays within 1 px of where that point projects
//!   (the point under the pixel its id was first seen at).
//! - A re-identification is an id back after an absence. It is wrong if its
//!   pixel is more than 3 px from where the id's first world point projects.
//! - Each frame-to-frame step of a track is also compared with the true
//!   motion of its world point.
//!
//! - Each tracked position's σ (`Feature::sigma_px`, the affine fit's
//!   covariance) is read against its error: the error over σ has a robust
//!   spread near one, and the tracks the tracker calls least precise err
//!   most (docs/frontend.md, "Pixel noise").
//!
//! Issue 22's targets are 95 % of tracks within 1 px and under 1 % of
//! re-identifications wrong; the assertions hold them. Measured (README,
//! "Front-end"): 95.9 % of 9074 tracks within 1 px (98.2 % within 2 px);
//! 12 of 1651 re-identifications wrong (0.73 %). Without the affine check
//! against each track's first window (`affine.rs`), 47.5 % of tracks stayed
//! within 1 px. A run that begins with a re-identification is scored
//! against the landmark's first world point, like any other.

// Names carry their frames (`T_W_C`, `p_in_W`), as everywhere here.
#![allow(non_snake_case)]

use std::collections::BTreeMap;

use cmsckf_frontend::image::Gray;
use cmsckf_frontend::tracker::{Tracker, TrackerParams};
use cmsckf_models::camera::Camera;
use cmsckf_sitl::config::SimConfig;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::render::Renderer;
use nalgebra::Vector3;

/// The previous frame's camera pose and its features' pixels, by id.
type PrevFrame = (nalgebra::Isometry3<f64>, BTreeMap<u64, [f64; 2]>);

/// One id's truth: its first world point, the frame it was last seen, and
/// the largest reprojection error of its current run.
struct Truth {
    p_in_W: Vector3<f64>,
    last: usize,
    worst_px: f64,
    run_len: usize,
    /// Whether the current run began with a re-identification.
    from_reid: bool,
}

#[derive(Default)]
struct Score {
    runs: usize,
    good_runs: usize,
    worst: Vec<f64>,
    reid: usize,
    wrong: usize,
    /// Runs that began with a re-identification, and those within 1 px.
    reid_runs: usize,
    reid_good_runs: usize,
    on_sky: usize,
    /// Each step's error (px): tracked motion less the true motion.
    steps: Vec<f64>,
    /// Each tracked position's error against its world point (px, along
    /// u and v) and the σ the tracker gave it; and the same for positions
    /// a re-identification put back on their landmark.
    sigma_err: Vec<(f64, f64, f64)>,
    reid_sigma_err: Vec<(f64, f64, f64)>,
}

impl Score {
    fn close(&mut self, t: &Truth) {
        if t.run_len >= 2 {
            self.runs += 1;
            self.worst.push(t.worst_px);
            self.good_runs += usize::from(t.worst_px <= 1.0);
            if t.from_reid {
                self.reid_runs += 1;
                self.reid_good_runs += usize::from(t.worst_px <= 1.0);
            }
        }
    }
}

#[test]
fn rendered_tracks_are_scored_against_their_world_points() {
    let mut sim = SimConfig::new();
    sim.camera.rate_hz = 20.0;
    let ds = Dataset::generate("figure8", 3, Some(40.0), &sim).unwrap();
    let mut r = Renderer::for_dataset(&ds);
    let prm = TrackerParams::default();
    let mut tracker = Tracker::new(prm, Some(Camera::from_config(&sim.camera)));
    let (mut poses, mut bytes) = (Vec::new(), Vec::new());
    let mut ids: BTreeMap<u64, Truth> = BTreeMap::new();
    let mut sc = Score::default();
    let mut prev: Option<PrevFrame> = None;
    for (k, f) in ds.frames.iter().enumerate() {
        r.exposure_poses(&ds.trajectory, f.t_exposure_s, &mut poses);
        r.render(&poses, k as u64, &mut bytes);
        let img = Gray::from_u8(r.width(), r.height(), &bytes).unwrap();
        let T_W_C = poses[0];
        let feats = tracker.process(&img).to_vec();
        for feat in &feats {
            let uv = [f64::from(feat.u_px), f64::from(feat.v_px)];
            let err = |p: &Vector3<f64>| {
                r.project(&T_W_C, p)
                    .map_or(f64::INFINITY, |q| (q[0] - uv[0]).hypot(q[1] - uv[1]))
            };
            match ids.get_mut(&feat.id) {
                Some(t) if t.last + 1 == k => {
                    t.worst_px = t.worst_px.max(err(&t.p_in_W));
                    if let Some(q) = r.project(&T_W_C, &t.p_in_W) {
                        if feat.sigma_px > 0.0 {
                            sc.sigma_err
                                .push((uv[0] - q[0], uv[1] - q[1], f64::from(feat.sigma_px)));
                        }
                    }
                    t.run_len += 1;
                    t.last = k;
                    // This step against the true motion of the world point.
                    if let Some((T_prev, uv_prev)) = &prev {
                        let (a, b) = (r.project(T_prev, &t.p_in_W), r.project(&T_W_C, &t.p_in_W));
                        if let (Some(a), Some(b), Some(p)) = (a, b, uv_prev.get(&feat.id)) {
                            let e = [(uv[0] - p[0]) - (b[0] - a[0]), (uv[1] - p[1]) - (b[1] - a[1])];
                            sc.steps.push(e[0].hypot(e[1]));
                        }
                    }
                }
                Some(t) => {
                    // Back after an absence: a re-identification.
                    sc.close(t);
                    sc.reid += 1;
                    let e = err(&t.p_in_W);
                    if let Some(q) = r.project(&T_W_C, &t.p_in_W) {
                        if feat.sigma_px > 0.0 && e <= 3.0 {
                            sc.reid_sigma_err
                                .push((uv[0] - q[0], uv[1] - q[1], f64::from(feat.sigma_px)));
                        }
                    }
                    sc.wrong += usize::from(e > 3.0);
                    t.worst_px = e;
                    t.run_len = 1;
                    t.last = k;
                    t.from_reid = true;
                }
                None => match r.surface_point(&T_W_C, uv) {
                    Some(hit) => {
                        let t = Truth {
                            p_in_W: hit.p_in_W,
                            last: k,
                            worst_px: 0.0,
                            run_len: 1,
                            from_reid: false,
                        };
                        ids.insert(feat.id, t);
                    }
                    None => sc.on_sky += 1,
                },
            }
        }
        let uv_now = feats
            .iter()
            .map(|f| (f.id, [f64::from(f.u_px), f64::from(f.v_px)]))
            .collect();
        prev = Some((T_W_C, uv_now));
    }
    for t in ids.values() {
        sc.close(t);
    }
    sc.worst.sort_by(f64::total_cmp);
    let pct = |q: f64| sc.worst[((sc.worst.len() - 1) as f64 * q) as usize];
    let within = |px: f64| 100.0 * sc.worst.iter().filter(|&&e| e <= px).count() as f64 / sc.runs as f64;
    sc.steps.sort_by(f64::total_cmp);
    let step = |q: f64| sc.steps[((sc.steps.len() - 1) as f64 * q) as usize];
    let s = tracker.stats;
    eprintln!(
        "{} frames: {} tracks, {:.1} % within 1 px of their world point all their life, {:.1} % within 2 px \
         (worst error: median {:.2}, 95th percentile {:.2} px); step errors median {:.3}, p90 {:.2}, p99 {:.2} px; \
         {} re-identified, {} of them wrong ({} of {} runs that began with one within 1 px); {} features seen on the sky; detected {}, lost by Lucas–Kanade {}, \
         by RANSAC {}",
        ds.frames.len(),
        sc.runs,
        within(1.0),
        within(2.0),
        pct(0.5),
        pct(0.95),
        step(0.5),
        step(0.9),
        step(0.99),
        sc.reid,
        sc.wrong,
        sc.reid_good_runs,
        sc.reid_runs,
        sc.on_sky,
        s.detected,
        s.lost_klt,
        s.lost_ransac
    );
    // The σ against the error: the robust spread of error/σ over both axes
    // (1.4826 × the median absolute value), and the error's RMS among the
    // half of positions the tracker called most precise and the tenth it
    // called least.
    let spread = |v: &[(f64, f64, f64)]| {
        let mut z: Vec<f64> = v.iter().flat_map(|&(a, b, s)| [(a / s).abs(), (b / s).abs()]).collect();
        z.sort_by(f64::total_cmp);
        1.4826 * z[z.len() / 2]
    };
    let (z_spread, reid_spread) = (spread(&sc.sigma_err), spread(&sc.reid_sigma_err));
    let mut by_sigma = sc.sigma_err.clone();
    by_sigma.sort_by(|a, b| a.2.total_cmp(&b.2));
    let rms =
        |v: &[(f64, f64, f64)]| (v.iter().map(|&(a, b, _)| a * a + b * b).sum::<f64>() / (2 * v.len()) as f64).sqrt();
    let n = by_sigma.len();
    let (precise, loose) = (rms(&by_sigma[..n / 2]), rms(&by_sigma[n - n / 10..]));
    eprintln!(
        "σ of {n} tracked positions: median {:.3} px, 90th percentile {:.3} px; error/σ robust spread {z_spread:.2}; \
         error RMS {precise:.3} px in the most precise half, {loose:.2} px in the least precise tenth; \
         {} re-identified positions (within 3 px): error/σ robust spread {reid_spread:.2}",
        by_sigma[n / 2].2,
        by_sigma[n * 9 / 10].2,
        sc.reid_sigma_err.len()
    );
    assert!(n > 20_000, "{n} positions with a σ");
    assert!((0.7..1.5).contains(&z_spread), "error/σ spread {z_spread:.2}");
    assert!(
        sc.reid_sigma_err.len() > 1000,
        "{} re-identified positions",
        sc.reid_sigma_err.len()
    );
    assert!(
        (0.5..2.0).contains(&reid_spread),
        "re-identified error/σ spread {reid_spread:.2}"
    );
    assert!(
        loose > 5.0 * precise,
        "least precise tenth {loose:.3} px, most precise half {precise:.3} px"
    );
    assert!(sc.runs > 1000, "{} tracks", sc.runs);
    assert!(within(1.0) >= 95.0, "{:.1} % within 1 px", within(1.0));
    assert!(within(2.0) >= 97.0, "{:.1} % within 2 px", within(2.0));
    assert!(
        step(0.5) < 0.1 && step(0.9) < 0.3,
        "step errors: median {:.3}, p90 {:.2} px",
        step(0.5),
        step(0.9)
    );
    assert!(sc.reid >= 1000, "{} re-identified", sc.reid);
    assert!(
        sc.wrong * 100 < sc.reid,
        "{} of {} re-identifications wrong",
        sc.wrong,
        sc.reid
    );
}
