//! The surfaces' paint: a procedural texture in metres, the same wherever
//! and whenever it is looked at, so a place flown again looks the same and a
//! tracker can re-identify it. It is a function, not an image: nothing is
//! stored, nothing repeats, and any point of any surface is exact.
//!
//! Intensity at surface point `(x, y)` (m), seen with a pixel footprint `f`
//! (m, the surface length one pixel covers; `Footprint`: its largest for
//! the fades, and across each edge for its blur):
//!
//! `I = 112 + Σ_o a_o w(f, c_o) (2 n_o(x/c_o, y/c_o) − 1) + Σ_l b_l w(f, s_l) R_l(x, y; f)`
//!
//! - `n_o`: value noise on a lattice of cell `c_o` (smooth-step blended);
//! - `R_l`: at most one rectangle per cell of layer `l` (its place, size and
//!   brightness `b_l` hashed from the cell), its edges blurred over the
//!   footprint, so each corner is a sharp, unique world point;
//! - `w(f, c)`: fades a detail out as the footprint grows past a quarter of
//!   its size, as a camera's pixels average it away. Without it, far
//!   surfaces would alias into noise that no real camera sees.

/// Width of a rectangle's edge, in pixel footprints: a camera's optics and
/// pixels blur an edge over about two pixels. Sharper edges alias: their
/// sampled grey no longer moves smoothly with the edge, and sub-pixel
/// tracking inherits a bias of tenths of a pixel.
const EDGE_FOOTPRINTS: f64 = 2.0;
/// Value-noise octaves: (cell m, amplitude grey levels).
const OCTAVES: [(f64, f64); 1] = [(1.4, 36.0)];
/// Rectangle layers: (cell m, fill probability, offset of the grid m,
/// contrast). The finer three are what a camera a few decimetres above the
/// ground tracks (a landed drone's, or one lifting off): real ground has
/// detail at every scale. Without them (the coarsest cells 0.9 m, the edges
/// blurred over at least 2 cm) the view from 0.3 m held four or five
/// blurred rectangles, and a take-off's first tracks were on far blocks
/// only, which hid a lift-off failure (the estimator README's §3c, Z0).
const RECT_LAYERS: [(f64, f64, f64, f64); 5] = [
    (1.3, 0.6, 0.0, 1.0),
    (0.9, 0.45, 0.41, 1.0),
    (0.45, 0.4, 0.17, 0.8),
    (0.2, 0.4, 0.07, 0.7),
    (0.09, 0.4, 0.031, 0.6),
];

/// What one pixel covers of a surface (m): over all directions, the
/// largest (`fade_m`, which fades detail out), and across each edge
/// direction (`edge_m[0]` across an edge of constant `x`, `edge_m[1]`
/// across one of constant `y`), which blurs the edges.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    pub fade_m: f64,
    pub edge_m: [f64; 2],
}

impl Footprint {
    /// A pixel square to the surface: `f_m` in every direction.
    pub fn square(f_m: f64) -> Self {
        Self {
            fade_m: f_m,
            edge_m: [f_m; 2],
        }
    }
}

/// A texture, drawn from a seed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Texture {
    seed: u64,
}

/// SplitMix64's finaliser: a well-mixed 64-bit hash.
#[inline]
pub(super) fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The hash of lattice cell `(ix, iy)` under `seed`.
#[inline]
fn cell_hash(seed: u64, ix: i64, iy: i64) -> u64 {
    mix(seed ^ (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F))
}

/// Bits `k·16 ..` of `h` as a number in `[0, 1)`.
#[inline]
fn unit(h: u64, k: u32) -> f64 {
    ((h >> (16 * k)) & 0xFFFF) as f64 / 65536.0
}

/// `x.floor()` as an integer, without a call into libm (the default target
/// has no rounding instruction, and this runs several times a pixel).
#[inline]
fn floor_i(x: f64) -> i64 {
    let i = x as i64;
    i - i64::from((i as f64) > x)
}

#[inline]
fn smoothstep(t: f64) -> f64 {
    let u = t.clamp(0.0, 1.0);
    u * u * (3.0 - 2.0 * u)
}

/// How much of a detail of size `size_m` survives a pixel footprint
/// `footprint_m`: 1 below a quarter of its size, 0 above a half.
#[inline]
fn survives(footprint_m: f64, size_m: f64) -> f64 {
    1.0 - smoothstep((footprint_m / size_m - 0.25) * 4.0)
}

impl Texture {
    pub fn new(seed: u64) -> Self {
        Self {
            seed: mix(seed.wrapping_add(0x5EED)),
        }
    }

    /// Value noise in `[0, 1]` at lattice coordinates `(x, y)`.
    #[inline]
    fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
        let (ix, iy) = (floor_i(x), floor_i(y));
        let (tx, ty) = (smoothstep(x - ix as f64), smoothstep(y - iy as f64));
        let v = |dx: i64, dy: i64| unit(cell_hash(seed, ix + dx, iy + dy), 0);
        let top = v(0, 0) + (v(1, 0) - v(0, 0)) * tx;
        let bottom = v(0, 1) + (v(1, 1) - v(0, 1)) * tx;
        top + (bottom - top) * ty
    }

    /// The intensity (grey levels, 0–255) at surface point `(x_m, y_m)`
    /// seen with footprint `fp` (module docs). This runs for every
    /// pixel: it divides only once.
    pub fn at(&self, x_m: f64, y_m: f64, fp: &Footprint) -> f64 {
        let footprint_m = fp.fade_m;
        let [fx_m, fy_m] = fp.edge_m;
        let mut v = 112.0;
        for (o, &(cell, amp)) in OCTAVES.iter().enumerate() {
            let w = survives(footprint_m, 2.0 * cell);
            if w > 0.0 {
                let inv = 1.0 / cell;
                let n = Self::value_noise(self.seed.wrapping_add(o as u64), x_m * inv, y_m * inv);
                v += amp * w * (2.0 * n - 1.0);
            }
        }
        // Edges are blurred over EDGE_FOOTPRINTS footprints across them, and
        // at least 4 mm (a tenth of the finest rectangle's shortest side):
        // the image is band-limited and needs no anti-aliasing.
        let inv_edge_x = 1.0 / (EDGE_FOOTPRINTS * fx_m).max(0.004);
        let inv_edge_y = 1.0 / (EDGE_FOOTPRINTS * fy_m).max(0.004);
        for (l, &(cell, fill, offset, contrast)) in RECT_LAYERS.iter().enumerate() {
            // A rectangle under a footprint fades by itself (its blurred
            // edges meet); whole layers drop out once a footprint outgrows
            // their cells, to spare the work.
            let keep = survives(footprint_m, 2.0 * cell);
            if keep <= 0.0 {
                continue;
            }
            let inv_cell = 1.0 / cell;
            let (ix, iy) = (floor_i((x_m + offset) * inv_cell), floor_i((y_m + offset) * inv_cell));
            let h = cell_hash(self.seed ^ (0xA5A5 + l as u64), ix, iy);
            if unit(h, 0) >= fill {
                continue;
            }
            // Sides 25–75 % of the cell, placed inside it.
            let (w_m, h_m) = (cell * (0.25 + 0.5 * unit(h, 1)), cell * (0.25 + 0.5 * unit(h, 2)));
            let pos = unit(h, 3);
            let x0 = ix as f64 * cell - offset + (cell - w_m) * pos;
            let y0 = iy as f64 * cell - offset + (cell - h_m) * (1.0 - pos);
            // Signed distances inside each edge, in footprints.
            let d = [
                (x_m - x0) * inv_edge_x,
                (x0 + w_m - x_m) * inv_edge_x,
                (y_m - y0) * inv_edge_y,
                (y0 + h_m - y_m) * inv_edge_y,
            ];
            if d.iter().any(|&e| e <= -0.5) {
                continue;
            }
            let inside: f64 = d.iter().map(|&e| smoothstep(e + 0.5)).product();
            let sign = if h & (1 << 63) != 0 { 1.0 } else { -1.0 };
            let b = sign * contrast * (40.0 + 40.0 * unit(mix(h), 0));
            v += b * keep * inside;
        }
        v.clamp(0.0, 255.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_point_always_looks_the_same_and_seeds_differ() {
        let (a, b) = (Texture::new(1), Texture::new(2));
        let mut differ = 0;
        for k in 0..200 {
            let (x, y) = (k as f64 * 0.37 - 30.0, k as f64 * 0.11 + 5.0);
            assert_eq!(
                a.at(x, y, &Footprint::square(0.01)),
                a.at(x, y, &Footprint::square(0.01))
            );
            if (a.at(x, y, &Footprint::square(0.01)) - b.at(x, y, &Footprint::square(0.01))).abs() > 1.0 {
                differ += 1;
            }
        }
        assert!(differ > 150, "{differ}");
    }

    #[test]
    fn detail_fades_to_the_mean_as_the_footprint_grows() {
        let t = Texture::new(3);
        let spread = |f: f64| {
            let v: Vec<f64> = (0..2000)
                .map(|k| t.at(k as f64 * 0.173, k as f64 * 0.071, &Footprint::square(f)))
                .collect();
            let m = v.iter().sum::<f64>() / v.len() as f64;
            (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
        };
        let (near, far) = (spread(0.01), spread(5.0));
        assert!(near > 25.0, "near {near}");
        assert!(far < 1e-9, "far {far}");
    }
}
