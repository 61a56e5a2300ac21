//! Time per 752×480 frame of the whole tracker (pyramid, Lucas–Kanade with
//! the forward–backward check, the first-window check, RANSAC, top-up
//! detection and re-identification), 150 features, one core.
//!
//! - `tracker/racetrack`: the headline figure. The simulator's rendered
//!   racetrack at 20 Hz (15 m/s over the textured ground and blocks), 10 s
//!   of it after the take-off, played in a loop: each pass is a lap flown
//!   again, so re-identification finds revisits and its store fills (to
//!   its bound of 1000 keyframes after about 2000 frames), as in a long flight. The conversion of
//!   each frame from 8-bit bytes is timed too, as the run loop does it.
//! - `tracker/plane`: a textured plane panning 3 px a frame, back and forth.
//! - The parts: the pyramid, and detection of 150 corners on an empty image.

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::Matrix3;

use cmsckf_frontend::image::Gray;
use cmsckf_frontend::synthetic::Texture;
use cmsckf_frontend::tracker::{Tracker, TrackerParams};
use cmsckf_models::camera::Camera;
use cmsckf_models::sensors::CameraConfig;
use cmsckf_sitl::config::SimConfig;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::render::Renderer;

/// The rendered racetrack's frames (8-bit), from `from_s` for `len_s`.
fn racetrack(from_s: f64, len_s: f64) -> (Camera, usize, usize, Vec<Vec<u8>>) {
    let mut sim = SimConfig::new();
    sim.camera.rate_hz = 20.0;
    let ds = Dataset::generate("racetrack", 1, Some(from_s + len_s), &sim).expect("the racetrack generates");
    let mut r = Renderer::for_dataset(&ds);
    let (mut poses, mut frames) = (Vec::new(), Vec::new());
    for (k, f) in ds.frames.iter().enumerate().filter(|(_, f)| f.t_exposure_s >= from_s) {
        r.exposure_poses(&ds.trajectory, f.t_exposure_s, &mut poses);
        let mut bytes = Vec::new();
        r.render(&poses, k as u64, &mut bytes);
        frames.push(bytes);
    }
    (Camera::from_config(&sim.camera), r.width(), r.height(), frames)
}

fn rendered(c: &mut Criterion) {
    let (cam, w, h, frames) = racetrack(10.0, 10.0);
    let mut tracker = Tracker::new(TrackerParams::default(), Some(cam));
    let mut img = Gray::default();
    let mut k = 0;
    c.bench_function("tracker/racetrack/752x480/150", |b| {
        b.iter(|| {
            img.set_from_u8(w, h, &frames[k % frames.len()]);
            k += 1;
            tracker.process(&img).len()
        })
    });
    let s = tracker.stats;
    eprintln!(
        "racetrack: {k} frames, {} detected, {} re-identified ({} refused by their first window), {} found again \
         where a recognised place put them, lost {} by Lucas–Kanade, {} by the first-window check, {} by its warp's stretch, {} by RANSAC",
        s.detected, s.reidentified, s.reid_refused, s.reacquired, s.lost_klt, s.lost_anchor, s.lost_warp, s.lost_ransac
    );
}

fn plane(c: &mut Criterion) {
    let (w, h) = (752, 480);
    let tex = Texture::new(11, 900.0);
    let frames: Vec<_> = (0..20)
        .map(|k| {
            let mut m = Matrix3::identity();
            m[(0, 2)] = 3.0 * k as f64;
            m[(1, 2)] = 1.5 * k as f64;
            tex.render(w, h, &m)
        })
        .collect();
    let cam = Camera::from_config(&CameraConfig::default());
    c.bench_function("tracker/plane/752x480/150", |b| {
        let mut tracker = Tracker::new(TrackerParams::default(), Some(cam.clone()));
        let mut k = 0;
        b.iter(|| {
            // Back and forth along the pan, so the motion never jumps.
            let i = k % (2 * frames.len() - 2);
            let i = if i < frames.len() { i } else { 2 * frames.len() - 2 - i };
            let n = tracker.process(&frames[i]).len();
            k += 1;
            n
        })
    });
}

/// The parts: the pyramid, and detection of 150 corners on an empty image.
fn parts(c: &mut Criterion) {
    let img = Texture::new(11, 900.0).render(752, 480, &Matrix3::identity());
    let mut pyr = cmsckf_frontend::image::Pyramid::default();
    c.bench_function("pyramid/752x480/4", |b| b.iter(|| pyr.rebuild(&img, 4)));
    let mut det = cmsckf_frontend::detect::Detector::default();
    let prm = cmsckf_frontend::detect::DetectParams::default();
    c.bench_function("detect/752x480/150", |b| {
        b.iter(|| det.detect(&img, &[], 150, &prm).len())
    });
}

criterion_group!(benches, rendered, plane, parts);
criterion_main!(benches);
