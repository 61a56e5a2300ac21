//! Pyramidal Lucas–Kanade: why this exists is that a drone camera moves a
//! feature by tens of pixels between frames, further than one Lucas–Kanade
//! step converges, so the search starts on the coarsest level of a pyramid
//! and is refined level by level (Bouguet's formulation).
//!
//! At each level `L`, with the point `p` scaled to it and the current
//! displacement `d`, the window `W` around `p` in the previous image `I`
//! is matched in the next image `J` by Gauss–Newton on
//! `Σ_w (I(p+w) − J(p+d+w))²`:
//! `G = Σ ∇I ∇Iᵀ` (the structure tensor of the template, fixed),
//! `b = Σ (I(p+w) − J(p+d+w)) ∇I`, `d ← d + G⁻¹ b`, until `|G⁻¹ b| < eps`.
//! The level's `d` doubled seeds the next finer level. A window whose `G`
//! has a small least eigenvalue (no texture in two directions) on the image
//! itself is refused; a flat one on a coarse level only skips that level.
//!
//! The forward–backward check tracks the result back to the previous image
//! and refuses a track that does not return within `max_fb_error_px` of
//! where it started (Kalal et al., 2010).

use crate::image::{dot, Pyramid};

/// The tracker's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KltParams {
    /// Half the window side (px): the window is `2r + 1` square.
    pub half_window: usize,
    /// Gauss–Newton iterations per level, at most.
    pub max_iterations: usize,
    /// Stop when a step is shorter than this (px).
    pub epsilon_px: f32,
    /// The least eigenvalue of `G / window area` below which a window is
    /// too flat to track (intensity² / px²).
    pub min_eigenvalue: f32,
    /// Largest forward–backward distance kept (px).
    pub max_fb_error_px: f32,
}

impl Default for KltParams {
    fn default() -> Self {
        Self {
            half_window: 7,
            max_iterations: 20,
            epsilon_px: 0.01,
            min_eigenvalue: 1.0,
            max_fb_error_px: 0.5,
        }
    }
}

/// Scratch space for one track: the template (with a one-pixel ring for
/// its gradients), its gradients and the moving window, reused.
#[derive(Clone, Debug, Default)]
pub struct KltScratch {
    ring: Vec<f32>,
    template: Vec<f32>,
    gx: Vec<f32>,
    gy: Vec<f32>,
    moving: Vec<f32>,
}

/// A coarse level stops once a step is shorter than this (its own px):
/// it only has to bring the next finer level inside its basin, which is
/// a window wide, and the finest level alone sets the precision.
const COARSE_EPSILON_PX: f32 = 0.1;

/// Tracks `p` (level-0 px) from `prev` to `next`, starting from `guess`,
/// over the `max_levels` finest levels of the pyramids (at most); `None`
/// when a window is flat, leaves the image or does not converge.
pub fn track_point(
    prev: &Pyramid,
    next: &Pyramid,
    p: [f32; 2],
    guess: [f32; 2],
    max_levels: usize,
    prm: &KltParams,
    s: &mut KltScratch,
) -> Option<[f32; 2]> {
    let n_levels = prev.levels.len().min(next.levels.len()).min(max_levels.max(1));
    let r = prm.half_window;
    let side = 2 * r + 1;
    let area = (side * side) as f32;
    s.ring.resize((side + 2) * (side + 2), 0.0);
    s.template.resize(side * side, 0.0);
    s.gx.resize(side * side, 0.0);
    s.gy.resize(side * side, 0.0);
    s.moving.resize(side * side, 0.0);
    // Displacement on the current level, seeded from the guess.
    let top = (n_levels - 1) as i32;
    let scale_top = 0.5f32.powi(top);
    let mut d = [(guess[0] - p[0]) * scale_top, (guess[1] - p[1]) * scale_top];
    for level in (0..n_levels).rev() {
        let scale = 0.5f32.powi(level as i32);
        let (i_img, j_img) = (&prev.levels[level], &next.levels[level]);
        let (px, py) = (p[0] * scale, p[1] * scale);
        // Near the border a coarse level has no room for the window: the
        // level is skipped (its pixels are a whole window wide there); on
        // the image itself the track is lost.
        if !i_img.inside(px, py, r as f32 + 3.0) {
            if level == 0 {
                return None;
            }
            d = [2.0 * d[0], 2.0 * d[1]];
            continue;
        }
        // The template with a one-pixel ring, and its central differences.
        i_img.window(px, py, r + 1, &mut s.ring);
        let rs = side + 2;
        for j in 0..side {
            let (up, mid, down) = (
                &s.ring[j * rs..][..rs],
                &s.ring[(j + 1) * rs..][..rs],
                &s.ring[(j + 2) * rs..][..rs],
            );
            let k = j * side;
            let (t, gx, gy) = (
                &mut s.template[k..k + side],
                &mut s.gx[k..k + side],
                &mut s.gy[k..k + side],
            );
            for i in 0..side {
                t[i] = mid[i + 1];
                gx[i] = 0.5 * (mid[i + 2] - mid[i]);
                gy[i] = 0.5 * (down[i + 1] - up[i + 1]);
            }
        }
        let (gxx, gxy, gyy) = (dot(&s.gx, &s.gx), dot(&s.gx, &s.gy), dot(&s.gy, &s.gy));
        // Least eigenvalue of the 2×2 structure tensor, per pixel.
        let tr = 0.5 * (gxx + gyy);
        let det = gxx * gyy - gxy * gxy;
        let min_eig = (tr - (tr * tr - det).max(0.0).sqrt()) / area;
        // A flat window refuses the track on the image itself; on a coarse
        // level, where the texture is blurred away, the level is skipped
        // and the finer ones search from the displacement so far.
        if level == 0 && min_eig < prm.min_eigenvalue {
            return None;
        }
        let iterations = if det > 1e-6 * area * area && min_eig > 0.0 {
            prm.max_iterations
        } else {
            0
        };
        let inv_det = 1.0 / det;
        for _ in 0..iterations {
            let (qx, qy) = (px + d[0], py + d[1]);
            if !j_img.inside(qx, qy, r as f32 + 2.0) {
                if level == 0 {
                    return None;
                }
                break;
            }
            j_img.window(qx, qy, r, &mut s.moving);
            // The residual in place of the moving window, then
            // b = Σ e ∇I as two sums that vectorise.
            for (m, &t) in s.moving.iter_mut().zip(&s.template) {
                *m = t - *m;
            }
            let (bx, by) = (dot(&s.moving, &s.gx), dot(&s.moving, &s.gy));
            // δ = G⁻¹ b.
            let dx = inv_det * (gyy * bx - gxy * by);
            let dy = inv_det * (gxx * by - gxy * bx);
            d[0] += dx;
            d[1] += dy;
            let eps = if level == 0 {
                prm.epsilon_px
            } else {
                COARSE_EPSILON_PX.max(prm.epsilon_px)
            };
            if dx * dx + dy * dy < eps * eps {
                break;
            }
        }
        if level > 0 {
            d = [2.0 * d[0], 2.0 * d[1]];
        }
    }
    let q = [p[0] + d[0], p[1] + d[1]];
    (q[0].is_finite() && q[1].is_finite() && next.levels[0].inside(q[0], q[1], 0.0)).then_some(q)
}

/// Pyramid levels of the backward track.
const BACKWARD_LEVELS: usize = 2;

/// Tracks `p` forward and back: the new position when the backward track
/// returns within `max_fb_error_px` of `p`. The backward track starts at
/// `p` itself, so it needs only the two finest levels: a track it accepts
/// ends within half a pixel of its start, far inside their basin.
pub fn track_checked(
    prev: &Pyramid,
    next: &Pyramid,
    p: [f32; 2],
    guess: [f32; 2],
    prm: &KltParams,
    s: &mut KltScratch,
) -> Option<[f32; 2]> {
    let q = track_point(prev, next, p, guess, usize::MAX, prm, s)?;
    let back = track_point(next, prev, q, p, BACKWARD_LEVELS, prm, s)?;
    let fb = ((back[0] - p[0]).powi(2) + (back[1] - p[1]).powi(2)).sqrt();
    (fb <= prm.max_fb_error_px).then_some(q)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Gray;
    use crate::synthetic::textured;

    /// A smooth random texture shifted by a known sub-pixel amount is
    /// tracked to a few hundredths of a pixel, also for shifts of 20 px that
    /// only the pyramid reaches; a flat patch is refused.
    #[test]
    fn recovers_known_shifts() {
        let (w, h) = (320, 240);
        let prm = KltParams::default();
        let mut s = KltScratch::default();
        for (dx, dy) in [(0.3f32, -0.7f32), (4.25, 2.5), (-18.6, 11.2)] {
            let a = textured(w, h, 7, 0.0, 0.0);
            let b = textured(w, h, 7, dx, dy);
            let (pa, pb) = (Pyramid::of(&a, 4), Pyramid::of(&b, 4));
            let mut worst = 0.0f32;
            for &(x, y) in &[(100.0f32, 90.0f32), (160.0, 120.0), (210.5, 140.25)] {
                let q = track_checked(&pa, &pb, [x, y], [x, y], &prm, &mut s).expect("tracked");
                worst = worst.max(((q[0] - x - dx).powi(2) + (q[1] - y - dy).powi(2)).sqrt());
            }
            assert!(worst < 0.05, "shift ({dx}, {dy}): error {worst} px");
        }
        let flat = Pyramid::of(&Gray::new(w, h), 3);
        assert!(track_point(&flat, &flat, [100.0, 100.0], [100.0, 100.0], 3, &prm, &mut s).is_none());
    }
}
