//! Converts a camera frame in distorted pixels into the estimator's
//! observations: undistorted normalised coordinates with a whitening matrix
//! (README.md §3, eq. W1), rejecting what cannot be used.

use std::collections::BTreeSet;

use nalgebra::{Matrix2, Vector2};

use cmsckf_models::camera::Camera;
use cmsckf_models::sensors::CameraConfig;

/// One feature ready for the filter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormObs {
    pub landmark_id: u64,
    /// Undistorted normalised coordinates `(x/z, y/z)`.
    pub xn: Vector2<f64>,
    /// Whitening: `W = J_pix / σ_px`, so the noise of `W·xn` is unit.
    pub W: Matrix2<f64>,
}

/// Counts of features dropped while normalising a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameRejects {
    pub non_finite: u64,
    pub outside_image: u64,
    pub undistort_failed: u64,
    pub duplicate_id: u64,
}

/// A frame's features ready for the filter, and what normalising dropped.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NormFrame {
    pub obs: Vec<NormObs>,
    pub rejects: FrameRejects,
}

/// The camera model and pixel noise that normalise frames. The daemon and
/// replay run it where a frame arrives (the feature socket's task, the log
/// reader's thread), so the fusion thread receives frames ready to fuse.
#[derive(Clone, Debug)]
pub struct Normaliser {
    pub cam: Camera,
    pub pixel_sigma_px: f64,
}

impl Normaliser {
    pub fn new(c: &CameraConfig) -> Self {
        Self {
            cam: Camera::from_config(c),
            pixel_sigma_px: c.pixel_noise_px,
        }
    }

    /// Normalises `(landmark_id, u_px, v_px)` features into a new frame.
    pub fn frame(&self, features: &[(u64, f64, f64)]) -> NormFrame {
        let mut obs = Vec::with_capacity(features.len());
        let rejects = self.normalise_into(features.iter().copied(), &mut obs);
        NormFrame { obs, rejects }
    }

    /// [`normalise`] with this camera and noise, into a caller's buffer.
    pub fn normalise_into(
        &self,
        features: impl IntoIterator<Item = (u64, f64, f64)>,
        out: &mut Vec<NormObs>,
    ) -> FrameRejects {
        normalise(&self.cam, self.pixel_sigma_px, features, out)
    }
}

/// Normalises `(landmark_id, u_px, v_px)` features; `out` is cleared and
/// refilled so a caller can reuse its buffer.
pub fn normalise(
    cam: &Camera,
    pixel_sigma_px: f64,
    features: impl IntoIterator<Item = (u64, f64, f64)>,
    out: &mut Vec<NormObs>,
) -> FrameRejects {
    out.clear();
    let mut rej = FrameRejects::default();
    let mut seen = BTreeSet::new();
    for (id, u, v) in features {
        if !u.is_finite() || !v.is_finite() {
            rej.non_finite += 1;
            continue;
        }
        let uv = Vector2::new(u, v);
        if !cam.in_image(&uv) {
            rej.outside_image += 1;
            continue;
        }
        if !seen.insert(id) {
            rej.duplicate_id += 1;
            continue;
        }
        let Some(xn) = cam.undistort(&uv) else {
            rej.undistort_failed += 1;
            continue;
        };
        out.push(NormObs {
            landmark_id: id,
            xn,
            W: cam.pixel_jacobian(&xn) / pixel_sigma_px,
        });
    }
    rej
}
