//! Camera geometry: pinhole projection with radial-tangential or equidistant
//! distortion, and its inverse.
//!
//! Both the simulator (which projects landmarks into distorted pixels) and the
//! estimator's input adapter (which undistorts pixels into normalised
//! coordinates) use this one implementation.

use nalgebra::{Isometry3, Matrix2, Translation3, UnitQuaternion, Vector2, Vector3};

use crate::sensors::{CameraConfig, CameraModelKind};

/// A calibrated camera with its mounting on the body.
#[derive(Clone, Debug)]
pub struct Camera {
    pub kind: CameraModelKind,
    pub width_px: f64,
    pub height_px: f64,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub dist: [f64; 4],
    /// Pose of the camera in the body frame (`T_B_C`: camera → body).
    pub T_B_C: Isometry3<f64>,
}

impl Camera {
    pub fn from_config(c: &CameraConfig) -> Self {
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            c.q_B_C_xyzw[3],
            c.q_B_C_xyzw[0],
            c.q_B_C_xyzw[1],
            c.q_B_C_xyzw[2],
        ));
        Self {
            kind: c.model,
            width_px: c.width_px as f64,
            height_px: c.height_px as f64,
            fx: c.intrinsics[0],
            fy: c.intrinsics[1],
            cx: c.intrinsics[2],
            cy: c.intrinsics[3],
            dist: c.distortion,
            T_B_C: Isometry3::from_parts(Translation3::from(Vector3::from(c.p_C_in_B_m)), q),
        }
    }

    /// Distorts normalised coordinates `(x/z, y/z)`.
    pub fn distort(&self, xn: &Vector2<f64>) -> Vector2<f64> {
        let [k1, k2, k3, k4] = self.dist;
        match self.kind {
            CameraModelKind::PinholeRadtan => {
                let (x, y) = (xn.x, xn.y);
                let r2 = x * x + y * y;
                let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
                // Here k3, k4 are the tangential p1, p2.
                let (p1, p2) = (k3, k4);
                Vector2::new(
                    x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                    y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
                )
            }
            CameraModelKind::PinholeEquidistant => {
                let r = xn.norm();
                if r < 1e-12 {
                    return *xn;
                }
                let th = r.atan();
                let t2 = th * th;
                let thd = th * (1.0 + k1 * t2 + k2 * t2 * t2 + k3 * t2 * t2 * t2 + k4 * t2 * t2 * t2 * t2);
                xn * (thd / r)
            }
        }
    }

    /// Jacobian of [`Self::distort`] with respect to the normalised point,
    /// by central differences (used only by the iterative undistortion).
    fn distort_jacobian(&self, xn: &Vector2<f64>) -> Matrix2<f64> {
        let h = 1e-7;
        let mut j = Matrix2::zeros();
        for k in 0..2 {
            let mut d = Vector2::zeros();
            d[k] = h;
            let col = (self.distort(&(xn + d)) - self.distort(&(xn - d))) / (2.0 * h);
            j.set_column(k, &col);
        }
        j
    }

    /// Pixel of a distorted normalised point.
    pub fn to_pixel(&self, xd: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(self.fx * xd.x + self.cx, self.fy * xd.y + self.cy)
    }

    /// Projects a point in the camera frame to distorted pixels. `None` when
    /// it is behind the camera or too far off-axis for the lens model.
    pub fn project(&self, p_in_C: &Vector3<f64>) -> Option<Vector2<f64>> {
        if p_in_C.z <= 1e-6 {
            return None;
        }
        let xn = Vector2::new(p_in_C.x / p_in_C.z, p_in_C.y / p_in_C.z);
        if xn.norm() > 3.0 {
            return None;
        }
        Some(self.to_pixel(&self.distort(&xn)))
    }

    pub fn in_image(&self, uv: &Vector2<f64>) -> bool {
        uv.x >= 0.0 && uv.y >= 0.0 && uv.x < self.width_px && uv.y < self.height_px
    }

    /// Inverts the distortion by Gauss–Newton; returns normalised
    /// coordinates, or `None` if the input is not finite or does not converge.
    pub fn undistort(&self, uv: &Vector2<f64>) -> Option<Vector2<f64>> {
        if !uv.x.is_finite() || !uv.y.is_finite() {
            return None;
        }
        let xd = Vector2::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy);
        let mut xn = xd;
        for _ in 0..30 {
            let e = self.distort(&xn) - xd;
            if e.norm() < 1e-13 {
                return Some(xn);
            }
            let j = self.distort_jacobian(&xn);
            let step = j.try_inverse()? * e;
            xn -= step;
            if !xn.x.is_finite() || xn.norm() > 10.0 {
                return None;
            }
        }
        ((self.distort(&xn) - xd).norm() < 1e-9).then_some(xn)
    }

    /// Jacobian of pixels with respect to normalised coordinates at `xn`
    /// (used to map pixel noise into normalised coordinates).
    pub fn pixel_jacobian(&self, xn: &Vector2<f64>) -> Matrix2<f64> {
        let j = self.distort_jacobian(xn);
        Matrix2::new(
            self.fx * j[(0, 0)],
            self.fx * j[(0, 1)],
            self.fy * j[(1, 0)],
            self.fy * j[(1, 1)],
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cams() -> Vec<Camera> {
        let mut c = CameraConfig::default();
        let a = Camera::from_config(&c);
        c.model = CameraModelKind::PinholeEquidistant;
        c.distortion = [0.01, -0.005, 0.001, -0.0002];
        vec![a, Camera::from_config(&c)]
    }

    #[test]
    fn undistort_inverts_distort() {
        for cam in cams() {
            for (x, y) in [(0.0, 0.0), (0.3, -0.2), (-0.6, 0.4), (0.7, 0.45)] {
                let xn = Vector2::new(x, y);
                let uv = cam.to_pixel(&cam.distort(&xn));
                let back = cam.undistort(&uv).unwrap();
                assert!((back - xn).norm() < 1e-10, "{:?} {xn} -> {back}", cam.kind);
            }
            assert!(cam.undistort(&Vector2::new(f64::NAN, 1.0)).is_none());
        }
    }

    #[test]
    fn forward_camera_looks_along_body_x() {
        let cam = &cams()[0];
        let axis_in_B = cam.T_B_C.rotation * Vector3::z();
        assert!((axis_in_B - Vector3::x()).norm() < 1e-12);
        let uv = cam.project(&Vector3::new(0.0, 0.0, 5.0)).unwrap();
        assert!((uv - Vector2::new(cam.cx, cam.cy)).norm() < 1e-9);
        assert!(cam.project(&Vector3::new(0.0, 0.0, -5.0)).is_none());
    }
}
