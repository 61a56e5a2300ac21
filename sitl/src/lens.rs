//! The simulated camera's true lens: why this exists is that no real lens is
//! its calibration. A calibration's focal lengths, principal point and
//! distortion each carry an error, so a ray the daemon's model sends to a
//! pixel really lands a fraction of a pixel away, by an amount that varies
//! smoothly over the image. A simulator that renders through the exact model
//! it hands the daemon tests a filter that never meets that error; this one
//! draws, per flight, a true lens around the configured calibration
//! (`[lens]`), renders and projects through it, and hands the daemon the
//! calibration.

use nalgebra::Vector2;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use cmsckf_models::camera::Camera;
use cmsckf_models::check::{Check, FieldError, Validate};
use cmsckf_models::sensors::CameraConfig;

/// `[lens]`: one sigma of each calibrated value's error. The defaults give
/// a lens whose pixels lie 0.1–0.3 px from where its calibration puts them
/// (RMS over the image, [`reprojection_rms_px`]), the range a real
/// calibration's reprojection error reports; all zero gives the exact model.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct LensErrorConfig {
    /// Each focal length's error, one sigma (px).
    pub focal_sigma_px: f64,
    /// Each principal-point coordinate's error, one sigma (px).
    pub principal_point_sigma_px: f64,
    /// Each distortion coefficient's error, one sigma (unitless, in the
    /// camera model's own order: radtan `[k1, k2, p1, p2]`, equidistant
    /// `[k1, k2, k3, k4]`).
    pub distortion_sigma: [f64; 4],
}

impl Default for LensErrorConfig {
    fn default() -> Self {
        Self {
            focal_sigma_px: 0.15,
            principal_point_sigma_px: 0.12,
            distortion_sigma: [3e-4, 3e-4, 3e-5, 3e-5],
        }
    }
}

impl LensErrorConfig {
    /// A lens exactly as calibrated.
    pub fn exact() -> Self {
        Self {
            focal_sigma_px: 0.0,
            principal_point_sigma_px: 0.0,
            distortion_sigma: [0.0; 4],
        }
    }

    /// The true lens of one flight: `calibrated` with each intrinsic and
    /// distortion coefficient moved by a Gaussian draw of its sigma.
    pub fn draw(&self, calibrated: &CameraConfig, rng: &mut ChaCha8Rng) -> CameraConfig {
        let mut lens = calibrated.clone();
        for k in 0..4 {
            let sigma = if k < 2 {
                self.focal_sigma_px
            } else {
                self.principal_point_sigma_px
            };
            lens.intrinsics[k] += sigma * rng.sample::<f64, _>(StandardNormal);
        }
        for k in 0..4 {
            lens.distortion[k] += self.distortion_sigma[k] * rng.sample::<f64, _>(StandardNormal);
        }
        lens
    }
}

impl Validate for LensErrorConfig {
    fn validate(&self, prefix: &str) -> Result<(), FieldError> {
        let c = Check::new(prefix);
        c.range("focal_sigma_px", self.focal_sigma_px, 0.0, 50.0)?;
        c.range("principal_point_sigma_px", self.principal_point_sigma_px, 0.0, 50.0)?;
        c.all_finite("distortion_sigma", &self.distortion_sigma, 0.0, 0.1)
    }
}

/// How far the true lens puts each pixel from where the calibration does
/// (RMS over a 16 × 10 grid across the image, px): each grid pixel is taken
/// back to its ray through the calibration, and that ray projected through
/// the true lens. Grid pixels whose ray either model cannot carry are
/// skipped; `0.0` if none is left.
pub fn reprojection_rms_px(calibrated: &CameraConfig, lens: &CameraConfig) -> f64 {
    let (cal, tru) = (Camera::from_config(calibrated), Camera::from_config(lens));
    let (nu, nv) = (16, 10);
    let (mut sum_sq, mut n) = (0.0, 0usize);
    for i in 0..nu {
        for j in 0..nv {
            let uv = Vector2::new(
                (i as f64 + 0.5) * cal.width_px / nu as f64,
                (j as f64 + 0.5) * cal.height_px / nv as f64,
            );
            let Some(xn) = cal.undistort(&uv) else { continue };
            let Some(uv_true) = tru.project(&xn.push(1.0)) else {
                continue;
            };
            sum_sq += (uv_true - uv).norm_squared();
            n += 1;
        }
    }
    if n == 0 {
        0.0
    } else {
        (sum_sq / n as f64).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::rng_for;

    #[test]
    fn an_exact_lens_is_its_calibration() {
        let cal = CameraConfig::default();
        let lens = LensErrorConfig::exact().draw(&cal, &mut rng_for(1, 12));
        assert_eq!(lens, cal);
        assert!(reprojection_rms_px(&cal, &lens) < 1e-9);
    }

    #[test]
    fn the_default_lens_is_off_by_what_a_real_calibration_reports() {
        let cal = CameraConfig::default();
        let mut rms: Vec<f64> = (0..200)
            .map(|seed| reprojection_rms_px(&cal, &LensErrorConfig::default().draw(&cal, &mut rng_for(seed, 12))))
            .collect();
        rms.sort_by(f64::total_cmp);
        let (lo, median, hi) = (rms[20], rms[100], rms[180]);
        eprintln!("lens reprojection RMS over 200 draws: 10 % {lo:.3}, median {median:.3}, 90 % {hi:.3} px");
        assert!((0.1..=0.3).contains(&median), "median {median:.3} px");
        assert!(lo > 0.05 && hi < 0.5, "10 % {lo:.3}, 90 % {hi:.3} px");
    }

    #[test]
    fn a_moved_principal_point_moves_every_pixel_by_it() {
        let cal = CameraConfig::default();
        let mut lens = cal.clone();
        lens.intrinsics[2] += 0.3;
        let rms = reprojection_rms_px(&cal, &lens);
        assert!((rms - 0.3).abs() < 1e-6, "{rms}");
    }
}
