//! The world the rendered camera sees: a textured ground plane and textured
//! blocks (buildings, containers, walls) scattered beside the flown path,
//! never on it. World frame NED (m), like the trajectories; the ground is
//! the plane `z = GROUND_Z_M`, a little below the body origin of a landed
//! vehicle, so a camera on the ground still looks over it.

use nalgebra::Vector3;

use super::texture::{Footprint, Texture};
use rand::Rng;

use crate::rng::rng_for;
use crate::trajectory::Trajectory;

/// Height of the ground in NED (m): 0.3 m below the IMU of a landed drone.
pub const GROUND_Z_M: f64 = 0.3;
/// Nearest a block's side comes to the flown path, horizontally (m).
const CLEARANCE_M: f64 = 5.0;
/// Farthest a block's centre lies from the flown path (m).
const REACH_M: f64 = 38.0;
/// Ground area per candidate block (m²).
const AREA_PER_BLOCK_M2: f64 = 260.0;

/// An axis-aligned block standing on the ground.
#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    /// Corners with the smallest and largest coordinates (NED, m): `min.z`
    /// is its top, `max.z` the ground.
    pub min: Vector3<f64>,
    pub max: Vector3<f64>,
    seed: u64,
}

/// What a ray meets first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// The world point (NED, m).
    pub p_in_W: Vector3<f64>,
    /// The surface: 0 the ground, `1 + i` block `i`.
    pub surface: u32,
    /// Ray parameter: `p = o + t d`.
    pub t: f64,
    /// Unit normal of the surface there (facing the ray).
    pub n: Vector3<f64>,
}

/// The textured world.
#[derive(Clone, Debug)]
pub struct World {
    pub blocks: Vec<Block>,
    ground: Texture,
}

impl World {
    /// A world around `traj`: blocks drawn from `seed` within `REACH_M` of
    /// the path (sampled every 0.2 s) and at least `CLEARANCE_M` from it.
    pub fn around(traj: &Trajectory, seed: u64) -> Self {
        let n = (traj.duration_s / 0.2).ceil().max(1.0) as usize;
        let path: Vec<[f64; 2]> = (0..=n)
            .map(|k| {
                let p = traj.sample((k as f64 * 0.2).min(traj.duration_s)).p_B_in_W;
                [p.x, p.y]
            })
            .collect();
        Self::around_path(&path, seed)
    }

    /// A world around a path given as horizontal points (m, north and
    /// east; closely spaced, since the clearance is kept from the points):
    /// for a flight whose trajectory is not known ahead, as beside an
    /// autopilot's SITL, whose planned route it is.
    pub fn around_path(path: &[[f64; 2]], seed: u64) -> Self {
        if path.is_empty() {
            // No route: the ground alone.
            return Self {
                blocks: Vec::new(),
                ground: Texture::new(seed),
            };
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in path {
            for i in 0..2 {
                lo[i] = lo[i].min(p[i] - REACH_M);
                hi[i] = hi[i].max(p[i] + REACH_M);
            }
        }
        let area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
        let mut r = rng_for(seed, 11);
        let mut blocks = Vec::new();
        for _ in 0..(area / AREA_PER_BLOCK_M2) as usize {
            let c = [
                lo[0] + (hi[0] - lo[0]) * r.random::<f64>(),
                lo[1] + (hi[1] - lo[1]) * r.random::<f64>(),
            ];
            let half = [1.0 + 2.5 * r.random::<f64>(), 1.0 + 2.5 * r.random::<f64>()];
            let height = 2.5 + 8.0 * r.random::<f64>();
            let tex_seed = r.random::<u64>();
            // Horizontal distance from the path to the block's sides.
            let gap = path
                .iter()
                .map(|p| {
                    let dx = ((p[0] - c[0]).abs() - half[0]).max(0.0);
                    let dy = ((p[1] - c[1]).abs() - half[1]).max(0.0);
                    dx.hypot(dy)
                })
                .fold(f64::INFINITY, f64::min);
            let centre = path
                .iter()
                .map(|p| (p[0] - c[0]).hypot(p[1] - c[1]))
                .fold(f64::INFINITY, f64::min);
            if gap < CLEARANCE_M || centre > REACH_M {
                continue;
            }
            blocks.push(Block {
                min: Vector3::new(c[0] - half[0], c[1] - half[1], GROUND_Z_M - height),
                max: Vector3::new(c[0] + half[0], c[1] + half[1], GROUND_Z_M),
                seed: tex_seed,
            });
        }
        Self {
            blocks,
            ground: Texture::new(seed),
        }
    }

    /// The ray `o + t d` (`t > 0`) against the ground and the blocks listed
    /// in `blocks` (indices): the nearest hit.
    pub fn cast(&self, o: &Vector3<f64>, d: &Vector3<f64>, blocks: impl Iterator<Item = usize>) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        if d.z > 1e-12 && o.z < GROUND_Z_M {
            let t = (GROUND_Z_M - o.z) / d.z;
            best = Some(Hit {
                p_in_W: o + d * t,
                surface: 0,
                t,
                n: -Vector3::z(),
            });
        }
        for i in blocks {
            let b = &self.blocks[i];
            if let Some((t, axis)) = slab(o, d, &b.min, &b.max) {
                if best.is_none_or(|h| t < h.t) {
                    let mut n = Vector3::zeros();
                    n[axis] = -d[axis].signum();
                    best = Some(Hit {
                        p_in_W: o + d * t,
                        surface: 1 + i as u32,
                        t,
                        n,
                    });
                }
            }
        }
        best
    }

    /// The intensity of `hit`, seen along the unit ray `d_unit` by pixels
    /// that each span `pixel_m` (m) of a surface square to the ray at the
    /// hit's range: the surface's texture in its own coordinates (world
    /// axes `(u, v)`), seen through [`footprint`], shaded by which way it
    /// faces, so a block stands out from the ground behind it.
    pub fn shade(&self, hit: &Hit, pixel_m: f64, d_unit: &Vector3<f64>) -> f64 {
        let p = &hit.p_in_W;
        if hit.surface == 0 {
            return self.ground.at(p.x, p.y, &footprint(pixel_m, d_unit, &hit.n, (0, 1)));
        }
        let b = &self.blocks[(hit.surface - 1) as usize];
        // Each face is its own texture: seed by the face's axis and side.
        let (axis, side) = (
            (0..3).find(|&k| hit.n[k] != 0.0).unwrap_or(2),
            u64::from(hit.n.sum() > 0.0),
        );
        let tex = Texture::new(b.seed ^ (axis as u64 * 2 + side + 1));
        let (u, v) = match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let light = [0.8, 1.0, 1.1][axis] * if side == 1 { 0.85 } else { 1.0 };
        (tex.at(p[u], p[v], &footprint(pixel_m, d_unit, &hit.n, (u, v))) * light).min(255.0)
    }
}

/// What one pixel covers of a surface of normal `n` whose texture runs
/// along world axes `(u, v)`, seen along the unit ray `d_unit` by pixels
/// that each span `pixel_m` (m) square to the ray.
///
/// A surface seen obliquely is foreshortened in one direction only, so an
/// edge is blurred over its two pixels across its own image line, as a
/// lens blurs it, not over the obliquity's worst case in both directions
/// (which blurred an edge along the ground many pixels wide, and slid the
/// corners it met as the camera climbed). With `J` the image's Jacobian
/// from the surface's `(u, v)`, one pixel across an edge `u = const` (its
/// image line along `J e_v`) spans `|J e_v| / |det J|` of `u`: with
/// `J ≈ (1/pixel_m) Π` (`Π` the projection square to the ray),
/// `|Π e_v| = √(1 − (e_v·d)²)` and `|det Π| = cos_in = |n·d|`, that is
/// `pixel_m · √(1 − d_v²) / cos_in`; the same with `u` and `v` swapped.
/// Detail fades over the largest footprint, `pixel_m / cos_in`.
pub(super) fn footprint(pixel_m: f64, d_unit: &Vector3<f64>, n: &Vector3<f64>, (u, v): (usize, usize)) -> Footprint {
    let fade_m = pixel_m / n.dot(d_unit).abs().max(0.05);
    let across = |along: usize| fade_m * (1.0 - d_unit[along] * d_unit[along]).max(0.0).sqrt();
    Footprint {
        fade_m,
        edge_m: [across(v), across(u)],
    }
}

/// The slab test: where the ray `o + t d` enters the box `[lo, hi]` (`t > 0`)
/// and through which axis' face. `None` if it misses or starts inside.
#[inline]
pub(super) fn slab(o: &Vector3<f64>, d: &Vector3<f64>, lo: &Vector3<f64>, hi: &Vector3<f64>) -> Option<(f64, usize)> {
    let (mut t_in, mut t_out, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
    for k in 0..3 {
        if d[k].abs() < 1e-15 {
            if o[k] < lo[k] || o[k] > hi[k] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d[k];
        let (a, b) = ((lo[k] - o[k]) * inv, (hi[k] - o[k]) * inv);
        let (near, far) = if a < b { (a, b) } else { (b, a) };
        if near > t_in {
            t_in = near;
            axis = k;
        }
        t_out = t_out.min(far);
    }
    (t_in <= t_out && t_in > 1e-9).then_some((t_in, axis))
}
