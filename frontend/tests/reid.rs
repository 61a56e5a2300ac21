//! Re-identification on images with known truth: a camera 3 m above a
//! textured ground plane (EuRoC cam0's model, distortion included) flies
//! out 4 m and comes back along a path 10 cm aside, turning by 8°. On the
//! way back the tracker has long lost the outbound features, so the ids
//! they get are new, unless re-identification recognises them. Every
//! re-identified feature is checked against the truth: its ground point now
//! against the one its old id was first seen at.

use std::collections::BTreeMap;

use cmsckf_frontend::synthetic::{pixel_rays, plane_point, Texture};
use cmsckf_frontend::tracker::{Tracker, TrackerParams};
use cmsckf_models::camera::Camera;
use cmsckf_models::sensors::CameraConfig;
use nalgebra::{Matrix3, Rotation3, Vector3};

/// The camera at frame `k` of 80: out along x 10 cm a frame for 40 frames,
/// then back.
fn pose(k: usize) -> (Matrix3<f64>, Vector3<f64>) {
    let down = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
    let (x, y, yaw) = if k < 40 {
        (0.1 * k as f64, 0.0, 0.0)
    } else {
        let back = (k - 40) as f64;
        (4.0 - 0.1 * back, 0.1, 8f64.to_radians() * (back / 39.0).min(1.0))
    };
    let r = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw);
    (r.matrix() * down, Vector3::new(x, y, 3.0))
}

#[test]
fn old_landmarks_are_recognised_on_the_way_back() {
    let cam = Camera::from_config(&CameraConfig::default());
    let rays = pixel_rays(&cam);
    let tex = Texture::new(9, 1500.0);
    let mut tracker = Tracker::new(TrackerParams::default(), Some(cam.clone()));
    // Each id: its ground point when first seen, the last frame seen, and
    // whether it was ever more than 3 px from it.
    let mut seen: BTreeMap<u64, ([f64; 2], usize, bool)> = BTreeMap::new();
    let (mut reappeared, mut wrong, mut missed) = (0usize, 0usize, 0usize);
    let mut outbound: Vec<[f64; 2]> = Vec::new();
    let one_px_m = 3.0 / cam.fx;
    for k in 0..80 {
        let (r, p) = pose(k);
        let img = tex.render_plane(&cam, &rays, &r, &p, 100.0);
        for f in tracker.process(&img).to_vec() {
            let g = plane_point(&cam, &r, &p, [f64::from(f.u_px), f64::from(f.v_px)]).unwrap();
            match seen.get_mut(&f.id) {
                Some((g0, last, bad)) => {
                    // An id back after an absence: a re-identification (one
                    // in the frame that lost it looks unbroken here).
                    reappeared += usize::from(*last + 1 < k);
                    // Any sighting of an id more than 3 px from its first
                    // ground point is a wrong association (a track held
                    // to its first window stays within a pixel).
                    let err = ((g[0] - g0[0]).powi(2) + (g[1] - g0[1]).powi(2)).sqrt();
                    if err > 3.0 * one_px_m && !*bad {
                        *bad = true;
                        wrong += 1;
                        eprintln!("frame {k}: id {} {:.1} px from its landmark", f.id, err / one_px_m);
                    }
                    *last = k;
                }
                None => {
                    // A new id on the way back on an outbound landmark's
                    // point: one re-identification could have made.
                    if k >= 40
                        && outbound
                            .iter()
                            .any(|o: &[f64; 2]| ((g[0] - o[0]).powi(2) + (g[1] - o[1]).powi(2)).sqrt() < 3.0 * one_px_m)
                    {
                        missed += 1;
                    }
                    if k < 40 {
                        outbound.push(g);
                    }
                    seen.insert(f.id, (g, k, false));
                }
            }
        }
    }
    let s = tracker.stats;
    eprintln!(
        "re-identified {} features; {reappeared} ids came back after an absence; {wrong} ids were ever more than \
         3 px from their landmark; {missed} new ids on the way back sit on an outbound landmark; detected {}, lost \
         by Lucas–Kanade {}, by RANSAC {}",
        s.reidentified, s.detected, s.lost_klt, s.lost_ransac
    );
    // Measured: 25 re-identified (15 after an absence), 0 ids ever more
    // than 3 px from their landmark; 60 missed. Every id that came back is one
    // re-identification; a landmark lost and found in the same frame is
    // one too, without an absence.
    assert!(s.reidentified >= 15, "{} re-identified", s.reidentified);
    assert!(reappeared as u64 <= s.reidentified, "{reappeared} > {}", s.reidentified);
    assert!(
        (wrong as f64) < 0.01 * s.reidentified as f64,
        "{wrong} wrong of {}",
        s.reidentified
    );
}
