//! Each track held to the window it was first seen with, through an affine
//! warp: why this exists is that frame-to-frame Lucas–Kanade, translation
//! only, drifts where the image of a surface scales or shears from frame to
//! frame (a forward camera over the ground): the window's texture pulls the
//! estimate by the scale change times its offset from the centre, a tenth
//! of a pixel a frame, always the same way. Shi and Tomasi ("Good features
//! to track", CVPR 1994) track frame to frame and then check each feature
//! against its first appearance with an affine map; here that check also
//! corrects the position.
//!
//! Inverse-compositional Gauss–Newton (Baker and Matthews, IJCV 2004): the
//! anchor `T` is the window at the first sighting, its pixels `x` offsets
//! from the feature; the warp is `W(x; A, t) = A x + t` into the new image
//! `I`. With `J(x) = ∇T(x) ∂W/∂p` at the identity, for
//! `p = (A₀₀, A₀₁, A₁₀, A₁₁, t_x, t_y)`, i.e.
//! `J = [T_x x, T_x y, T_y x, T_y y, T_x, T_y]`, and `H = Σ Jᵀ J` (both fixed
//! per anchor), each step solves `Δp = H⁻¹ Σ Jᵀ (I(W(x)) − T(x))` and
//! composes `W ← W ∘ W(Δp)⁻¹`: `A ← A (1 + D)⁻¹`, `t ← t − A d`, where `D`
//! and `d` are `Δp`'s matrix and vector parts.

use nalgebra::{Matrix2, Matrix6, Vector2, Vector6};

use crate::image::Gray;

/// Half the side of the warped window (px).
pub const HALF: usize = 9;

/// How far above the noise of two images a perfect match's residual may
/// lie (see [`Anchor::fits`]).
const NOISE_MARGIN: f32 = 1.2;

/// The side of the first window with its one-pixel ring (px).
pub const RING_SIDE: usize = 2 * HALF + 3;

/// The window of `img` at `(u, v)` with its one-pixel ring (`RING_SIDE²`,
/// row by row) as grey bytes, written into `out`, if it fits: a tenth of
/// an anchor's size, so re-identification can keep one for every landmark
/// it knows (quantised to grey levels: under 0.3 of RMS error, below any
/// camera's noise).
pub fn window_bytes(img: &Gray, u: f32, v: f32, ring: &mut Vec<f32>, out: &mut Vec<u8>) -> bool {
    if !sample_ring(img, u, v, ring) {
        return false;
    }
    out.clear();
    out.extend(ring.iter().map(|&v| v.round().clamp(0.0, 255.0) as u8));
    true
}

/// The window of `img` at `(u, v)` with its one-pixel ring (`RING_SIDE²`,
/// row by row) into `ring`, if it fits in the image.
fn sample_ring(img: &Gray, u: f32, v: f32, ring: &mut Vec<f32>) -> bool {
    if !img.inside(u, v, (HALF + 2) as f32) {
        return false;
    }
    ring.resize(RING_SIDE * RING_SIDE, 0.0);
    img.window(u, v, HALF + 1, ring);
    true
}

/// A track's first window: its pixels, the steepest-descent images `J`
/// and `H⁻¹`, and the current warp.
#[derive(Clone, Debug)]
pub struct Anchor {
    t: Vec<f32>,
    j: Vec<[f32; 6]>,
    h_inv: Matrix6<f32>,
    /// The window's standard deviation (grey levels): residuals are read
    /// against it, so a check does not depend on the scene's contrast
    /// (beyond the noise's floor).
    spread: f32,
    /// The warp's linear part (the translation is the feature's position).
    pub a: Matrix2<f32>,
}

impl Anchor {
    /// The window of `img` centred at `(u, v)`, or `None` if it does not
    /// fit or is too flat to hold an affine warp.
    pub fn new(img: &Gray, u: f32, v: f32) -> Option<Self> {
        let mut ring = Vec::new();
        if !sample_ring(img, u, v, &mut ring) {
            return None;
        }
        Self::from_ring(&ring)
    }

    /// The anchor of a window kept as grey bytes ([`window_bytes`]), its
    /// warp the identity: how a re-identified track is checked against
    /// its landmark's look.
    pub fn from_window_bytes(bytes: &[u8]) -> Option<Self> {
        if bytes.len() != RING_SIDE * RING_SIDE {
            return None;
        }
        let ring: Vec<f32> = bytes.iter().map(|&b| f32::from(b)).collect();
        Self::from_ring(&ring)
    }

    /// From the first window with its one-pixel ring (`RING_SIDE²`).
    fn from_ring(ring: &[f32]) -> Option<Self> {
        let side = RING_SIDE;
        let n = 2 * HALF + 1;
        let (mut t, mut j) = (Vec::with_capacity(n * n), Vec::with_capacity(n * n));
        let mut h = Matrix6::<f32>::zeros();
        for y in 0..n {
            for x in 0..n {
                let c = (y + 1) * side + x + 1;
                let (gx, gy) = (
                    0.5 * (ring[c + 1] - ring[c - 1]),
                    0.5 * (ring[c + side] - ring[c - side]),
                );
                let (dx, dy) = (x as f32 - HALF as f32, y as f32 - HALF as f32);
                let row = [gx * dx, gx * dy, gy * dx, gy * dy, gx, gy];
                let jv = Vector6::from_row_slice(&row);
                h += jv * jv.transpose();
                t.push(ring[c]);
                j.push(row);
            }
        }
        let h_inv = h.try_inverse()?;
        let mean = t.iter().sum::<f32>() / t.len() as f32;
        let spread = (t.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / t.len() as f32).sqrt();
        Some(Self {
            t,
            j,
            h_inv,
            spread,
            a: Matrix2::identity(),
        })
    }

    /// Refines the feature's position `pos` in `img`, starting from the
    /// current warp: the new position and the residual's RMS (grey levels;
    /// see [`Anchor::fits`]), or `None` if the window leaves the image or
    /// the warp degenerates.
    pub fn refine(&mut self, img: &Gray, pos: [f32; 2], iterations: usize) -> Option<([f32; 2], f32)> {
        let mut t = Vector2::new(pos[0], pos[1]);
        let mut a = self.a;
        let n = 2 * HALF + 1;
        let mut rms = f32::INFINITY;
        for _ in 0..iterations {
            // How far the warped window reaches from its centre (px): the
            // largest row sum of |A| times the window's half side.
            let reach = HALF as f32 * a.abs().column_sum().max().max(1.0);
            if !img.inside(t.x, t.y, reach + 2.0) {
                return None;
            }
            let mut b = Vector6::<f32>::zeros();
            let mut sq = 0.0f32;
            for y in 0..n {
                for x in 0..n {
                    let k = y * n + x;
                    let d = Vector2::new(x as f32 - HALF as f32, y as f32 - HALF as f32);
                    let p = a * d + t;
                    // Inside: the window's reach was checked above.
                    let e = img.sample_inside(p.x, p.y) - self.t[k];
                    sq += e * e;
                    let jr = &self.j[k];
                    for i in 0..6 {
                        b[i] += jr[i] * e;
                    }
                }
            }
            rms = (sq / (n * n) as f32).sqrt();
            let dp = self.h_inv * b;
            let dm = Matrix2::new(1.0 + dp[0], dp[1], dp[2], 1.0 + dp[3]);
            let dm_inv = dm.try_inverse()?;
            a *= dm_inv;
            t -= a * Vector2::new(dp[4], dp[5]);
            if !(t.x.is_finite() && t.y.is_finite()) {
                return None;
            }
            if dp[4].hypot(dp[5]) < 0.01 {
                break;
            }
        }
        // A warp that shrinks, grows or shears the window past a factor of
        // two is no longer this window.
        let det = a.determinant();
        if !(0.25..4.0).contains(&det) {
            return None;
        }
        self.a = a;
        Some(([t.x, t.y], rms))
    }

    /// Whether a residual RMS `rms` (grey levels) still matches this
    /// window: below `share` of the window's spread, added in quadrature
    /// to what the noise of two images alone leaves, `√2 σ` for a noise
    /// of `noise_grey` (σ) a pixel, with a margin of 1.2. A share of 0.1
    /// alone would be the noise itself for a window of median contrast
    /// (a spread of 30 grey levels on the rendered world, noise 2).
    pub fn fits(&self, rms: f32, share: f32, noise_grey: f32) -> bool {
        let noise = NOISE_MARGIN * std::f32::consts::SQRT_2 * noise_grey;
        rms * rms < (share * self.spread).powi(2) + noise * noise
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::Texture;
    use nalgebra::Matrix3;

    /// A texture seen through a known affine map (a 6 % zoom, a 3° turn and
    /// a shift) is found to a few hundredths of a pixel from the window of
    /// the unwarped image.
    #[test]
    fn recovers_a_known_affine_motion() {
        let tex = Texture::new(5, 400.0);
        let a = tex.render(200, 200, &Matrix3::identity());
        let (s, th) = (1.06f64, 3f64.to_radians());
        let h = Matrix3::new(
            s * th.cos(),
            -s * th.sin(),
            4.3,
            s * th.sin(),
            s * th.cos(),
            -2.6,
            0.0,
            0.0,
            1.0,
        );
        let b = tex.render(200, 200, &h);
        for &(u, v) in &[(90.0f64, 100.0f64), (120.5, 80.25)] {
            let mut anchor = Anchor::new(&a, u as f32, v as f32).expect("textured");
            let truth = h * nalgebra::Vector3::new(u, v, 1.0);
            // Start 1.5 px off, as a translation-only track would leave it.
            let start = [truth.x as f32 + 1.0, truth.y as f32 - 1.1];
            let (q, rms) = anchor.refine(&b, start, 30).expect("converges");
            let err = (f64::from(q[0]) - truth.x).hypot(f64::from(q[1]) - truth.y);
            assert!(err < 0.05, "({u}, {v}): {err} px off, residual {rms}");
            assert!((f64::from(anchor.a.determinant()) - s * s).abs() < 0.01, "{}", anchor.a);
        }
    }
}
