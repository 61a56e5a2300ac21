//! `C ← β C + α A B` on nalgebra matrices and views of any strides, packed
//! into buffers each thread keeps, so that a product allocates nothing once
//! its thread has run one of that size.
//!
//! Why it exists: nalgebra hands every product above 5 × 5 to
//! matrixmultiply, which allocates its packing buffer afresh on each call;
//! those were 37 of the 101 allocations a camera frame made (issue 43's
//! counting allocator, `tests/alloc_frame.rs`), and a filter thread that
//! calls the allocator at every product can be held by another thread's
//! allocation. The product itself is the textbook blocked one (Goto and van
//! de Geijn's loops): `B` packed by `KC × NC` panels into strips of `NR`
//! columns, `A` by `MC × KC` blocks into strips of `MR` rows, and an
//! `MR × NR` register tile summed over `KC` in each kernel call. The kernel
//! is AVX2 with fused multiply-adds where the CPU has both (chosen at run
//! time, as `kernels.rs` does), a portable loop the compiler vectorises
//! elsewhere. Each entry of `A B` is the sum over `k` in order, so the two
//! paths differ by round-off only.

#![deny(unsafe_op_in_unsafe_fn)]

use std::cell::RefCell;

use nalgebra::{Dim, Matrix, RawStorage, RawStorageMut};

/// The register tile: `MR` rows by `NR` columns, `NR` 4 (AVX2: two
/// four-lane vectors a column, eight accumulators) or 8 (AVX-512: one
/// eight-lane vector a column, eight accumulators).
const MR: usize = 8;
/// The widest tile's columns: room for any tile.
const NR_MAX: usize = 8;
/// The depth of a packed panel: `KC` steps of the kernel per call.
const KC: usize = 256;
/// Rows of `A` packed at a time (`MC × KC` doubles: 256 kB).
const MC: usize = 128;
/// Columns of `B` packed at a time (`KC × NC` doubles: 2 MB).
const NC: usize = 1024;

thread_local! {
    /// The packed `A` block and `B` panel of this thread's products.
    static PACKED: RefCell<(Vec<f64>, Vec<f64>)> = const { RefCell::new((Vec::new(), Vec::new())) };
}

/// `C ← β C + α A B`. With `β = 0`, `C` is not read (a NaN in it does
/// not survive), as nalgebra's `gemm` promises. `C` must not overlap `A`
/// or `B`, which the borrows guarantee.
///
/// # Panics
/// If the shapes do not agree (`A` m × k, `B` k × n, `C` m × n).
pub fn gemm<R1, C1, S1, R2, C2, S2, R3, C3, S3>(
    c: &mut Matrix<f64, R1, C1, S1>,
    alpha: f64,
    a: &Matrix<f64, R2, C2, S2>,
    b: &Matrix<f64, R3, C3, S3>,
    beta: f64,
) where
    R1: Dim,
    C1: Dim,
    S1: RawStorageMut<f64, R1, C1>,
    R2: Dim,
    C2: Dim,
    S2: RawStorage<f64, R2, C2>,
    R3: Dim,
    C3: Dim,
    S3: RawStorage<f64, R3, C3>,
{
    let (m, n) = c.shape();
    let k = a.ncols();
    assert!(
        a.nrows() == m && b.nrows() == k && b.ncols() == n,
        "gemm: C {m}×{n} ← A {}×{k} · B {}×{}",
        a.nrows(),
        b.nrows(),
        b.ncols()
    );
    if m == 0 || n == 0 {
        return;
    }
    let (rsa, csa) = a.strides();
    let (rsb, csb) = b.strides();
    let (rsc, csc) = c.strides();
    let at = Strided {
        ptr: a.as_ptr(),
        rs: rsa,
        cs: csa,
    };
    let bt = Strided {
        ptr: b.as_ptr(),
        rs: rsb,
        cs: csb,
    };
    let ct = StridedMut {
        ptr: c.as_mut_ptr(),
        rs: rsc,
        cs: csc,
    };
    if m * n * k <= SMALL {
        // SAFETY: as below.
        unsafe { gemm_small(m, n, k, alpha, at, bt, beta, ct) };
        return;
    }
    let run = |packed: &mut (Vec<f64>, Vec<f64>)| {
        // SAFETY: the three descriptors come from nalgebra storages of the
        // shapes checked above, so every index below (rows < m or k,
        // columns < k or n) is inside its matrix; `c` is borrowed mutably
        // apart from `a` and `b`.
        unsafe { gemm_strided(m, n, k, alpha, at, bt, beta, ct, &mut packed.0, &mut packed.1) }
    };
    // A product never calls another, so the buffers are never borrowed
    // twice on one thread; should that change, the product still runs, on
    // buffers of its own.
    let done = PACKED.try_with(|p| p.try_borrow_mut().map(|mut p| run(&mut p)).is_ok());
    if done != Ok(true) {
        run(&mut (Vec::new(), Vec::new()));
    }
}

#[derive(Clone, Copy)]
struct Strided {
    ptr: *const f64,
    rs: usize,
    cs: usize,
}

#[derive(Clone, Copy)]
struct StridedMut {
    ptr: *mut f64,
    rs: usize,
    cs: usize,
}

/// Products of at most this many multiply-adds skip the packing: a track's
/// Jacobian blocks (`2m × 3` by `3 × 3`) would pay more to pack than to
/// multiply.
const SMALL: usize = 4096;

/// `C ← β C + α A B` column by column, no packing: for small products.
///
/// # Safety
/// As [`gemm_strided`].
#[allow(clippy::too_many_arguments)]
unsafe fn gemm_small(m: usize, n: usize, k: usize, alpha: f64, a: Strided, b: Strided, beta: f64, c: StridedMut) {
    for j in 0..n {
        // SAFETY: every index is inside its matrix (i < m, p < k, j < n).
        unsafe {
            let cj = c.ptr.add(j * c.cs);
            for i in 0..m {
                let cij = cj.add(i * c.rs);
                *cij = if beta == 0.0 { 0.0 } else { beta * *cij };
            }
            if a.rs == 1 && c.rs == 1 {
                // Contiguous columns: a vectorised axpy each.
                let cj = std::slice::from_raw_parts_mut(cj, m);
                for p in 0..k {
                    let bpj = alpha * *b.ptr.add(p * b.rs + j * b.cs);
                    let ap = std::slice::from_raw_parts(a.ptr.add(p * a.cs), m);
                    for (x, &y) in cj.iter_mut().zip(ap) {
                        *x += y * bpj;
                    }
                }
                continue;
            }
            for p in 0..k {
                let bpj = alpha * *b.ptr.add(p * b.rs + j * b.cs);
                let ap = a.ptr.add(p * a.cs);
                for i in 0..m {
                    *cj.add(i * c.rs) += *ap.add(i * a.rs) * bpj;
                }
            }
        }
    }
}

/// The blocked loops over a product whose operands are given by pointer and
/// strides, on the kernel this CPU has.
///
/// # Safety
/// `a` must be valid for reads of `m × k` entries at its strides, `b` of
/// `k × n`, `c` for reads and writes of `m × n`, and `c` must not overlap
/// `a` or `b`.
#[allow(clippy::too_many_arguments)]
unsafe fn gemm_strided(
    m: usize,
    n: usize,
    k: usize,
    alpha: f64,
    a: Strided,
    b: Strided,
    beta: f64,
    c: StridedMut,
    pa: &mut Vec<f64>,
    pb: &mut Vec<f64>,
) {
    if k == 0 {
        for j in 0..n {
            for i in 0..m {
                // SAFETY: i < m, j < n (the caller's contract).
                unsafe {
                    let cij = c.ptr.add(i * c.rs + j * c.cs);
                    *cij = if beta == 0.0 { 0.0 } else { beta * *cij };
                }
            }
        }
        return;
    }
    // Room for the largest block and panel, grown once per thread; the
    // packing writes every entry a kernel reads, padding included.
    let need_a = MC.min(m).div_ceil(MR) * MR * KC.min(k);
    let need_b = NC.min(n).div_ceil(NR_MAX) * NR_MAX * KC.min(k);
    if pa.len() < need_a {
        pa.resize(need_a, 0.0);
    }
    if pb.len() < need_b {
        pb.resize(need_b, 0.0);
    }
    match Kernel::detect() {
        // SAFETY: the caller's contract.
        Kernel::Portable => unsafe { gemm_body::<PORTABLE, 4>(m, n, k, alpha, a, b, beta, c, pa, pb) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the variant exists only where the CPU has AVX2 and FMA.
        Kernel::Avx2Fma => unsafe { gemm_avx2_fma(m, n, k, alpha, a, b, beta, c, pa, pb) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the variant exists only where the CPU has AVX-512F.
        Kernel::Avx512 => unsafe { gemm_avx512(m, n, k, alpha, a, b, beta, c, pa, pb) },
    }
}

/// [`gemm_body`] compiled for AVX2 and FMA, its packing loops included.
///
/// # Safety
/// As [`gemm_strided`]; the CPU must have AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn gemm_avx2_fma(
    m: usize,
    n: usize,
    k: usize,
    alpha: f64,
    a: Strided,
    b: Strided,
    beta: f64,
    c: StridedMut,
    pa: &mut [f64],
    pb: &mut [f64],
) {
    // SAFETY: the caller's contract.
    unsafe { gemm_body::<AVX2, 4>(m, n, k, alpha, a, b, beta, c, pa, pb) }
}

/// [`gemm_body`] compiled for AVX-512F, on 8 × 8 tiles.
///
/// # Safety
/// As [`gemm_strided`]; the CPU must have AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
unsafe fn gemm_avx512(
    m: usize,
    n: usize,
    k: usize,
    alpha: f64,
    a: Strided,
    b: Strided,
    beta: f64,
    c: StridedMut,
    pa: &mut [f64],
    pb: &mut [f64],
) {
    // SAFETY: the caller's contract.
    unsafe { gemm_body::<AVX512, 8>(m, n, k, alpha, a, b, beta, c, pa, pb) }
}

/// The kernels [`gemm_body`] can be compiled with.
const PORTABLE: u8 = 0;
const AVX2: u8 = 1;
const AVX512: u8 = 2;

/// Goto's loops: `B` by `KC × NC` panels, `A` by `MC × KC` blocks, an
/// `MR × NR` tile of C per kernel call. `PATH` picks the kernel: `AVX2`
/// only from [`gemm_avx2_fma`], `AVX512` only from [`gemm_avx512`].
///
/// # Safety
/// As [`gemm_strided`], with `k > 0` and `pa`, `pb` at least as long as it
/// makes them.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
unsafe fn gemm_body<const PATH: u8, const NR: usize>(
    m: usize,
    n: usize,
    k: usize,
    alpha: f64,
    a: Strided,
    b: Strided,
    beta: f64,
    c: StridedMut,
    pa: &mut [f64],
    pb: &mut [f64],
) {
    let mut tile = [0.0f64; MR * NR_MAX];
    for jc in (0..n).step_by(NC) {
        let nc = NC.min(n - jc);
        let n_strips = nc.div_ceil(NR);
        for pc in (0..k).step_by(KC) {
            let kc = KC.min(k - pc);
            // SAFETY: the panel's rows pc.. < k and columns jc.. < n are
            // inside B; `pb` holds n_strips · kc · NR.
            unsafe { pack_b::<NR>(kc, nc, b.ptr.add(pc * b.rs + jc * b.cs), b.rs, b.cs, pb) };
            // The first depth block scales C by β; the later ones add.
            let scale = if pc > 0 || beta == 1.0 {
                Scale::Add
            } else if beta == 0.0 {
                Scale::Overwrite
            } else {
                Scale::Beta(beta)
            };
            for ic in (0..m).step_by(MC) {
                let mc = MC.min(m - ic);
                let m_strips = mc.div_ceil(MR);
                // SAFETY: as for B.
                unsafe { pack_a(kc, mc, a.ptr.add(ic * a.rs + pc * a.cs), a.rs, a.cs, pa) };
                for sj in 0..n_strips {
                    let b_strip = &pb[sj * kc * NR..(sj + 1) * kc * NR];
                    let cols = NR.min(nc - sj * NR);
                    for si in 0..m_strips {
                        let a_strip = &pa[si * kc * MR..(si + 1) * kc * MR];
                        let rows = MR.min(mc - si * MR);
                        let tile_c = StridedMut {
                            ptr: c.ptr.wrapping_add((ic + si * MR) * c.rs + (jc + sj * NR) * c.cs),
                            ..c
                        };
                        // SAFETY: the tile's `rows × cols` entries are
                        // inside C (rows < m, columns < n); PATH is AVX2 or
                        // AVX512 only on a CPU that has them (NR 4 and 8).
                        unsafe {
                            match PATH {
                                #[cfg(target_arch = "x86_64")]
                                AVX2 => {
                                    kernel_avx2_fma(kc, a_strip, b_strip, alpha, scale, tile_c, rows, cols, &mut tile)
                                }
                                #[cfg(target_arch = "x86_64")]
                                AVX512 => {
                                    kernel_avx512(kc, a_strip, b_strip, alpha, scale, tile_c, rows, cols, &mut tile)
                                }
                                _ => {
                                    kernel_portable::<NR>(kc, a_strip, b_strip, &mut tile);
                                    write_tile::<NR>(&tile, alpha, scale, tile_c, rows, cols);
                                }
                            }
                        }
                    }
                }
            }
        }
    }
}

/// `mc × kc` of A (at `a`, strides `rs`, `cs`) into strips of `MR` rows,
/// each `kc` columns of `MR`, zero below the last row.
///
/// # Safety
/// `a` valid for `mc × kc` entries at its strides; `out` holds
/// `⌈mc/MR⌉ · MR · kc`.
#[inline(always)]
unsafe fn pack_a(kc: usize, mc: usize, a: *const f64, rs: usize, cs: usize, out: &mut [f64]) {
    let out = &mut out[..mc.div_ceil(MR) * MR * kc];
    for (s, strip) in out.chunks_exact_mut(MR * kc).enumerate() {
        let rows = MR.min(mc - s * MR);
        // SAFETY: rows s·MR.. < mc, columns < kc (the caller's contract).
        let a = unsafe { a.add(s * MR * rs) };
        for (p, dst) in strip.chunks_exact_mut(MR).enumerate() {
            if rows == MR && rs == 1 {
                // SAFETY: MR contiguous rows of column p.
                dst.copy_from_slice(unsafe { std::slice::from_raw_parts(a.add(p * cs), MR) });
            } else {
                for (ii, d) in dst.iter_mut().enumerate() {
                    // SAFETY: ii < rows is inside A; the rest is padding.
                    *d = if ii < rows {
                        unsafe { *a.add(ii * rs + p * cs) }
                    } else {
                        0.0
                    };
                }
            }
        }
    }
}

/// `kc × nc` of B into strips of `NR` columns, each `kc` rows of `NR`, zero
/// right of the last column.
///
/// # Safety
/// `b` valid for `kc × nc` entries at its strides; `out` holds
/// `⌈nc/NR⌉ · NR · kc`.
#[inline(always)]
unsafe fn pack_b<const NR: usize>(kc: usize, nc: usize, b: *const f64, rs: usize, cs: usize, out: &mut [f64]) {
    let out = &mut out[..nc.div_ceil(NR) * NR * kc];
    for (s, strip) in out.chunks_exact_mut(NR * kc).enumerate() {
        let cols = NR.min(nc - s * NR);
        // SAFETY: columns s·NR.. < nc, rows < kc (the caller's contract).
        let b = unsafe { b.add(s * NR * cs) };
        if cols == NR {
            // Rows of the strip at a time: NR reads, one NR-wide write.
            for (p, dst) in strip.chunks_exact_mut(NR).enumerate() {
                let mut row = [0.0; NR];
                for (jj, d) in row.iter_mut().enumerate() {
                    // SAFETY: row p < kc, column jj < NR of the strip.
                    *d = unsafe { std::ptr::read(b.add(p * rs + jj * cs)) };
                }
                dst.copy_from_slice(&row);
            }
        } else {
            for (p, dst) in strip.chunks_exact_mut(NR).enumerate() {
                for (jj, d) in dst.iter_mut().enumerate() {
                    // SAFETY: jj < cols is inside B; the rest is padding.
                    *d = if jj < cols {
                        unsafe { *b.add(p * rs + jj * cs) }
                    } else {
                        0.0
                    };
                }
            }
        }
    }
}

/// What a tile does with the entries of C it lands on.
#[derive(Clone, Copy)]
enum Scale {
    /// `C ← α AB` (β = 0: C is not read).
    Overwrite,
    /// `C ← β C + α AB`.
    Beta(f64),
    /// `C ← C + α AB` (the depth blocks after the first).
    Add,
}

impl Scale {
    #[inline(always)]
    fn apply(self, c: f64, ab: f64) -> f64 {
        match self {
            Self::Overwrite => ab,
            Self::Beta(beta) => beta * c + ab,
            Self::Add => c + ab,
        }
    }
}

/// Writes `α tile` into C's `rows × cols` entries at `c`.
///
/// # Safety
/// `c` must be valid for reads and writes of `rows × cols` entries at its
/// strides.
#[inline(always)]
unsafe fn write_tile<const NR: usize>(
    tile: &[f64; MR * NR_MAX],
    alpha: f64,
    scale: Scale,
    c: StridedMut,
    rows: usize,
    cols: usize,
) {
    for jj in 0..cols {
        for ii in 0..rows {
            // SAFETY: ii < rows, jj < cols (the caller's contract).
            unsafe {
                let cij = c.ptr.add(ii * c.rs + jj * c.cs);
                *cij = scale.apply(*cij, alpha * tile[jj * MR + ii]);
            }
        }
    }
}

/// The `MR × NR` kernel for this CPU.
#[derive(Clone, Copy)]
enum Kernel {
    Portable,
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

impl Kernel {
    fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                return Self::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                return Self::Avx2Fma;
            }
        }
        Self::Portable
    }

    /// `C ← scale(C) + α Σ_p a_p b_pᵀ` over `kc` steps on one tile, for the
    /// tests: `a` holds `kc` columns of `MR` rows, `b` `kc` rows of
    /// [`Kernel::nr`] columns, and `c` the tile's `rows × cols` entries.
    ///
    /// # Safety
    /// `c` must be valid for reads and writes of `rows × cols` entries at
    /// its strides, `rows ≤ MR`, `cols ≤ nr`.
    #[cfg(test)]
    #[allow(clippy::too_many_arguments)]
    unsafe fn run(
        self,
        kc: usize,
        a: &[f64],
        b: &[f64],
        alpha: f64,
        scale: Scale,
        c: StridedMut,
        rows: usize,
        cols: usize,
    ) {
        assert!(a.len() >= kc * MR && b.len() >= kc * self.nr() && rows <= MR && cols <= self.nr());
        let mut tile = [0.0; MR * NR_MAX];
        match self {
            // SAFETY: the caller's contract.
            Self::Portable => unsafe {
                kernel_portable::<4>(kc, a, b, &mut tile);
                write_tile::<4>(&tile, alpha, scale, c, rows, cols);
            },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the variants exist only where the CPU has their
            // features; the lengths are checked above, C's by the caller.
            Self::Avx2Fma => unsafe { tile_alone::<AVX2>(kc, a, b, alpha, scale, c, rows, cols, &mut tile) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as above.
            Self::Avx512 => unsafe { tile_alone::<AVX512>(kc, a, b, alpha, scale, c, rows, cols, &mut tile) },
        }
    }

    /// The tile's columns on this path.
    #[cfg(test)]
    fn nr(self) -> usize {
        match self {
            #[cfg(target_arch = "x86_64")]
            Self::Avx512 => 8,
            _ => 4,
        }
    }
}

/// `tile = Σ_p a_p b_pᵀ` over `kc` steps, column-major `MR × NR`: the
/// portable kernel, which the compiler vectorises for the baseline CPU.
#[inline(always)]
fn kernel_portable<const NR: usize>(kc: usize, a: &[f64], b: &[f64], tile: &mut [f64; MR * NR_MAX]) {
    let mut acc = [[0.0f64; MR]; NR];
    for (ap, bp) in a.chunks_exact(MR).zip(b.chunks_exact(NR)).take(kc) {
        for (accj, &bj) in acc.iter_mut().zip(bp) {
            for (x, &ai) in accj.iter_mut().zip(ap) {
                *x += ai * bj;
            }
        }
    }
    for (j, accj) in acc.iter().enumerate() {
        tile[j * MR..(j + 1) * MR].copy_from_slice(accj);
    }
}

/// The tile in AVX2 with fused multiply-adds (`NR` = 4): eight
/// accumulators of four lanes, two loads of `a` and four broadcasts of `b`
/// a step. A whole tile of a column-major C is read and written as
/// vectors. Inlined into functions compiled for AVX2 and FMA.
///
/// # Safety
/// The CPU must have AVX2 and FMA; `a` must hold `kc · MR` and `b`
/// `kc · 4` entries; `c` valid for `rows × cols` entries at its strides.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn kernel_avx2_fma(
    kc: usize,
    a: &[f64],
    b: &[f64],
    alpha: f64,
    scale: Scale,
    c: StridedMut,
    rows: usize,
    cols: usize,
    tile: &mut [f64; MR * NR_MAX],
) {
    use std::arch::x86_64::*;
    const NR: usize = 4;
    let (ap, bp) = (a.as_ptr(), b.as_ptr());
    // SAFETY: the CPU has AVX (the caller's contract).
    let mut acc = [[unsafe { _mm256_setzero_pd() }; 2]; NR];
    for p in 0..kc {
        // SAFETY: p < kc, and `a`, `b` hold kc steps (the caller's contract).
        unsafe {
            let a0 = _mm256_loadu_pd(ap.add(p * MR));
            let a1 = _mm256_loadu_pd(ap.add(p * MR + 4));
            for (j, cj) in acc.iter_mut().enumerate() {
                let bj = _mm256_broadcast_sd(&*bp.add(p * NR + j));
                cj[0] = _mm256_fmadd_pd(a0, bj, cj[0]);
                cj[1] = _mm256_fmadd_pd(a1, bj, cj[1]);
            }
        }
    }
    // SAFETY: as above.
    let va = unsafe { _mm256_set1_pd(alpha) };
    if rows == MR && cols == NR && c.rs == 1 {
        for (j, cj) in acc.iter().enumerate() {
            // SAFETY: a whole tile of contiguous columns inside C (the
            // caller's contract).
            unsafe {
                let col = c.ptr.add(j * c.cs);
                for (h, &x) in cj.iter().enumerate() {
                    let at = col.add(4 * h);
                    let out = match scale {
                        Scale::Overwrite => _mm256_mul_pd(va, x),
                        Scale::Beta(beta) => {
                            _mm256_fmadd_pd(va, x, _mm256_mul_pd(_mm256_set1_pd(beta), _mm256_loadu_pd(at)))
                        }
                        Scale::Add => _mm256_fmadd_pd(va, x, _mm256_loadu_pd(at)),
                    };
                    _mm256_storeu_pd(at, out);
                }
            }
        }
        return;
    }
    for (j, cj) in acc.iter().enumerate() {
        // SAFETY: the tile holds MR · NR_MAX entries.
        unsafe {
            _mm256_storeu_pd(tile.as_mut_ptr().add(j * MR), cj[0]);
            _mm256_storeu_pd(tile.as_mut_ptr().add(j * MR + 4), cj[1]);
        }
    }
    // SAFETY: the caller's contract.
    unsafe { write_tile::<NR>(tile, alpha, scale, c, rows, cols) };
}

/// The tile in AVX-512 (`NR` = 8): eight accumulators of eight lanes, one
/// load of `a` and eight broadcasts of `b` a step. Inlined into functions
/// compiled for AVX-512F.
///
/// # Safety
/// The CPU must have AVX-512F; `a` must hold `kc · MR` and `b` `kc · 8`
/// entries; `c` valid for `rows × cols` entries at its strides.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn kernel_avx512(
    kc: usize,
    a: &[f64],
    b: &[f64],
    alpha: f64,
    scale: Scale,
    c: StridedMut,
    rows: usize,
    cols: usize,
    tile: &mut [f64; MR * NR_MAX],
) {
    use std::arch::x86_64::*;
    const NR: usize = 8;
    let (ap, bp) = (a.as_ptr(), b.as_ptr());
    // SAFETY: the CPU has AVX-512F (the caller's contract).
    let mut acc = [unsafe { _mm512_setzero_pd() }; NR];
    for p in 0..kc {
        // SAFETY: p < kc, and `a`, `b` hold kc steps (the caller's contract).
        unsafe {
            let a0 = _mm512_loadu_pd(ap.add(p * MR));
            for (j, cj) in acc.iter_mut().enumerate() {
                let bj = _mm512_set1_pd(*bp.add(p * NR + j));
                *cj = _mm512_fmadd_pd(a0, bj, *cj);
            }
        }
    }
    // SAFETY: as above.
    let va = unsafe { _mm512_set1_pd(alpha) };
    if rows == MR && cols == NR && c.rs == 1 {
        for (j, &x) in acc.iter().enumerate() {
            // SAFETY: a whole tile of contiguous columns inside C (the
            // caller's contract).
            unsafe {
                let at = c.ptr.add(j * c.cs);
                let out = match scale {
                    Scale::Overwrite => _mm512_mul_pd(va, x),
                    Scale::Beta(beta) => {
                        _mm512_fmadd_pd(va, x, _mm512_mul_pd(_mm512_set1_pd(beta), _mm512_loadu_pd(at)))
                    }
                    Scale::Add => _mm512_fmadd_pd(va, x, _mm512_loadu_pd(at)),
                };
                _mm512_storeu_pd(at, out);
            }
        }
        return;
    }
    for (j, &x) in acc.iter().enumerate() {
        // SAFETY: the tile holds MR · NR_MAX entries.
        unsafe { _mm512_storeu_pd(tile.as_mut_ptr().add(j * MR), x) };
    }
    // SAFETY: the caller's contract.
    unsafe { write_tile::<NR>(tile, alpha, scale, c, rows, cols) };
}

/// One tile of a SIMD path on its own (the tests' [`Kernel::run`]),
/// compiled for both paths' features; `PATH` picks which.
///
/// # Safety
/// As the path's kernel; the CPU must have AVX-512F for `AVX512`, AVX2 and
/// FMA for `AVX2`.
#[cfg(all(test, target_arch = "x86_64"))]
#[target_feature(enable = "avx2,fma,avx512f")]
#[allow(clippy::too_many_arguments)]
unsafe fn tile_alone<const PATH: u8>(
    kc: usize,
    a: &[f64],
    b: &[f64],
    alpha: f64,
    scale: Scale,
    c: StridedMut,
    rows: usize,
    cols: usize,
    tile: &mut [f64; MR * NR_MAX],
) {
    // SAFETY: the caller's contract.
    unsafe {
        if PATH == AVX512 {
            kernel_avx512(kc, a, b, alpha, scale, c, rows, cols, tile)
        } else {
            kernel_avx2_fma(kc, a, b, alpha, scale, c, rows, cols, tile)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random(rng: &mut ChaCha8Rng, r: usize, c: usize) -> DMatrix<f64> {
        DMatrix::from_fn(r, c, |_, _| rng.random_range(-1.0..1.0))
    }

    /// Against the textbook triple loop, over shapes that cross every
    /// block edge (MR, NR, KC, MC) and are empty, and on strided views
    /// (transposes, sub-blocks).
    #[test]
    fn gemm_matches_the_triple_loop_on_every_shape_and_stride() {
        let mut rng = ChaCha8Rng::seed_from_u64(43);
        let sizes = [0, 1, 3, 4, 5, 7, 8, 9, 17, 130, 257];
        for &m in &sizes {
            for &n in &[0, 1, 4, 5, 9, 33] {
                for &k in &[0, 1, 2, 8, 255, 257, 300] {
                    if m * n * k > 2_000_000 {
                        continue;
                    }
                    let a = random(&mut rng, m, k);
                    let b = random(&mut rng, k, n);
                    let c0 = random(&mut rng, m, n);
                    for (alpha, beta) in [(1.0, 0.0), (-0.5, 1.0), (2.0, -3.0)] {
                        let mut want = c0.clone() * beta;
                        for j in 0..n {
                            for i in 0..m {
                                want[(i, j)] += alpha * (0..k).map(|p| a[(i, p)] * b[(p, j)]).sum::<f64>();
                            }
                        }
                        let mut c = c0.clone();
                        gemm(&mut c, alpha, &a, &b, beta);
                        let err = (&c - &want).abs().max();
                        assert!(
                            err <= 1e-12 * (k as f64 + 1.0),
                            "{m}×{k}·{k}×{n} α {alpha} β {beta}: {err}"
                        );
                    }
                }
            }
        }
        // Strided operands: Aᵀ's rows as a view of a wider matrix, a
        // sub-block of C.
        let big_a = random(&mut rng, 40, 60);
        let b = random(&mut rng, 19, 11);
        let mut c = random(&mut rng, 30, 20);
        let at = big_a.transpose();
        let a_view = at.view((5, 2), (13, 19));
        let want = {
            let mut w = c.clone();
            let sub = w.view((3, 4), (13, 11)) * 0.5 + a_view * &b * 1.5;
            w.view_mut((3, 4), (13, 11)).copy_from(&sub);
            w
        };
        gemm(&mut c.view_mut((3, 4), (13, 11)), 1.5, &a_view, &b, 0.5);
        assert!((&c - &want).abs().max() < 1e-13);
        // A row-stride view as the left operand (nalgebra's small-product
        // path read such views out of bounds: docs/performance.md).
        let rows = DMatrix::from_row_slice(2, 3, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let v = nalgebra::DMatrixView::from_slice_with_strides(rows.as_slice(), 3, 2, 2, 1);
        let mut out = DMatrix::zeros(3, 1);
        gemm(&mut out, 1.0, &v, &DMatrix::from_column_slice(2, 1, &[1.0, 1.0]), 0.0);
        assert_eq!(
            out.as_slice(),
            (&rows.transpose() * DMatrix::from_element(2, 1, 1.0)).as_slice()
        );
    }

    /// β = 0 does not read C: a NaN there is overwritten.
    #[test]
    fn gemm_with_beta_zero_ignores_what_c_held() {
        let a = DMatrix::from_element(9, 3, 1.0);
        let b = DMatrix::from_element(3, 5, 2.0);
        let mut c = DMatrix::from_element(9, 5, f64::NAN);
        gemm(&mut c, 1.0, &a, &b, 0.0);
        assert!(c.iter().all(|&x| x == 6.0));
        let mut c = DMatrix::from_element(9, 5, f64::NAN);
        gemm(&mut c, 1.0, &DMatrix::zeros(9, 0), &DMatrix::zeros(0, 5), 0.0);
        assert!(c.iter().all(|&x| x == 0.0));
    }

    /// Each SIMD kernel agrees with the portable one to round-off on whole
    /// and partial tiles, in each of the ways a tile lands on C.
    #[test]
    fn the_kernels_agree() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let kc = 37;
        let a: Vec<f64> = (0..kc * MR).map(|_| rng.random_range(-1.0..1.0)).collect();
        let b: Vec<f64> = (0..kc * NR_MAX).map(|_| rng.random_range(-1.0..1.0)).collect();
        let c0: Vec<f64> = (0..MR * NR_MAX).map(|_| rng.random_range(-1.0..1.0)).collect();
        let fast = Kernel::detect();
        let nr = fast.nr();
        // The portable kernel on the fast one's columns: b regrouped by 4.
        let b4: Vec<f64> = (0..kc)
            .flat_map(|p| (0..4).map(move |j| (p, j)))
            .map(|(p, j)| b[p * nr + j])
            .collect();
        let b4_hi: Vec<f64> = (0..kc)
            .flat_map(|p| (0..4).map(move |j| (p, j)))
            .map(|(p, j)| if nr == 8 { b[p * nr + 4 + j] } else { 0.0 })
            .collect();
        for scale in [Scale::Overwrite, Scale::Beta(0.5), Scale::Add] {
            for (rows, cols) in [(MR, nr), (3, nr), (MR, 1)] {
                let mut want = c0.clone();
                let mut got = c0.clone();
                let col = |v: &mut Vec<f64>, j0: usize| StridedMut {
                    ptr: v[j0 * MR..].as_mut_ptr(),
                    rs: 1,
                    cs: MR,
                };
                // SAFETY: C is MR × NR_MAX, column-major; each call's
                // columns are inside it.
                unsafe {
                    Kernel::Portable.run(kc, &a, &b4, -1.5, scale, col(&mut want, 0), rows, cols.min(4));
                    if cols > 4 {
                        Kernel::Portable.run(kc, &a, &b4_hi, -1.5, scale, col(&mut want, 4), rows, cols - 4);
                    }
                    fast.run(kc, &a, &b, -1.5, scale, col(&mut got, 0), rows, cols);
                }
                for (x, y) in want.iter().zip(&got) {
                    assert!((x - y).abs() < 1e-13, "{x} {y}");
                }
            }
        }
    }
}
