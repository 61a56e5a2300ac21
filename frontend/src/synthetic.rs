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
    /// Rectangles `(brightness, x0, y0, x1, y1)`: sharp corners, each a
    /// unique point (a blob's corner response is a ring).
    rects: Vec<(f64, f64, f64, f64, f64)>,
    /// The blobs reaching each cell of a `CELL`-unit grid (from `origin`).
    grid: Vec<Vec<u32>>,
    rect_grid: Vec<Vec<u32>>,
    grid_w: usize,
    origin: f64,
}

/// The blob grid's cell side (texture units).
const CELL: f64 = 32.0;

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
            .collect::<Vec<_>>();
        let rects = (0..((extent_px * extent_px) / 600.0) as usize)
            .map(|_| {
                let (x0, y0) = (extent_px * (2.0 * r.unit() - 0.5), extent_px * (2.0 * r.unit() - 0.5));
                let sign = if r.unit() < 0.5 { -1.0 } else { 1.0 };
                (
                    sign * (25.0 + 40.0 * r.unit()),
                    x0,
                    y0,
                    x0 + 4.0 + 10.0 * r.unit(),
                    y0 + 4.0 + 10.0 * r.unit(),
                )
            })
            .collect::<Vec<_>>();
        // Blobs reach 5 s; the grid covers where they can lie.
        let origin = -0.5 * extent_px - 40.0;
        let grid_w = ((2.0 * extent_px + 80.0) / CELL).ceil() as usize + 1;
        let mut grid = vec![Vec::new(); grid_w * grid_w];
        for (i, &(_, cx, cy, s)) in blobs.iter().enumerate() {
            let reach = 5.0 * s;
            let cell = |v: f64| (((v - origin) / CELL).floor().max(0.0) as usize).min(grid_w - 1);
            for gy in cell(cy - reach)..=cell(cy + reach) {
                for gx in cell(cx - reach)..=cell(cx + reach) {
                    grid[gy * grid_w + gx].push(i as u32);
                }
            }
        }
        let mut rect_grid = vec![Vec::new(); grid_w * grid_w];
        for (i, &(_, x0, y0, x1, y1)) in rects.iter().enumerate() {
            let cell = |v: f64| (((v - origin) / CELL).floor().max(0.0) as usize).min(grid_w - 1);
            for gy in cell(y0 - 2.0)..=cell(y1 + 2.0) {
                for gx in cell(x0 - 2.0)..=cell(x1 + 2.0) {
                    rect_grid[gy * grid_w + gx].push(i as u32);
                }
            }
        }
        Self {
            waves,
            blobs,
            rects,
            rect_grid,
            grid,
            grid_w,
            origin,
        }
    }

    /// The intensity at texture point `(x, y)`.
    pub fn at(&self, x: f64, y: f64) -> f64 {
        let mut v = 128.0;
        for &(a, kx, ky, ph) in &self.waves {
            v += a * (kx * x + ky * y + ph).sin();
        }
        let (gx, gy) = ((x - self.origin) / CELL, (y - self.origin) / CELL);
        if gx < 0.0 || gy < 0.0 || gx >= self.grid_w as f64 || gy >= self.grid_w as f64 {
            return v.clamp(0.0, 255.0);
        }
        let cell = gy as usize * self.grid_w + gx as usize;
        for &i in &self.grid[cell] {
            let (b, cx, cy, s) = self.blobs[i as usize];
            let d2 = (x - cx).powi(2) + (y - cy).powi(2);
            if d2 < 25.0 * s * s {
                v += b * (-0.5 * d2 / (s * s)).exp();
            }
        }
        // Edges blurred over three texture units (a smoothstep), as optics
        // blur them, so the images are band-limited and need no anti-aliasing.
        let ramp = |t: f64| {
            let u = (t / 3.0 + 0.5).clamp(0.0, 1.0);
            u * u * (3.0 - 2.0 * u)
        };
        for &i in &self.rect_grid[cell] {
            let (b, x0, y0, x1, y1) = self.rects[i as usize];
            let inside = ramp(x - x0) * ramp(x1 - x) * ramp(y - y0) * ramp(y1 - y);
            v += b * inside;
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
    ray_on_plane([xn.x, xn.y], R_W_C, p_C_in_W)
}

/// Where the ray through normalised coordinates `xn` of a camera at
/// `R_W_C`, `p_C_in_W` meets the plane `z = 0`: `p + t R [xn; 1]` with
/// `t = −p_z / d_z > 0`. `None` when it runs parallel or away.
fn ray_on_plane(xn: [f64; 2], R_W_C: &Matrix3<f64>, p_C_in_W: &Vector3<f64>) -> Option<[f64; 2]> {
    let d = R_W_C * Vector3::new(xn[0], xn[1], 1.0);
    if d.z.abs() < 1e-9 {
        return None;
    }
    let t = -p_C_in_W.z / d.z;
    (t > 0.0).then(|| [p_C_in_W.x + t * d.x, p_C_in_W.y + t * d.y])
}

/// Every pixel's undistorted normalised coordinates (row-major; `None`
/// where the model has no inverse): computed once per camera, so rendering
/// many frames costs a ray–plane intersection a pixel.
pub fn pixel_rays(cam: &Camera) -> Vec<Option<[f64; 2]>> {
    let (w, h) = (cam.width_px as usize, cam.height_px as usize);
    (0..w * h)
        .map(|k| {
            cam.undistort(&Vector2::new((k % w) as f64, (k / w) as f64))
                .map(|x| [x.x, x.y])
        })
        .collect()
}

impl Texture {
    /// The image `cam` takes of the textured ground plane from `R_W_C`,
    /// `p_C_in_W` ([`plane_point`]): physically consistent with the camera
    /// model, distortion included, so a tracker's epipolar check applies.
    /// `rays` is [`pixel_rays`] of the camera.
    pub fn render_plane(
        &self,
        cam: &Camera,
        rays: &[Option<[f64; 2]>],
        R_W_C: &Matrix3<f64>,
        p_C_in_W: &Vector3<f64>,
        px_per_m: f64,
    ) -> crate::image::Gray {
        let (w, h) = (cam.width_px as usize, cam.height_px as usize);
        let mut g = crate::image::Gray::new(w, h);
        for (k, ray) in rays.iter().enumerate().take(w * h) {
            let Some(xn) = ray else { continue };
            if let Some([x, y]) = ray_on_plane(*xn, R_W_C, p_C_in_W) {
                g.px[k] = self.at(x * px_per_m, y * px_per_m) as f32;
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
