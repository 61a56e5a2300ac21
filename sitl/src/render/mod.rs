//! The camera's images, rendered: why this exists is that a visual
//! front-end can only be tested, and its tracks scored, on images whose
//! every pixel has a known world point. The simulator's feature oracle
//! (`features`) skips the images; this renders them, so that
//! `cmsckf-frontend` runs in the loop exactly as it would on a drone.
//!
//! - [`world`]: the textured ground and blocks along the flown path;
//! - [`texture`]: the procedural paint, filtered by the pixel footprint.
//!
//! Each pixel's ray goes through the camera's own model (distortion
//! included, inverted once per pixel at start-up), meets the nearest
//! surface, and takes that surface's texture there. [`Renderer::surface_point`]
//! gives the same ray's world point for any pixel, which is how tracks and
//! re-identifications are scored. Noise is Gaussian per pixel; motion blur,
//! when asked for, averages sub-frames over the exposure; lens vignetting
//! and auto-exposure's frame-to-frame gain flicker are options (off by
//! default).

pub mod texture;
pub mod world;

use nalgebra::{Isometry3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::trajectory::{Trajectory, TruthSample};
use cmsckf_models::camera::Camera;
use cmsckf_models::check::{Check, FieldError, Validate};

pub use world::{Hit, World, GROUND_Z_M};

/// Farthest a block is drawn (m).
const MAX_RANGE_M: f64 = 150.0;
/// Farthest the ground is drawn before the sky takes over (m).
const GROUND_RANGE_M: f64 = 400.0;

/// `[render]`: the rendered camera's settings (used by `demo --frontend`).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RenderConfig {
    /// Pixel noise, one sigma (grey levels of 255).
    pub noise_grey: f64,
    /// Exposure time (s), over which motion blur is drawn.
    pub exposure_s: f64,
    /// Sub-frames averaged over the exposure: 1 is no motion blur.
    pub blur_samples: usize,
    /// Lens vignetting: a ray at angle θ off the optical axis keeps
    /// `cos(θ)^vignetting_cos_power` of the light (4 is a thin lens's
    /// natural fall-off; 0 is none).
    pub vignetting_cos_power: f64,
    /// Auto-exposure's frame-to-frame gain change, one sigma (a fraction:
    /// 0.02 brightens or darkens a frame by 2 %).
    pub gain_flicker: f64,
}

impl Default for RenderConfig {
    fn default() -> Self {
        Self {
            noise_grey: 2.0,
            exposure_s: 0.004,
            blur_samples: 1,
            vignetting_cos_power: 0.0,
            gain_flicker: 0.0,
        }
    }
}

impl Validate for RenderConfig {
    fn validate(&self, prefix: &str) -> Result<(), FieldError> {
        let c = Check::new(prefix);
        c.range("noise_grey", self.noise_grey, 0.0, 50.0)?;
        c.range("exposure_s", self.exposure_s, 0.0, 0.1)?;
        c.within("blur_samples", self.blur_samples as u64, 1, 16, "set 1 (no blur) to 16")?;
        c.range("vignetting_cos_power", self.vignetting_cos_power, 0.0, 8.0)?;
        c.range("gain_flicker", self.gain_flicker, 0.0, 0.5)?;
        Ok(())
    }
}

/// A unit Gaussian draw from one hash `h` (Irwin–Hall: its four 16-bit
/// uniforms summed, centred and scaled to unit variance).
fn unit_gaussian(h: u64) -> f32 {
    let s: u32 = (0..4).map(|k| ((h >> (16 * k)) & 0xFFFF) as u32).sum();
    (s as f32 / 65536.0 - 2.0) * 3f32.sqrt()
}

/// A block that may be in view, and where its corners project (normalised
/// coordinates; infinite when a corner is behind the camera).
#[derive(Clone, Copy, Debug)]
struct Candidate {
    block: usize,
    lo: [f64; 2],
    hi: [f64; 2],
}

/// Renders a camera's images of a [`World`].
pub struct Renderer {
    pub world: World,
    cam: Camera,
    cfg: RenderConfig,
    /// Each pixel's undistorted normalised coordinates (NaN where the lens
    /// model has no inverse).
    rays: Vec<[f64; 2]>,
    /// Each pixel's share of the light after vignetting.
    vignette: Vec<f32>,
    /// Bounds of `rays`, to drop blocks out of view.
    ray_lo: [f64; 2],
    ray_hi: [f64; 2],
    acc: Vec<f32>,
    cands: Vec<Candidate>,
}

impl Renderer {
    pub fn new(world: World, cam: Camera, cfg: RenderConfig) -> Self {
        let (w, h) = (cam.width_px as usize, cam.height_px as usize);
        let rays: Vec<[f64; 2]> = (0..w * h)
            .map(|k| {
                cam.undistort(&Vector2::new((k % w) as f64, (k / w) as f64))
                    .map_or([f64::NAN; 2], |x| [x.x, x.y])
            })
            .collect();
        let vignette = rays
            .iter()
            .map(|r| {
                // cos θ of the ray (x, y, 1).
                let cos = 1.0 / (1.0 + r[0] * r[0] + r[1] * r[1]).sqrt();
                if cos.is_finite() {
                    cos.powf(cfg.vignetting_cos_power) as f32
                } else {
                    1.0
                }
            })
            .collect();
        let (mut ray_lo, mut ray_hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for r in rays.iter().filter(|r| r[0].is_finite()) {
            for i in 0..2 {
                ray_lo[i] = ray_lo[i].min(r[i]);
                ray_hi[i] = ray_hi[i].max(r[i]);
            }
        }
        Self {
            world,
            cam,
            cfg,
            rays,
            vignette,
            ray_lo,
            ray_hi,
            acc: vec![0.0; w * h],
            cands: Vec::new(),
        }
    }

    /// The camera's poses over an exposure centred on `t_s`: one a blur
    /// sub-frame, evenly spread over `exposure_s` (just `t_s` without blur).
    pub fn exposure_poses(&self, traj: &Trajectory, t_s: f64, poses: &mut Vec<Isometry3<f64>>) {
        poses.clear();
        let n = self.cfg.blur_samples.max(1);
        for k in 0..n {
            let dt = if n == 1 {
                0.0
            } else {
                self.cfg.exposure_s * (k as f64 / (n - 1) as f64 - 0.5)
            };
            poses.push(self.camera_pose(&traj.sample(t_s + dt)));
        }
    }

    pub fn width(&self) -> usize {
        self.cam.width_px as usize
    }

    pub fn height(&self) -> usize {
        self.cam.height_px as usize
    }

    /// The camera's pose in the world at a body truth sample: `T_W_B T_B_C`.
    pub fn camera_pose(&self, truth: &TruthSample) -> Isometry3<f64> {
        Isometry3::from_parts(truth.p_B_in_W.into(), truth.q_W_B) * self.cam.T_B_C
    }

    /// The image exposed over `poses` (one per sub-frame; one pose is no
    /// blur), with noise drawn from `noise_seed`, into `out` (row-major,
    /// `width × height` bytes).
    pub fn render(&mut self, poses: &[Isometry3<f64>], noise_seed: u64, out: &mut Vec<u8>) {
        let n = self.rays.len();
        self.acc.iter_mut().for_each(|a| *a = 0.0);
        for T_W_C in poses {
            self.render_pose(T_W_C);
        }
        let scale = 1.0 / poses.len().max(1) as f32;
        out.clear();
        out.reserve(n);
        let mut rng = noise_seed ^ 0x6A09_E667_F3BC_C908;
        let sigma = self.cfg.noise_grey as f32;
        // The frame's gain, drawn from the same seed.
        let gain = 1.0 + self.cfg.gain_flicker as f32 * unit_gaussian(texture::mix(rng ^ 0xA54F_F53A_5F1D_36F1));
        let scale = scale * gain;
        for (a, v) in self.acc.iter().zip(&self.vignette) {
            rng = rng.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let g = unit_gaussian(texture::mix(rng));
            out.push((a * scale * v + sigma * g + 0.5).clamp(0.0, 255.0) as u8);
        }
    }

    /// Adds the view from `T_W_C` to the accumulator, its rows split over
    /// the machine's cores.
    fn render_pose(&mut self, T_W_C: &Isometry3<f64>) {
        self.cull(T_W_C);
        let R = T_W_C.rotation.to_rotation_matrix().into_inner();
        let o = T_W_C.translation.vector;
        let w = self.width();
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).clamp(1, 8);
        let mut acc = std::mem::take(&mut self.acc);
        // Rows dealt out in turn, so the sky's cheap rows and the ground's
        // dear ones are shared alike.
        let mut shares: Vec<Vec<(usize, &mut [f32])>> = (0..threads).map(|_| Vec::new()).collect();
        for (y, row) in acc.chunks_mut(w).enumerate() {
            shares[y % threads].push((y, row));
        }
        let this = &*self;
        std::thread::scope(|s| {
            for share in shares {
                s.spawn(move || {
                    for (y, row) in share {
                        for (x, a) in row.iter_mut().enumerate() {
                            *a += this.pixel(&R, &o, y * w + x) as f32;
                        }
                    }
                });
            }
        });
        self.acc = acc;
    }

    /// The grey of pixel `k` seen from a camera at rotation `R` (`R_W_C`)
    /// and position `o` (`p_C_in_W`), before noise.
    fn pixel(&self, R: &nalgebra::Matrix3<f64>, o: &Vector3<f64>, k: usize) -> f64 {
        let r = self.rays[k];
        if !r[0].is_finite() {
            return 0.0;
        }
        let d = R * Vector3::new(r[0], r[1], 1.0);
        let in_view = self
            .cands
            .iter()
            .filter(|c| r[0] >= c.lo[0] && r[0] <= c.hi[0] && r[1] >= c.lo[1] && r[1] <= c.hi[1])
            .map(|c| c.block);
        let norm = d.norm();
        match self.world.cast(o, &d, in_view) {
            Some(hit) if hit.surface != 0 || hit.t * norm < GROUND_RANGE_M => {
                let range = hit.t * norm;
                // A pixel's angle times the range; the surface's obliquity
                // stretches it per edge direction (`world::footprint`).
                let shade = self.world.shade(&hit, range / self.cam.fx, &(d / norm));
                // Haze: far surfaces fade into the horizon's grey.
                let haze = ((range - 60.0) / 300.0).clamp(0.0, 1.0);
                shade * (1.0 - haze) + 175.0 * haze
            }
            _ => sky(d.z / norm),
        }
    }

    /// Lists the blocks that may be seen from `T_W_C`, with the bounds of
    /// their projection.
    fn cull(&mut self, T_W_C: &Isometry3<f64>) {
        self.cands.clear();
        let T_C_W = T_W_C.inverse();
        let o = T_W_C.translation.vector;
        for (i, b) in self.world.blocks.iter().enumerate() {
            let centre = 0.5 * (b.min + b.max);
            if (centre - o).norm() > MAX_RANGE_M + (b.max - b.min).norm() {
                continue;
            }
            let (mut lo, mut hi, mut behind, mut front) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2], false, false);
            for c in 0..8 {
                let corner = Vector3::new(
                    if c & 1 == 0 { b.min.x } else { b.max.x },
                    if c & 2 == 0 { b.min.y } else { b.max.y },
                    if c & 4 == 0 { b.min.z } else { b.max.z },
                );
                let p = T_C_W * nalgebra::Point3::from(corner);
                if p.z < 0.05 {
                    behind = true;
                    continue;
                }
                front = true;
                for k in 0..2 {
                    lo[k] = lo[k].min(p[k] / p.z);
                    hi[k] = hi[k].max(p[k] / p.z);
                }
            }
            if !front {
                continue;
            }
            if behind {
                (lo, hi) = ([f64::NEG_INFINITY; 2], [f64::INFINITY; 2]);
            }
            if hi[0] < self.ray_lo[0] || lo[0] > self.ray_hi[0] || hi[1] < self.ray_lo[1] || lo[1] > self.ray_hi[1] {
                continue;
            }
            self.cands.push(Candidate { block: i, lo, hi });
        }
    }

    /// The true world point that pixel `uv` of the camera at `T_W_C` shows
    /// (the same ray as the rendered pixel's), or `None` for the sky.
    pub fn surface_point(&self, T_W_C: &Isometry3<f64>, uv: [f64; 2]) -> Option<Hit> {
        let xn = self.cam.undistort(&Vector2::new(uv[0], uv[1]))?;
        let d = T_W_C.rotation * Vector3::new(xn.x, xn.y, 1.0);
        let hit = self
            .world
            .cast(&T_W_C.translation.vector, &d, 0..self.world.blocks.len())?;
        (hit.surface != 0 || hit.t * d.norm() < GROUND_RANGE_M).then_some(hit)
    }

    /// Where the world point `p_in_W` appears to the camera at `T_W_C`
    /// (distorted pixels), if in front of it and in the image.
    pub fn project(&self, T_W_C: &Isometry3<f64>, p_in_W: &Vector3<f64>) -> Option<[f64; 2]> {
        let p = T_W_C.inverse_transform_point(&(*p_in_W).into());
        let uv = self.cam.project(&p.coords)?;
        self.cam.in_image(&uv).then_some([uv.x, uv.y])
    }
}

/// The sky's grey for a ray whose unit direction has NED `z` component
/// `dz` (negative upward): smooth, featureless.
fn sky(dz: f64) -> f64 {
    185.0 + 35.0 * (-dz).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests;
