//! Converts a camera frame in distorted pixels into the estimator's
//! observations: undistorted normalised coordinates with a whitening matrix
//! (README.md §3, eq. W1), rejecting what cannot be used.

use std::collections::BTreeSet;

use nalgebra::{Matrix2, Vector2};

use cmsckf_models::camera::Camera;
use cmsckf_models::feature_wire::PixelFeature;
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

/// A feature's pixel noise: the σ its front-end sent, with the error each
/// frame adds that the front-end's σ does not hold (`camera.model_noise_px`)
/// added in quadrature, or one σ for features that come
/// without, and for all when the front-end's are not taken (README.md §3,
/// eq. W1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelNoise {
    /// For a feature without a σ of its own (`camera.pixel_noise_px`).
    pub default_px: f64,
    /// Added in quadrature to a front-end's σ (`camera.model_noise_px`);
    /// `None`: the front-end's σ is not taken (`camera.frontend_sigma`
    /// off) and every feature is weighed with `default_px`.
    pub model_px: Option<f64>,
}

impl PixelNoise {
    /// The σ (px) this feature is weighed with: `√(σ_f² + σ_model²)` if
    /// the front-end sent a usable `σ_f` (`PixelFeature::sigma_usable`),
    /// else the default.
    pub fn sigma_px(&self, f: &PixelFeature) -> f64 {
        match (f.sigma_px, self.model_px) {
            (Some(s), Some(model_px)) if PixelFeature::sigma_usable(s) => s.hypot(model_px),
            _ => self.default_px,
        }
    }
}

/// The camera model and pixel noise that normalise frames. The daemon and
/// replay run it where a frame arrives (the feature socket's task, the log
/// reader's thread), so the fusion thread receives frames ready to fuse.
#[derive(Clone, Debug)]
pub struct Normaliser {
    pub cam: Camera,
    pub noise: PixelNoise,
}

impl Normaliser {
    pub fn new(c: &CameraConfig) -> Self {
        Self {
            cam: Camera::from_config(c),
            noise: PixelNoise {
                default_px: c.pixel_noise_px,
                model_px: c.frontend_sigma.then_some(c.model_noise_px),
            },
        }
    }

    /// Normalises features into a new frame.
    pub fn frame(&self, features: &[PixelFeature]) -> NormFrame {
        let mut obs = Vec::with_capacity(features.len());
        let rejects = self.normalise_into(features.iter().copied(), &mut obs);
        NormFrame { obs, rejects }
    }

    /// [`normalise`] with this camera and noise, into a caller's buffer.
    pub fn normalise_into(
        &self,
        features: impl IntoIterator<Item = PixelFeature>,
        out: &mut Vec<NormObs>,
    ) -> FrameRejects {
        normalise(&self.cam, self.noise, features, out)
    }
}

/// Normalises features; `out` is cleared and refilled so a caller can
/// reuse its buffer.
pub fn normalise(
    cam: &Camera,
    noise: PixelNoise,
    features: impl IntoIterator<Item = PixelFeature>,
    out: &mut Vec<NormObs>,
) -> FrameRejects {
    out.clear();
    let mut rej = FrameRejects::default();
    let mut seen = BTreeSet::new();
    for f in features {
        let (id, u, v) = (f.landmark_id, f.u_px, f.v_px);
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
            W: cam.pixel_jacobian(&xn) / noise.sigma_px(&f),
        });
    }
    rej
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each feature is whitened by its own σ: the front-end's with the
    /// model's added in quadrature, or the default without one (W1).
    #[test]
    fn each_feature_is_weighed_by_its_own_sigma() {
        let mut c = CameraConfig {
            pixel_noise_px: 1.0,
            frontend_sigma: true,
            model_noise_px: 0.05,
            ..CameraConfig::default()
        };
        let n = Normaliser::new(&c);
        let (u, v) = (300.0, 200.0);
        let with = |s: Option<f64>| PixelFeature {
            sigma_px: s,
            ..PixelFeature::new(1, u, v)
        };
        let frame = n.frame(&[
            with(Some(0.12)),
            PixelFeature {
                landmark_id: 2,
                ..with(None)
            },
        ]);
        assert_eq!(frame.obs.len(), 2);
        let J = n.cam.pixel_jacobian(&frame.obs[0].xn);
        // 0.12 ⊕ 0.05 = 0.13 px.
        assert!((frame.obs[0].W - J / 0.13).norm() < 1e-9 * J.norm());
        assert!((frame.obs[1].W - J).norm() < 1e-9 * J.norm());
        // A σ that cannot weigh anything falls back to the default (the
        // socket refuses such lines; this is the filter's own guard).
        for bad in [0.0, -1.0, 1e-9, 5e3, f64::NAN, f64::INFINITY] {
            assert_eq!(n.noise.sigma_px(&with(Some(bad))), 1.0);
        }
        // The default model noise with the σ on: the least σ the socket
        // takes weighs no more than the model noise allows (0.001 ⊕ 0.01 px).
        let d = Normaliser::new(&CameraConfig {
            frontend_sigma: true,
            ..CameraConfig::default()
        });
        assert!((d.noise.sigma_px(&with(Some(0.001))) - 0.001f64.hypot(0.01)).abs() < 1e-15);
        // Off, every feature is weighed with the default.
        c.frontend_sigma = false;
        assert_eq!(Normaliser::new(&c).noise.sigma_px(&with(Some(0.12))), 1.0);
        assert!(!CameraConfig::default().frontend_sigma, "off by default");
    }
}
