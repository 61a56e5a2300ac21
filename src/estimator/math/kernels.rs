//! The vector kernels of the dense factorisations (`dot`, `axpy`), once
//! for the baseline CPU the binary targets and once for AVX2 with fused
//! multiply-adds, chosen at run time.
//!
//! Why it exists: the release build targets plain x86-64 so that it runs on
//! any companion computer, and its vector code is then two lanes wide with
//! separate multiplies and adds. The Householder triangularisation is the
//! camera update's largest cost (issue 43's profile, docs/performance.md),
//! and on a CPU with AVX2 and FMA (Intel's Core since 2013, AMD's since
//! 2015; not the Atom, Celeron and Pentium Silver parts of some companion
//! computers, which take the portable path) four lanes of fused
//! multiply-adds do its column operations. The profile in
//! docs/performance.md gives what the change (with the IMU step's) saved.
//! The two paths differ by round-off only (a fused multiply-add rounds
//! once, and the sums are taken in another order), so a replay is bit for
//! bit only on a CPU that takes the same path. Other architectures (the
//! arm64 package) take the portable path, which the compiler vectorises
//! for their baseline (NEON).

#![deny(unsafe_op_in_unsafe_fn)]

use super::{axpy, dot};

/// The column operations a factorisation is written against; its code is
/// generic over them so that one source serves both paths.
pub trait Kernels: Copy {
    /// `Σ aᵢ bᵢ` over the common length.
    fn dot(self, a: &[f64], b: &[f64]) -> f64;
    /// `y ← y + α x` over the common length.
    fn axpy(self, alpha: f64, x: &[f64], y: &mut [f64]);
    /// `vᵀ cₖ` for four columns at once, all over the shortest length of
    /// `v` and the columns (on every path; callers pass equal lengths): one
    /// pass over `v` instead of four (a reflection applied to a
    /// panel's columns reads its vector once per four columns).
    #[inline(always)]
    fn dot4(self, v: &[f64], c: [&[f64]; 4]) -> [f64; 4] {
        let n = c.iter().fold(v.len(), |n, ck| n.min(ck.len()));
        c.map(|ck| self.dot(&v[..n], ck))
    }
    /// `cₖ ← cₖ + αₖ v` for four columns at once, over the shortest of `v`
    /// and the columns (as [`Kernels::dot4`]).
    #[inline(always)]
    fn axpy4(self, alpha: [f64; 4], v: &[f64], c: [&mut [f64]; 4]) {
        let n = c.iter().fold(v.len(), |n, ck| n.min(ck.len()));
        for (a, ck) in alpha.into_iter().zip(c) {
            self.axpy(a, &v[..n], ck);
        }
    }
}

/// The portable kernels ([`super::dot`], [`super::axpy`]).
#[derive(Clone, Copy, Debug)]
pub struct Portable;

impl Kernels for Portable {
    #[inline(always)]
    fn dot(self, a: &[f64], b: &[f64]) -> f64 {
        dot(a, b)
    }
    #[inline(always)]
    fn axpy(self, alpha: f64, x: &[f64], y: &mut [f64]) {
        axpy(alpha, x, y)
    }
}

/// AVX2 and FMA kernels. A value exists only where the CPU has both
/// ([`Avx2Fma::detect`]): holding one is the proof that calling them is
/// sound.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub struct Avx2Fma(());

#[cfg(target_arch = "x86_64")]
impl Avx2Fma {
    /// `Some` where the CPU has AVX2 and FMA (the standard library caches
    /// the detection).
    #[inline]
    pub fn detect() -> Option<Self> {
        (std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")).then_some(Self(()))
    }
}

#[cfg(target_arch = "x86_64")]
impl Kernels for Avx2Fma {
    #[inline(always)]
    fn dot(self, a: &[f64], b: &[f64]) -> f64 {
        // SAFETY: `self` exists only where the CPU has AVX2 and FMA.
        unsafe { dot_avx2_fma(a, b) }
    }
    #[inline(always)]
    fn axpy(self, alpha: f64, x: &[f64], y: &mut [f64]) {
        // SAFETY: as above.
        unsafe { axpy_avx2_fma(alpha, x, y) }
    }
    #[inline(always)]
    fn dot4(self, v: &[f64], c: [&[f64]; 4]) -> [f64; 4] {
        // SAFETY: as above.
        unsafe { dot4_avx2_fma(v, c) }
    }
    #[inline(always)]
    fn axpy4(self, alpha: [f64; 4], v: &[f64], c: [&mut [f64]; 4]) {
        // SAFETY: as above.
        unsafe { axpy4_avx2_fma(alpha, v, c) }
    }
}

/// Four lanes summed to one.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
fn hsum_avx(x: std::arch::x86_64::__m256d) -> f64 {
    use std::arch::x86_64::*;
    let pair = _mm_add_pd(_mm256_castpd256_pd128(x), _mm256_extractf128_pd::<1>(x));
    _mm_cvtsd_f64(_mm_add_sd(pair, _mm_unpackhi_pd(pair, pair)))
}

/// [`Kernels::dot4`] in four-lane fused multiply-adds: each load of `v`
/// serves four columns, and the four columns' chains keep the units busy.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn dot4_avx2_fma(v: &[f64], c: [&[f64]; 4]) -> [f64; 4] {
    use std::arch::x86_64::*;
    let n = c.iter().fold(v.len(), |n, ck| n.min(ck.len()));
    let pv = v.as_ptr();
    let pc = c.map(|ck| ck.as_ptr());
    let mut acc = [[_mm256_setzero_pd(); 4]; 2];
    let mut i = 0;
    // SAFETY (the loads): every index read is below `n`, within `v` and
    // each column.
    while i + 8 <= n {
        for (h, acc_h) in acc.iter_mut().enumerate() {
            let o = i + 4 * h;
            let x = unsafe { _mm256_loadu_pd(pv.add(o)) };
            for (a, p) in acc_h.iter_mut().zip(pc) {
                *a = _mm256_fmadd_pd(x, unsafe { _mm256_loadu_pd(p.add(o)) }, *a);
            }
        }
        i += 8;
    }
    if i + 4 <= n {
        let x = unsafe { _mm256_loadu_pd(pv.add(i)) };
        for (a, p) in acc[0].iter_mut().zip(pc) {
            *a = _mm256_fmadd_pd(x, unsafe { _mm256_loadu_pd(p.add(i)) }, *a);
        }
        i += 4;
    }
    let mut out = [0.0; 4];
    for (k, o) in out.iter_mut().enumerate() {
        let mut s = hsum_avx(_mm256_add_pd(acc[0][k], acc[1][k]));
        for r in i..n {
            s = v[r].mul_add(c[k][r], s);
        }
        *o = s;
    }
    out
}

/// [`Kernels::axpy4`] in four-lane fused multiply-adds, `v` loaded once
/// for the four columns.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn axpy4_avx2_fma(alpha: [f64; 4], v: &[f64], c: [&mut [f64]; 4]) {
    use std::arch::x86_64::*;
    let n = c.iter().fold(v.len(), |n, ck| n.min(ck.len()));
    let pv = v.as_ptr();
    let [c0, c1, c2, c3] = c;
    let pc = [c0.as_mut_ptr(), c1.as_mut_ptr(), c2.as_mut_ptr(), c3.as_mut_ptr()];
    let va = alpha.map(|a| _mm256_set1_pd(a));
    let mut i = 0;
    // SAFETY (the loads and stores): every index is below `n`, within `v`
    // and each column; the columns are distinct mutable borrows, so none
    // overlaps another or `v`.
    while i + 4 <= n {
        let x = unsafe { _mm256_loadu_pd(pv.add(i)) };
        for (a, p) in va.iter().zip(pc) {
            unsafe {
                let r = _mm256_fmadd_pd(*a, x, _mm256_loadu_pd(p.add(i)));
                _mm256_storeu_pd(p.add(i), r);
            }
        }
        i += 4;
    }
    for r in i..n {
        for (a, p) in alpha.iter().zip(pc) {
            // SAFETY: `r < n`, within each column.
            unsafe { *p.add(r) = a.mul_add(v[r], *p.add(r)) };
        }
    }
}

/// [`dot`] in four-lane fused multiply-adds, four accumulators deep (an
/// FMA's latency is four cycles: fewer chains leave the units idle).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn dot_avx2_fma(a: &[f64], b: &[f64]) -> f64 {
    use std::arch::x86_64::*;
    let n = a.len().min(b.len());
    let (pa, pb) = (a.as_ptr(), b.as_ptr());
    let mut acc = [_mm256_setzero_pd(); 4];
    let mut i = 0;
    // SAFETY (the loads): every index read is below `n`, within both slices.
    while i + 16 <= n {
        for (k, acc_k) in acc.iter_mut().enumerate() {
            let o = i + 4 * k;
            *acc_k = _mm256_fmadd_pd(
                unsafe { _mm256_loadu_pd(pa.add(o)) },
                unsafe { _mm256_loadu_pd(pb.add(o)) },
                *acc_k,
            );
        }
        i += 16;
    }
    while i + 4 <= n {
        acc[0] = _mm256_fmadd_pd(
            unsafe { _mm256_loadu_pd(pa.add(i)) },
            unsafe { _mm256_loadu_pd(pb.add(i)) },
            acc[0],
        );
        i += 4;
    }
    let sum = _mm256_add_pd(_mm256_add_pd(acc[0], acc[1]), _mm256_add_pd(acc[2], acc[3]));
    let pair = _mm_add_pd(_mm256_castpd256_pd128(sum), _mm256_extractf128_pd::<1>(sum));
    let mut s = _mm_cvtsd_f64(_mm_add_sd(pair, _mm_unpackhi_pd(pair, pair)));
    for k in i..n {
        s = a[k].mul_add(b[k], s);
    }
    s
}

/// [`axpy`] in four-lane fused multiply-adds.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn axpy_avx2_fma(alpha: f64, x: &[f64], y: &mut [f64]) {
    use std::arch::x86_64::*;
    let n = x.len().min(y.len());
    let (px, py) = (x.as_ptr(), y.as_mut_ptr());
    let va = _mm256_set1_pd(alpha);
    let mut i = 0;
    // SAFETY (the loads and stores): every index is below `n`, within both
    // slices; `x` and `y` cannot overlap (`y` is borrowed mutably).
    while i + 4 <= n {
        unsafe {
            let r = _mm256_fmadd_pd(va, _mm256_loadu_pd(px.add(i)), _mm256_loadu_pd(py.add(i)));
            _mm256_storeu_pd(py.add(i), r);
        }
        i += 4;
    }
    for k in i..n {
        y[k] = alpha.mul_add(x[k], y[k]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both paths agree with a plain sum to round-off at every length
    /// (each tail and block case), `axpy` leaves `y` beyond the common
    /// length alone, and over slices of different lengths both use the
    /// common length only (either argument of `dot` the longer, `x` longer
    /// than `y` in `axpy`).
    #[test]
    fn both_paths_match_the_plain_sums_at_every_length() {
        check("portable", Portable);
        #[cfg(target_arch = "x86_64")]
        if let Some(k) = Avx2Fma::detect() {
            check("avx2+fma", k);
        }
    }

    fn check<K: Kernels>(name: &str, k: K) {
        for n in 0..40usize {
            let a: Vec<f64> = (0..n).map(|i| ((i * 37 % 17) as f64 - 8.0) / 3.0).collect();
            let b: Vec<f64> = (0..n).map(|i| ((i * 11 % 13) as f64 - 6.0) / 7.0).collect();
            let plain: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
            let scale = a.iter().zip(&b).map(|(x, y)| (x * y).abs()).sum::<f64>().max(1.0);
            let longer: Vec<f64> = a.iter().copied().chain([7.0, -3.0, 5.0]).collect();
            for (case, d) in [
                ("equal", k.dot(&a, &b)),
                ("a longer", k.dot(&longer, &b)),
                ("b longer", k.dot(&b, &longer)),
            ] {
                assert!(
                    (d - plain).abs() <= 1e-14 * scale,
                    "{name} dot, lengths {case}, at n = {n}: {d} vs {plain}"
                );
            }
            // Four columns at once: each as its own dot and axpy, with the
            // columns of different lengths (the shortest bounds each).
            let cols: Vec<Vec<f64>> = (0..4)
                .map(|c| (0..n + c).map(|i| ((i * (c + 3) % 11) as f64 - 5.0) / 4.0).collect())
                .collect();
            // Columns longer than `a`: `a`'s length bounds each. (A shorter
            // column bounds all four, on both paths: checked below.)
            let d4 = k.dot4(&a, [&cols[0], &cols[1], &cols[2], &cols[3]]);
            for (c, d) in d4.iter().enumerate() {
                let want: f64 = a.iter().zip(&cols[c]).map(|(x, y)| x * y).sum();
                assert!(
                    (d - want).abs() <= 1e-14 * scale.max(want.abs()) * 4.0,
                    "{name} dot4 column {c} at n = {n}"
                );
            }
            let mut four = cols.clone();
            let [c0, c1, c2, c3] = &mut four[..] else {
                unreachable!()
            };
            k.axpy4([0.5, -1.0, 2.0, 0.25], &a, [c0, c1, c2, c3]);
            for (c, alpha) in [0.5, -1.0, 2.0, 0.25].iter().enumerate() {
                for i in 0..cols[c].len() {
                    let want = if i < n { cols[c][i] + alpha * a[i] } else { cols[c][i] };
                    assert!(
                        (four[c][i] - want).abs() <= 1e-14 * 16.0,
                        "{name} axpy4 column {c} at {i} of {n}"
                    );
                }
            }
            // One column shorter than `a` bounds all four, on every path.
            if n > 0 {
                let short: Vec<f64> = cols[2][..n - 1].to_vec();
                let d4 = k.dot4(&a, [&cols[0], &cols[1], &short, &cols[3]]);
                for (c, d) in d4.iter().enumerate() {
                    let want: f64 = a[..n - 1].iter().zip(&cols[c]).map(|(x, y)| x * y).sum();
                    assert!(
                        (d - want).abs() <= 1e-14 * scale.max(want.abs()) * 4.0,
                        "{name} dot4 with a short column: column {c} at n = {n}"
                    );
                }
                let mut four = cols.clone();
                four[2].truncate(n - 1);
                let [c0, c1, c2, c3] = &mut four[..] else {
                    unreachable!()
                };
                k.axpy4([1.0; 4], &a, [c0, c1, c2, c3]);
                for c in [0, 1, 3] {
                    assert_eq!(
                        four[c][n - 1],
                        cols[c][n - 1],
                        "{name} axpy4 past the short column, {c}"
                    );
                }
            }
            let mut y = b.clone();
            y.push(42.0);
            k.axpy(0.5, &a, &mut y);
            assert_eq!(y[n], 42.0, "{name} axpy wrote past the common length");
            let mut short_y = b.clone();
            k.axpy(0.5, &longer, &mut short_y);
            for y in [&y[..n], &short_y[..]] {
                assert_eq!(y.len(), n);
                for i in 0..n {
                    assert!(
                        (y[i] - (b[i] + 0.5 * a[i])).abs() <= 1e-15 * 8.0,
                        "{name} axpy at {i} of {n}"
                    );
                }
            }
        }
    }
}
