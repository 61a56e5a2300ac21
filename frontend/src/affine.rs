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

use cmsckf_models::feature_wire::{SIGMA_MAX_PX, SIGMA_MIN_PX};
use nalgebra::{Matrix2, Matrix6, Vector2, Vector6};

use crate::image::{dot, sum, Gray};

/// Half the side of the warped window (px).
pub const HALF: usize = 9;

/// How far above the noise of two images a perfect match's residual may
/// lie (see [`Anchor::fits`]).
const NOISE_MARGIN: f32 = 1.2;

/// The side of the first window with its one-pixel ring (px).
pub const RING_SIDE: usize = 2 * HALF + 3;

/// The window's pixel count, `(2 HALF + 1)²`.
const N: usize = (2 * HALF + 1) * (2 * HALF + 1);

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
    // Rounded to the nearest level: the values are in [0, 255], so adding
    // a half and truncating is the rounding (without a call to `roundf`).
    out.extend(ring.iter().map(|&v| (v.clamp(0.0, 255.0) + 0.5) as u8));
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
/// and `H⁻¹`, and the current warp. Its buffers are refilled in place
/// ([`Anchor::reset_at`], [`Anchor::reset_from_window_bytes`]), so a
/// tracker that keeps its anchors allocates none per frame.
#[derive(Clone, Debug)]
pub struct Anchor {
    /// The window with its ring, as last sampled (scratch of the refill).
    ring: Vec<f32>,
    /// `T(x)`, row by row (`N`).
    t: Vec<f32>,
    /// The six steepest-descent images `J_i(x)`, one after the other
    /// (`6 N`): laid out by parameter, so each sum over the window reads
    /// one contiguous run.
    j: Vec<f32>,
    /// The residual image `I(W(x)) − T(x)` of the last step, and where
    /// each of its samples was taken: the index of the pixel left of and
    /// above the point, and the point's fractions past it (scratch).
    e: Vec<f32>,
    at: Vec<i32>,
    fx: Vec<f32>,
    fy: Vec<f32>,
    h_inv: Matrix6<f32>,
    /// The position's σ for a residual RMS of one grey level, before the
    /// smoothing's correction (`Anchor::sigma_px`): from `H⁻¹` in f64,
    /// since f32 loses a nearly one-dimensional window's weak direction.
    sigma_unit: f64,
    /// The window's standard deviation (grey levels): residuals are read
    /// against it, so a check does not depend on the scene's contrast
    /// (beyond the noise's floor).
    spread: f32,
    /// The warp's linear part (the translation is the feature's position).
    pub a: Matrix2<f32>,
}

impl Default for Anchor {
    /// An empty anchor, to be filled by a reset.
    fn default() -> Self {
        Self {
            ring: Vec::new(),
            t: Vec::new(),
            j: Vec::new(),
            e: Vec::new(),
            at: Vec::new(),
            fx: Vec::new(),
            fy: Vec::new(),
            h_inv: Matrix6::zeros(),
            sigma_unit: 0.0,
            spread: 0.0,
            a: Matrix2::identity(),
        }
    }
}

impl Anchor {
    /// An empty anchor whose buffers already have a window's sizes: a
    /// tracker makes its pool of these at start, so that no reset in
    /// flight allocates.
    pub fn with_buffers() -> Self {
        Self {
            ring: Vec::with_capacity(RING_SIDE * RING_SIDE),
            t: Vec::with_capacity(N),
            j: Vec::with_capacity(6 * N),
            e: Vec::with_capacity(N),
            at: Vec::with_capacity(N),
            fx: Vec::with_capacity(N),
            fy: Vec::with_capacity(N),
            ..Self::default()
        }
    }

    /// The window of `img` centred at `(u, v)`, or `None` if it does not
    /// fit or is too flat to hold an affine warp.
    pub fn new(img: &Gray, u: f32, v: f32) -> Option<Self> {
        let mut a = Self::default();
        a.reset_at(img, u, v).then_some(a)
    }

    /// [`Anchor::new`] into this anchor's buffers: false (the anchor
    /// unusable until the next reset) if the window does not fit or is
    /// too flat.
    pub fn reset_at(&mut self, img: &Gray, u: f32, v: f32) -> bool {
        let mut ring = std::mem::take(&mut self.ring);
        let ok = sample_ring(img, u, v, &mut ring) && self.reset_from_ring(&ring);
        self.ring = ring;
        ok
    }

    /// The anchor of a window kept as grey bytes ([`window_bytes`]), its
    /// warp the identity, in this anchor's buffers: how a re-identified
    /// track is checked against its landmark's look. False (the anchor
    /// unusable until the next reset) as for [`Anchor::reset_at`].
    pub fn reset_from_window_bytes(&mut self, bytes: &[u8]) -> bool {
        if bytes.len() != RING_SIDE * RING_SIDE {
            return false;
        }
        let mut ring = std::mem::take(&mut self.ring);
        ring.clear();
        ring.extend(bytes.iter().map(|&b| f32::from(b)));
        let ok = self.reset_from_ring(&ring);
        self.ring = ring;
        ok
    }

    /// From the first window with its one-pixel ring (`RING_SIDE²`): `T`,
    /// the central-difference gradients, `J = [T_x x, T_x y, T_y x, T_y y,
    /// T_x, T_y]` and `H = Σ Jᵀ J` (its 21 distinct entries, each a sum
    /// over the window).
    fn reset_from_ring(&mut self, ring: &[f32]) -> bool {
        let side = RING_SIDE;
        let n = 2 * HALF + 1;
        self.t.resize(N, 0.0);
        self.j.resize(6 * N, 0.0);
        self.e.resize(N, 0.0);
        self.at.resize(N, 0);
        self.fx.resize(N, 0.0);
        self.fy.resize(N, 0.0);
        self.a = Matrix2::identity();
        {
            let (j0, rest) = self.j.split_at_mut(N);
            let (j1, rest) = rest.split_at_mut(N);
            let (j2, rest) = rest.split_at_mut(N);
            let (j3, rest) = rest.split_at_mut(N);
            let (j4, j5) = rest.split_at_mut(N);
            // Row by row, over slices of the row's length (so each pass
            // vectorises).
            for y in 0..n {
                let dy = y as f32 - HALF as f32;
                let (up, mid, down) = (
                    &ring[y * side..][..side],
                    &ring[(y + 1) * side..][..side],
                    &ring[(y + 2) * side..][..side],
                );
                let row = y * n..(y + 1) * n;
                let t = &mut self.t[row.clone()];
                let (j0, j1, j2) = (&mut j0[row.clone()], &mut j1[row.clone()], &mut j2[row.clone()]);
                let (j3, j4, j5) = (&mut j3[row.clone()], &mut j4[row.clone()], &mut j5[row]);
                for x in 0..n {
                    let dx = x as f32 - HALF as f32;
                    let (gx, gy) = (0.5 * (mid[x + 2] - mid[x]), 0.5 * (down[x + 1] - up[x + 1]));
                    t[x] = mid[x + 1];
                    j0[x] = gx * dx;
                    j1[x] = gx * dy;
                    j2[x] = gy * dx;
                    j3[x] = gy * dy;
                    j4[x] = gx;
                    j5[x] = gy;
                }
            }
        }
        let mut h = Matrix6::<f32>::zeros();
        for r in 0..6 {
            for c in r..6 {
                let v = dot(&self.j[r * N..(r + 1) * N], &self.j[c * N..(c + 1) * N]);
                h[(r, c)] = v;
                h[(c, r)] = v;
            }
        }
        let Some(h_inv) = h.try_inverse() else { return false };
        self.h_inv = h_inv;
        // The translation's marginal covariance per unit residual variance
        // is `H⁻¹`'s lower-right 2×2 block; its larger eigenvalue's root.
        self.sigma_unit = match h.cast::<f64>().try_inverse() {
            Some(c) => {
                let (xx, xy, yy) = (c[(4, 4)], c[(4, 5)], c[(5, 5)]);
                let half_tr = 0.5 * (xx + yy);
                let lmax = half_tr + (half_tr * half_tr - (xx * yy - xy * xy)).max(0.0).sqrt();
                if lmax.is_finite() && lmax > 0.0 {
                    lmax.sqrt()
                } else {
                    f64::INFINITY
                }
            }
            None => f64::INFINITY,
        };
        // The spread, about the mean (the residual buffer as scratch).
        let mean = sum(&self.t) / N as f32;
        for (e, &t) in self.e.iter_mut().zip(&self.t) {
            *e = t - mean;
        }
        self.spread = (dot(&self.e, &self.e) / N as f32).sqrt();
        true
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
        if self.t.len() != N {
            return None;
        }
        for _ in 0..iterations {
            // How far the warped window reaches from its centre (px): the
            // largest row sum of |A| times the window's half side.
            let reach = HALF as f32 * a.abs().column_sum().max().max(1.0);
            if !img.inside(t.x, t.y, reach + 2.0) {
                return None;
            }
            // The residual image e(x) = I(W(x)) − T(x), W(x) = A x + t
            // (inside: the window's reach was checked above). First where
            // each sample falls, row by row (arithmetic alone, so it
            // vectorises; the points are positive, so truncation is the
            // floor), then the bilinear samples.
            let w = img.width as i32;
            for y in 0..n {
                let dy = y as f32 - HALF as f32;
                let (ox, oy) = (a[(0, 1)] * dy + t.x, a[(1, 1)] * dy + t.y);
                let row = y * n..(y + 1) * n;
                let (at, fx, fy) = (&mut self.at[row.clone()], &mut self.fx[row.clone()], &mut self.fy[row]);
                for x in 0..n {
                    let dx = x as f32 - HALF as f32;
                    let (px, py) = (a[(0, 0)] * dx + ox, a[(1, 0)] * dx + oy);
                    let (xi, yi) = (px as i32, py as i32);
                    at[x] = yi * w + xi;
                    fx[x] = px - xi as f32;
                    fy[x] = py - yi as f32;
                }
            }
            for ((((e, &tv), &at), &fx), &fy) in
                self.e.iter_mut().zip(&self.t).zip(&self.at).zip(&self.fx).zip(&self.fy)
            {
                *e = img.sample_at(at as usize, fx, fy) - tv;
            }
            // b = Σ Jᵀ e, one contiguous sum per parameter.
            let b = Vector6::from_fn(|i, _| dot(&self.j[i * N..(i + 1) * N], &self.e));
            rms = (dot(&self.e, &self.e) / N as f32).sqrt();
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

    /// The position's standard deviation (px) that a fit leaving a
    /// residual RMS of `rms` grey levels holds it to, along its least
    /// certain direction: the Gauss–Newton covariance `rms² H⁻¹` restricted
    /// to the translation (`H⁻¹`'s lower-right 2×2 block, the marginal of
    /// the six parameters), its largest eigenvalue's root, divided by
    /// `SMOOTH_NOISE_FACTOR`: the window is read on the smoothed frame,
    /// whose neighbouring residuals are correlated, so the sum over its
    /// pixels holds about `SMOOTH_NOISE_FACTOR²` as many independent ones
    /// (the `[1 2 1]/4` kernel's `Σw² = 0.375` along each axis). Clamped
    /// to the σ the feature socket takes. The warp's linear part `A` is
    /// left out (strictly the covariance is `A Σ Aᵀ`): over scales of
    /// 0.55–2 a Monte Carlo of noisy frames measured the spread at 0.93–1.12
    /// of this σ, the scale and the weaker correlation of a scaled window's
    /// samples roughly cancelling.
    pub fn sigma_px(&self, rms: f32) -> f32 {
        let sigma = f64::from(rms) * self.sigma_unit / f64::from(crate::image::SMOOTH_NOISE_FACTOR);
        // Within what the daemon takes (a noiseless image can leave no
        // residual at all, a flat window no bound): a feature's σ outside it
        // refuses the frame. NaN (from a NaN residual) is the largest.
        if sigma.is_nan() {
            return SIGMA_MAX_PX as f32;
        }
        sigma.clamp(SIGMA_MIN_PX, SIGMA_MAX_PX) as f32
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

    /// The σ grows with the residual and with a flatter window, and stays
    /// within what the feature socket takes.
    #[test]
    fn the_sigma_follows_the_residual_and_the_contrast() {
        let tex = Texture::new(5, 400.0);
        let img = tex.render(200, 200, &Matrix3::identity());
        let anchor = Anchor::new(&img, 100.0, 100.0).expect("textured");
        let (s1, s2) = (anchor.sigma_px(2.0), anchor.sigma_px(4.0));
        assert!(s1 > 0.0 && (s2 / s1 - 2.0).abs() < 1e-4, "{s1} {s2}");
        assert_eq!(anchor.sigma_px(0.0), SIGMA_MIN_PX as f32);
        assert_eq!(anchor.sigma_px(f32::MAX), SIGMA_MAX_PX as f32);
        // The same window at a quarter of the contrast: four times the σ.
        let mut faint = img.clone();
        for p in faint.px.iter_mut() {
            *p = 128.0 + 0.25 * (*p - 128.0);
        }
        let weak = Anchor::new(&faint, 100.0, 100.0).expect("still textured");
        let ratio = weak.sigma_px(2.0) / s1;
        assert!((ratio - 4.0).abs() < 0.01, "{ratio}");
        assert_eq!(anchor.sigma_px(f32::NAN), SIGMA_MAX_PX as f32);
        // A diagonal edge with a faint texture on it: along the edge the
        // window holds the position to nothing, and its σ says so (in f32,
        // H⁻¹ had given 0.015 px for this window).
        let mut edge = img.clone();
        for y in 0..edge.height {
            for x in 0..edge.width {
                let k = y * edge.width + x;
                let d = (x as f32 - y as f32) / 2.0;
                edge.px[k] = 128.0 + 60.0 * d.tanh() + 1e-3 * (img.px[k] - 128.0);
            }
        }
        let a = Anchor::new(&edge, 100.0, 100.0).expect("f32 inverts this H");
        assert!(a.sigma_px(1.0) > 10.0, "σ {} px along an edge", a.sigma_px(1.0));
    }
}
