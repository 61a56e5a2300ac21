//! Images with known motion, for the tracker's tests and benchmark: why
//! this exists is that a tracker can only be scored where the true motion
//! of every pixel is known. The texture is analytic (a sum of sinusoids and
//! blobs drawn from a seed), so an image of it under any homography `H`
//! (new pixel `u` shows texture point `H⁻¹ u`) is exact at every pixel,
//! with no resampling error, and so is each point's true position.

use cmsckf_models::camera::Camera;
use nalgebra::{Matrix3, Vector2, Vector3};

/// A small, fast, deterministic generator (SplitMix64).
#[derive(Clone, Debug)]
pub struct SplitMix(u64);

impl SplitMix {
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// An analytic texture: `128 + Σ a sin(k·x + φ) + Σ b exp(−|x − c|²/2s²)`.
#[derive(Clone, Debug)]
pub struct Texture {
    waves: Vec<(f64, f64, f64, f64)>,
    blobs: Vec<(f64, f64, f64, f64)>,
}

impl Texture {
    /// A texture over about `extent_px` square, drawn from `seed`.
    pub fn new(seed: u64, extent_px: f64) -> Self {
        let mut r = SplitMix::new(seed);
        let waves = (0..24)
            .map(|_| {
                let k = 0.05 + 0.35 * r.unit();
                let th = std::f64::consts::TAU * r.unit();
                (
                    12.0 * r.unit(),
                    k * th.cos(),
                    k * th.sin(),
                    std::f64::consts::TAU * r.unit(),
                )
            })
            .collect();
        let blobs = (0..((extent_px * extent_px) / 900.0) as usize)
            .map(|_| {
                let sign = if r.unit() < 0.5 { -1.0 } else { 1.0 };
                (
                    sign * (30.0 + 50.0 * r.unit()),
                    extent_px * (2.0 * r.unit() - 0.5),
                    extent_px * (2.0 * r.unit() - 0.5),
                    2.0 + 4.0 * r.unit(),
                )
            })
            .collect();
        Self { waves, blobs }
    }

    /// The intensity at texture point `(x, y)`.
    pub fn at(&self, x: f64, y: f64) -> f64 {
        let mut v = 128.0;
        for &(a, kx, ky, ph) in &self.waves {
            v += a * (kx * x + ky * y + ph).sin();
        }
        for &(b, cx, cy, s) in &self.blobs {
            let d2 = (x - cx).powi(2) + (y - cy).powi(2);
            if d2 < 25.0 * s * s {
                v += b * (-0.5 * d2 / (s * s)).exp();
            }
        }
        v.clamp(0.0, 255.0)
    }

    /// The `width × height` image in which pixel `u` shows texture point
    /// `H⁻¹ u` (homogeneous).
    pub fn render(&self, width: usize, height: usize, h: &Matrix3<f64>) -> crate::image::Gray {
        let hi = h.try_inverse().unwrap_or_else(Matrix3::identity);
        let mut g = crate::image::Gray::new(width, height);
        for y in 0..height {
            for x in 0..width {
                let t = hi * Vector3::new(x as f64, y as f64, 1.0);
                g.px[y * width + x] = self.at(t.x / t.z, t.y / t.z) as f32;
            }
        }
        g
    }
}

/// A camera looking at the textured ground plane `z = 0` (world frame,
/// metres; the texture is laid `px_per_m` texture units a metre): where the
/// pixel `uv` of `cam` at pose `R_W_C`, `p_C_in_W` sees the plane, through
/// the camera's own distortion. `None` when its ray misses the plane.
pub fn plane_point(cam: &Camera, R_W_C: &Matrix3<f64>, p_C_in_W: &Vector3<f64>, uv: [f64; 2]) -> Option<[f64; 2]> {
    let xn = cam.undistort(&Vector2::new(uv[0], uv[1]))?;
    let d = R_W_C * Vector3::new(xn.x, xn.y, 1.0);
    if d.z.abs() < 1e-9 {
        return None;
    }
    let t = -p_C_in_W.z / d.z;
    (t > 0.0).then(|| [p_C_in_W.x + t * d.x, p_C_in_W.y + t * d.y])
}

impl Texture {
    /// The image `cam` takes of the textured ground plane from `R_W_C`,
    /// `p_C_in_W` ([`plane_point`]): physically consistent with the camera
    /// model, distortion included, so a tracker's epipolar check applies.
    pub fn render_plane(
        &self,
        cam: &Camera,
        R_W_C: &Matrix3<f64>,
        p_C_in_W: &Vector3<f64>,
        px_per_m: f64,
    ) -> crate::image::Gray {
        let (w, h) = (cam.width_px as usize, cam.height_px as usize);
        let mut g = crate::image::Gray::new(w, h);
        for y in 0..h {
            for x in 0..w {
                if let Some(p) = plane_point(cam, R_W_C, p_C_in_W, [x as f64, y as f64]) {
                    g.px[y * w + x] = self.at(p[0] * px_per_m, p[1] * px_per_m) as f32;
                }
            }
        }
        g
    }
}

/// Where texture point `p` appears under `h`.
pub fn apply(h: &Matrix3<f64>, p: [f64; 2]) -> [f64; 2] {
    let q = h * Vector3::new(p[0], p[1], 1.0);
    [q.x / q.z, q.y / q.z]
}

/// The texture of `seed` shifted by `(dx, dy)` px, as a `width × height`
/// image.
pub fn textured(width: usize, height: usize, seed: u64, dx: f32, dy: f32) -> crate::image::Gray {
    let mut h = Matrix3::identity();
    h[(0, 2)] = f64::from(dx);
    h[(1, 2)] = f64::from(dy);
    Texture::new(seed, width.max(height) as f64).render(width, height, &h)
}
