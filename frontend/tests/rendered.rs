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
//! Issue 22's targets are 95 % of tracks within 1 px and under 1 % of
//! re-identifications wrong. Measured (README, "Front-end"): far from both.
//! 47.5 % of 3654 tracks stay within 1 px, 68.6 % within 2 px: the steps are
//! unbiased but 0.38 px RMS across and 0.22 px down the image, so tracks
//! random-walk off their points within 10–20 frames (on the fronto-parallel
//! synthetic plane they stay within 0.05 px a step). 8 of 30
//! re-identifications land more than 3 px from their landmark. The bounds
//! below guard today's figures against regression; the targets are the
//! issue's and still open.

use std::collections::BTreeMap;

use cmsckf_frontend::image::Gray;
use cmsckf_frontend::tracker::{Tracker, TrackerParams};
use cmsckf_models::camera::Camera;
use cmsckf_sitl::config::SimConfig;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::render::Renderer;
use nalgebra::Vector3;

/// One id's truth: its first world point, the frame it was last seen, and
/// the largest reprojection error of its current run.
struct Truth {
    p_in_W: Vector3<f64>,
    last: usize,
    worst_px: f64,
    run_len: usize,
}

#[derive(Default)]
struct Score {
    runs: usize,
    good_runs: usize,
    worst: Vec<f64>,
    reid: usize,
    wrong: usize,
    on_sky: usize,
    /// Squared step errors (x, y) and their count.
    step_sq: [f64; 2],
    steps: usize,
}

impl Score {
    fn close(&mut self, t: &Truth) {
        if t.run_len >= 2 {
            self.runs += 1;
            self.worst.push(t.worst_px);
            self.good_runs += usize::from(t.worst_px <= 1.0);
        }
    }
}

#[test]
fn rendered_tracks_are_scored_against_their_world_points() {
    let mut sim = SimConfig::new();
    sim.camera.rate_hz = 20.0;
    let scen = std::env::var("XS").unwrap_or("figure8".into());
    let dur: f64 = std::env::var("XD").map_or(40.0, |v| v.parse().unwrap());
    let ds = Dataset::generate(&scen, 3, Some(dur), &sim).unwrap();
    let mut r = Renderer::for_dataset(&ds);
    let mut prm = TrackerParams::default();
    if let Some(rp) = prm.reid.as_mut() {
        if let Ok(v) = std::env::var("XA") { rp.affine_tolerance_px = v.parse().unwrap(); }
        if let Ok(v) = std::env::var("XR") { rp.ratio = v.parse().unwrap(); }
        if let Ok(v) = std::env::var("XM") { rp.min_matches = v.parse().unwrap(); }
        if let Ok(v) = std::env::var("XH") { rp.max_distance = v.parse().unwrap(); }
        if let Ok(v) = std::env::var("XE") { rp.every_frames = v.parse().unwrap(); }
    }
    let mut tracker = Tracker::new(prm, Some(Camera::from_config(&sim.camera)));
    let (mut poses, mut bytes) = (Vec::new(), Vec::new());
    let mut ids: BTreeMap<u64, Truth> = BTreeMap::new();
    let mut sc = Score::default();
    let mut prev: Option<(nalgebra::Isometry3<f64>, BTreeMap<u64, [f64; 2]>)> = None;
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
                    t.run_len += 1;
                    t.last = k;
                    // This step against the true motion of the world point.
                    if let Some((T_prev, uv_prev)) = &prev {
                        let (a, b) = (r.project(T_prev, &t.p_in_W), r.project(&T_W_C, &t.p_in_W));
                        if let (Some(a), Some(b), Some(p)) = (a, b, uv_prev.get(&feat.id)) {
                            for i in 0..2 {
                                sc.step_sq[i] += ((uv[i] - p[i]) - (b[i] - a[i])).powi(2);
                            }
                            sc.steps += 1;
                        }
                    }
                }
                Some(t) => {
                    // Back after an absence: a re-identification.
                    sc.close(t);
                    sc.reid += 1;
                    let e = err(&t.p_in_W);
                    sc.wrong += usize::from(e > 3.0);
                    t.worst_px = e;
                    t.run_len = 1;
                    t.last = k;
                }
                None => match r.surface_point(&T_W_C, uv) {
                    Some(hit) => {
                        let t = Truth {
                            p_in_W: hit.p_in_W,
                            last: k,
                            worst_px: 0.0,
                            run_len: 1,
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
    let step_rms = |i: usize| (sc.step_sq[i] / sc.steps as f64).sqrt();
    let s = tracker.stats;
    eprintln!(
        "{} frames: {} tracks, {:.1} % within 1 px of their world point all their life, {:.1} % within 2 px \
         (worst error: median {:.2}, 95th percentile {:.2} px); steps {:.2} px RMS across, {:.2} px down; \
         {} re-identified, {} of them wrong; {} features seen on the sky; detected {}, lost by Lucas–Kanade {}, \
         by RANSAC {}",
        ds.frames.len(),
        sc.runs,
        within(1.0),
        within(2.0),
        pct(0.5),
        pct(0.95),
        step_rms(0),
        step_rms(1),
        sc.reid,
        sc.wrong,
        sc.on_sky,
        s.detected,
        s.lost_klt,
        s.lost_ransac
    );
    assert!(sc.runs > 1000, "{} tracks", sc.runs);
    // Regression guards on today's figures (module docs): the targets
    // (95 %, 1 %) are not met.
    assert!(within(1.0) >= 40.0, "{:.1} % within 1 px", within(1.0));
    assert!(within(2.0) >= 60.0, "{:.1} % within 2 px", within(2.0));
    assert!(
        step_rms(0) < 0.6 && step_rms(1) < 0.35,
        "steps {:.2} / {:.2} px RMS",
        step_rms(0),
        step_rms(1)
    );
    assert!(sc.reid >= 10, "{} re-identified", sc.reid);
    assert!(
        sc.wrong * 3 <= sc.reid,
        "{} of {} re-identifications wrong",
        sc.wrong,
        sc.reid
    );
}
