//! Time per 752×480 frame of the whole tracker (pyramid, Lucas–Kanade with
//! the forward–backward check, RANSAC, top-up detection) with 150 features,
//! on a textured plane panning 3 px a frame, back and forth. One core.

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::Matrix3;

use cmsckf_frontend::synthetic::Texture;
use cmsckf_frontend::tracker::{Tracker, TrackerParams};
use cmsckf_models::camera::Camera;
use cmsckf_models::sensors::CameraConfig;

fn bench(c: &mut Criterion) {
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
    c.bench_function("tracker/752x480/150", |b| {
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

criterion_group!(benches, bench, parts);
criterion_main!(benches);
