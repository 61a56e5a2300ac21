//! Outlier rejection by RANSAC on the epipolar constraint: why this exists
//! is that Lucas–Kanade happily follows a texture that is not a world point
//! (a reflection, an occlusion edge, a repeated pattern), and a track that
//! jumps between world points would reach the filter as a bad measurement.
//!
//! With normalised, undistorted coordinates `x₁, x₂` (`z = 1`) of one point
//! in two frames, a static world point satisfies `x₂ᵀ E x₁ = 0` (`E = [t]ₓ R`).
//! Eight pairs give `E` linearly (the 8-point algorithm: the null vector of
//! the stacked rows `x₂ ⊗ x₁`, then rank 2 enforced by SVD). Each pair is
//! scored by its Sampson distance
//! `(x₂ᵀEx₁)² / ((Ex₁)₁² + (Ex₁)₂² + (Eᵀx₂)₁² + (Eᵀx₂)₂²)`, a first-order
//! distance to the constraint in normalised units. The sample count adapts
//! to the inlier share seen (`log(1 − 0.99) / log(1 − w⁸)`). A still or
//! purely rotating camera makes every pair fit some `E`: then nothing is
//! rejected, as it should be.
//!
//! [`affine_inliers`] does the same for one affine image motion (from
//! three-pair samples), re-identification's second check of a revisit.

use nalgebra::{Matrix3, SMatrix, Vector3};

use crate::synthetic::SplitMix;

/// The fewest pairs RANSAC needs; with fewer, every pair is kept.
pub const MIN_PAIRS: usize = 8;

/// Marks each pair `(x₁, x₂)` an inlier (`true`) when its Sampson distance
/// to the best `E` found is below `threshold` (normalised units, e.g. 1 px
/// over the focal length). Deterministic: `seed` drives the sampling.
pub fn epipolar_inliers(pairs: &[([f64; 2], [f64; 2])], threshold: f64, seed: u64, inliers: &mut Vec<bool>) {
    inliers.clear();
    inliers.resize(pairs.len(), true);
    if pairs.len() < MIN_PAIRS + 2 {
        return;
    }
    let mut rng = SplitMix::new(seed);
    let t2 = threshold * threshold;
    let mut best_count = 0;
    let mut best = Matrix3::zeros();
    let mut needed = 200.0f64;
    let mut it = 0;
    let mut sample = [0usize; MIN_PAIRS];
    while (it as f64) < needed.min(200.0) {
        it += 1;
        // Eight distinct indices.
        let mut k = 0;
        while k < MIN_PAIRS {
            let i = (rng.next_u64() % pairs.len() as u64) as usize;
            if !sample[..k].contains(&i) {
                sample[k] = i;
                k += 1;
            }
        }
        let Some(e) = essential_8pt(pairs, &sample) else {
            continue;
        };
        let count = pairs.iter().filter(|p| sampson2(&e, p) < t2).count();
        if count > best_count {
            best_count = count;
            best = e;
            let w = count as f64 / pairs.len() as f64;
            let miss = 1.0 - w.powi(MIN_PAIRS as i32);
            needed = if miss <= 1e-12 {
                0.0
            } else {
                (1.0f64 - 0.99).ln() / miss.ln()
            };
        }
    }
    if best_count == 0 {
        return;
    }
    for (flag, p) in inliers.iter_mut().zip(pairs) {
        *flag = sampson2(&best, p) < t2;
    }
}

/// `E` from eight pairs: the eigenvector of `AᵀA` with the least eigenvalue
/// (`A` the stacked `x₂ ⊗ x₁` rows), its smallest singular value zeroed.
fn essential_8pt(pairs: &[([f64; 2], [f64; 2])], idx: &[usize; MIN_PAIRS]) -> Option<Matrix3<f64>> {
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for &i in idx {
        let (a, b) = pairs[i];
        let row = SMatrix::<f64, 1, 9>::from_row_slice(&[
            b[0] * a[0],
            b[0] * a[1],
            b[0],
            b[1] * a[0],
            b[1] * a[1],
            b[1],
            a[0],
            a[1],
            1.0,
        ]);
        ata += row.transpose() * row;
    }
    let eig = ata.symmetric_eigen();
    let (k, _) = eig.eigenvalues.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1))?;
    let v = eig.eigenvectors.column(k);
    let e = Matrix3::new(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8]);
    let mut svd = e.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    svd.singular_values[2] = 0.0;
    let e = u * Matrix3::from_diagonal(&svd.singular_values) * vt;
    e.iter().all(|x| x.is_finite()).then_some(e)
}

/// The squared Sampson distance of a pair to `x₂ᵀ E x₁ = 0`.
fn sampson2(e: &Matrix3<f64>, p: &([f64; 2], [f64; 2])) -> f64 {
    let x1 = Vector3::new(p.0[0], p.0[1], 1.0);
    let x2 = Vector3::new(p.1[0], p.1[1], 1.0);
    let ex1 = e * x1;
    let etx2 = e.transpose() * x2;
    let num = x2.dot(&ex1);
    let den = ex1.x * ex1.x + ex1.y * ex1.y + etx2.x * etx2.x + etx2.y * etx2.y;
    if den <= 0.0 {
        f64::INFINITY
    } else {
        num * num / den
    }
}

/// Marks the pixel pairs `(a, b)` that one affine map `b ≈ A a + t` (from
/// three-pair RANSAC samples, `seed` driven) carries to within
/// `tolerance_px`.
pub fn affine_inliers(pairs: &[([f64; 2], [f64; 2])], tolerance_px: f64, seed: u64, ok: &mut Vec<bool>) {
    ok.clear();
    ok.resize(pairs.len(), false);
    if pairs.len() < 3 {
        return;
    }
    let mut rng = SplitMix::new(seed ^ 0xaff1);
    let t2 = tolerance_px * tolerance_px;
    let mut best: Option<(usize, [f64; 6])> = None;
    for _ in 0..100 {
        let mut idx = [0usize; 3];
        for i in idx.iter_mut() {
            *i = (rng.next_u64() % pairs.len() as u64) as usize;
        }
        if idx[0] == idx[1] || idx[1] == idx[2] || idx[0] == idx[2] {
            continue;
        }
        // b = [a_x a_y 1] M (two columns), solved from the three pairs.
        let m = nalgebra::Matrix3::from_fn(|r, c| if c < 2 { pairs[idx[r]].0[c] } else { 1.0 });
        let Some(inv) = m.try_inverse() else { continue };
        let bx = inv * nalgebra::Vector3::from_fn(|r, _| pairs[idx[r]].1[0]);
        let by = inv * nalgebra::Vector3::from_fn(|r, _| pairs[idx[r]].1[1]);
        let p = [bx[0], bx[1], bx[2], by[0], by[1], by[2]];
        let fits = |(a, b): &([f64; 2], [f64; 2])| {
            let (x, y) = (p[0] * a[0] + p[1] * a[1] + p[2], p[3] * a[0] + p[4] * a[1] + p[5]);
            (x - b[0]).powi(2) + (y - b[1]).powi(2) < t2
        };
        let n = pairs.iter().filter(|q| fits(q)).count();
        if best.is_none_or(|(bn, _)| n > bn) {
            best = Some((n, p));
        }
    }
    if let Some((_, p)) = best {
        for (flag, (a, b)) in ok.iter_mut().zip(pairs) {
            let (x, y) = (p[0] * a[0] + p[1] * a[1] + p[2], p[3] * a[0] + p[4] * a[1] + p[5]);
            *flag = (x - b[0]).powi(2) + (y - b[1]).powi(2) < t2;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    /// Points seen from two poses, with 20 % of the pairs replaced by
    /// random ones: every outlier farther than 3 thresholds from its epipolar
    /// line is rejected and every true pair kept.
    #[test]
    fn rejects_pairs_off_the_epipolar_geometry() {
        let mut r = SplitMix::new(5);
        let rot = Rotation3::from_euler_angles(0.02, -0.05, 0.03);
        let t = Vector3::new(0.3, -0.1, 0.05);
        let mut pairs = Vec::new();
        let mut truth = Vec::new();
        for i in 0..150 {
            let p = Vector3::new(4.0 * r.unit() - 2.0, 3.0 * r.unit() - 1.5, 4.0 + 6.0 * r.unit());
            let q = rot * p + t;
            let a = [p.x / p.z, p.y / p.z];
            let mut b = [q.x / q.z, q.y / q.z];
            let outlier = i % 5 == 0;
            if outlier {
                b = [b[0] + 0.05 * (r.unit() - 0.5), b[1] + 0.05 * (r.unit() - 0.5)];
            }
            pairs.push((a, b));
            truth.push(!outlier);
        }
        let thr = 1.0 / 460.0;
        let mut inl = Vec::new();
        epipolar_inliers(&pairs, thr, 1, &mut inl);
        let kept_true = truth.iter().zip(&inl).filter(|(t, k)| **t && **k).count();
        assert_eq!(kept_true, truth.iter().filter(|t| **t).count());
        // An outlier can fall near its epipolar line by chance; those far
        // from it must go.
        let e = {
            let tx = Matrix3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0);
            tx * rot.matrix()
        };
        for ((p, k), t) in pairs.iter().zip(&inl).zip(&truth) {
            if !t && sampson2(&e, p).sqrt() > 3.0 * thr {
                assert!(!k, "an outlier kept");
            }
        }
        // A still camera: nothing to reject.
        let still: Vec<_> = pairs.iter().map(|p| (p.0, p.0)).collect();
        epipolar_inliers(&still, thr, 1, &mut inl);
        assert!(inl.iter().all(|k| *k));
    }
}
