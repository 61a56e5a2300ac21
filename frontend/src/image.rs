//! Grey images and their pyramids: why this exists is that every stage of
//! the tracker (corner scores, Lucas–Kanade, the forward–backward check)
//! reads intensities at sub-pixel positions on several scales, and one small
//! type with bilinear sampling serves them all without an image library.
//! Image buffers are reused from frame to frame, so no image is allocated
//! per frame once the first frame has sized them; the tracker's other lists
//! are kept the same way (`frontend/tests/no_alloc.rs` counts a lap of the
//! rendered racetrack at no allocation once re-identification's store is
//! full).

/// A grey image, intensities as `f32` in `[0, 255]`, row-major.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Gray {
    pub width: usize,
    pub height: usize,
    pub px: Vec<f32>,
}

impl Gray {
    /// A `width × height` image of zeros.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            px: vec![0.0; width * height],
        }
    }

    /// From 8-bit grey pixels (`bytes.len() == width * height`).
    pub fn from_u8(width: usize, height: usize, bytes: &[u8]) -> Option<Self> {
        (bytes.len() == width * height).then(|| Self {
            width,
            height,
            px: bytes.iter().map(|&b| f32::from(b)).collect(),
        })
    }

    /// Overwrites this image with 8-bit grey pixels, reusing its buffer
    /// (`bytes.len()` must be `width * height`; false, unchanged, if not).
    pub fn set_from_u8(&mut self, width: usize, height: usize, bytes: &[u8]) -> bool {
        if bytes.len() != width * height {
            return false;
        }
        self.width = width;
        self.height = height;
        self.px.clear();
        self.px.extend(bytes.iter().map(|&b| f32::from(b)));
        true
    }

    /// The pixel at integer `(x, y)`, clamped to the border.
    #[inline]
    pub fn at(&self, x: isize, y: isize) -> f32 {
        let xc = x.clamp(0, self.width as isize - 1) as usize;
        let yc = y.clamp(0, self.height as isize - 1) as usize;
        self.px[yc * self.width + xc]
    }

    /// Bilinear sample at `(x, y)` (pixel centres at integers), clamped.
    #[inline]
    pub fn sample(&self, x: f32, y: f32) -> f32 {
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (xi, yi) = (x0 as isize, y0 as isize);
        let a = self.at(xi, yi);
        let b = self.at(xi + 1, yi);
        let c = self.at(xi, yi + 1);
        let d = self.at(xi + 1, yi + 1);
        (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy
    }

    /// Bilinear sample at the pixel of index `k` (row-major) moved by the
    /// fractions `fx, fy` in `[0, 1)` right and down: the pixel right of
    /// it and the two below must exist (a point at least one pixel inside
    /// the image, [`Gray::inside`] with margin 1, has them). No clamping:
    /// callers that place many samples compute `k` and the fractions in a
    /// pass of their own.
    #[inline]
    pub fn sample_at(&self, k: usize, fx: f32, fy: f32) -> f32 {
        let w = self.width;
        let p = &self.px[k..k + w + 2];
        let top = p[0] + fx * (p[1] - p[0]);
        let bottom = p[w] + fx * (p[w + 1] - p[w]);
        top + fy * (bottom - top)
    }

    /// Whether `(x, y)` lies at least `margin` pixels inside the image.
    #[inline]
    pub fn inside(&self, x: f32, y: f32, margin: f32) -> bool {
        x >= margin && y >= margin && x <= self.width as f32 - 1.0 - margin && y <= self.height as f32 - 1.0 - margin
    }

    /// Bilinear samples of the `(2r+1)²` window centred at `(x, y)`, row by
    /// row, into `out`. Every sample of a window shares the same fractional
    /// offset, so the four weights are computed once; the window (plus one
    /// pixel) must lie inside the image ([`Gray::inside`] with margin `r + 1`).
    pub fn window(&self, x: f32, y: f32, r: usize, out: &mut [f32]) {
        // Inside, so positive: truncation is the floor.
        let (x0, y0) = (x as usize, y as usize);
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let (w00, w10, w01, w11) = ((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
        let side = 2 * r + 1;
        let (xs, ys) = (x0 - r, y0 - r);
        for (j, o) in out[..side * side].chunks_exact_mut(side).enumerate() {
            // Slices of known length, so the loop runs without bounds
            // checks (and vectorises).
            let at = (ys + j) * self.width + xs;
            let row0 = &self.px[at..at + side + 1];
            let row1 = &self.px[at + self.width..at + self.width + side + 1];
            let at = |o: &mut [f32], i: usize| {
                o[i] = w00 * row0[i] + w10 * row0[i + 1] + w01 * row1[i] + w11 * row1[i + 1];
            };
            if side < 4 {
                (0..side).for_each(|i| at(o, i));
                continue;
            }
            // Blocks of four (one vector each), the last one overlapping
            // the one before when the side is not a multiple of four, so
            // no pixel is left to a scalar tail.
            let block = |o: &mut [f32], i: usize| {
                let (o, a, b) = (&mut o[i..i + 4], &row0[i..i + 5], &row1[i..i + 5]);
                for k in 0..4 {
                    o[k] = w00 * a[k] + w10 * a[k + 1] + w01 * b[k] + w11 * b[k + 1];
                }
            };
            let mut i = 0;
            while i + 4 <= side {
                block(o, i);
                i += 4;
            }
            if i < side {
                block(o, side - 4);
            }
        }
    }

    /// Writes the image halved in each direction into `out`: each output
    /// pixel the mean of a 2×2 block (a box filter, enough against
    /// aliasing for Lucas–Kanade's smooth windows).
    pub fn half_into(&self, out: &mut Gray) {
        let (w, h) = (self.width / 2, self.height / 2);
        out.width = w;
        out.height = h;
        out.px.resize(w * h, 0.0);
        for y in 0..h {
            // Slices of known length, so the loop vectorises.
            let r0 = &self.px[2 * y * self.width..][..2 * w];
            let r1 = &self.px[(2 * y + 1) * self.width..][..2 * w];
            let o = &mut out.px[y * w..(y + 1) * w];
            for x in 0..w {
                o[x] = 0.25 * (r0[2 * x] + r0[2 * x + 1] + r1[2 * x] + r1[2 * x + 1]);
            }
        }
    }
}

/// How much of a pixel's independent noise (its sigma) is left after
/// [`Gray::smooth_into`]: each pass keeps `√(1/16 + 4/16 + 1/16)`, and the
/// two passes multiply.
pub const SMOOTH_NOISE_FACTOR: f32 = 0.375;

impl Gray {
    /// Writes the image smoothed by the binomial kernel `[1 2 1]/4` along
    /// each axis (a Gaussian of σ ≈ 0.7 px; edges clamped) into `out`,
    /// reusing its buffer. Why: an edge two pixels wide, as a camera
    /// draws it, has detail at the pixel pitch that bilinear sampling at a
    /// sub-pixel shift cannot reproduce, and a window compared across such
    /// a shift differs by that interpolation error alone; smoothed, it
    /// does not. `row` is scratch, kept by the caller.
    pub fn smooth_into(&self, out: &mut Gray, row: &mut Vec<f32>) {
        let (w, h) = (self.width, self.height);
        out.width = w;
        out.height = h;
        out.px.resize(w * h, 0.0);
        if w == 0 || h == 0 {
            return;
        }
        // Rows into `out`, then columns in place a row at a time, the row
        // above (as the row pass left it) kept aside in `row`. Each pass
        // runs over slices of equal length, so it vectorises.
        for (r, o) in self.px.chunks_exact(w).zip(out.px.chunks_exact_mut(w)) {
            let clamped = |x: usize| 0.25 * r[x.saturating_sub(1)] + 0.5 * r[x] + 0.25 * r[(x + 1).min(w - 1)];
            o[0] = clamped(0);
            o[w - 1] = clamped(w - 1);
            if w > 2 {
                for (((o, &a), &b), &c) in o[1..w - 1].iter_mut().zip(&r[..w - 2]).zip(&r[1..w - 1]).zip(&r[2..]) {
                    *o = 0.25 * a + 0.5 * b + 0.25 * c;
                }
            }
        }
        row.clear();
        row.extend_from_slice(&out.px[..w]);
        for y in 0..h {
            let (head, tail) = out.px.split_at_mut((y + 1) * w);
            let here = &mut head[y * w..];
            if y + 1 < h {
                // The row below is still as the row pass left it.
                let (here, above, below) = (&mut here[..w], &mut row[..w], &tail[..w]);
                for x in 0..w {
                    let v = here[x];
                    here[x] = 0.25 * above[x] + 0.5 * v + 0.25 * below[x];
                    above[x] = v;
                }
            } else {
                // The last row is its own below.
                for (o, &above) in here.iter_mut().zip(row.iter()) {
                    let v = *o;
                    *o = 0.25 * above + 0.5 * v + 0.25 * v;
                }
            }
        }
    }
}

/// `Σ aᵢ bᵢ` over eight running sums, so the loop vectorises (a float sum
/// kept in one accumulator cannot be reordered by the compiler).
#[inline]
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca.remainder().iter().zip(cb.remainder()).map(|(x, y)| x * y).sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..8 {
            acc[i] += x[i] * y[i];
        }
    }
    acc.iter().sum::<f32>() + tail
}

/// `Σ aᵢ` over eight running sums (see [`dot`]).
#[inline]
pub fn sum(a: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let c = a.chunks_exact(8);
    let tail: f32 = c.remainder().iter().sum();
    for x in c {
        for i in 0..8 {
            acc[i] += x[i];
        }
    }
    acc.iter().sum::<f32>() + tail
}

/// An image pyramid: level 0 the image, each next level half the size.
#[derive(Clone, Debug, Default)]
pub struct Pyramid {
    pub levels: Vec<Gray>,
}

impl Pyramid {
    /// Rebuilds the pyramid of `image` with `n_levels` levels (at least 1),
    /// reusing this pyramid's buffers.
    pub fn rebuild(&mut self, image: &Gray, n_levels: usize) {
        let n = n_levels.max(1);
        self.levels.resize_with(n, Gray::default);
        self.levels[0].width = image.width;
        self.levels[0].height = image.height;
        self.levels[0].px.clear();
        self.levels[0].px.extend_from_slice(&image.px);
        for l in 1..n {
            let (lower, upper) = self.levels.split_at_mut(l);
            lower[l - 1].half_into(&mut upper[0]);
        }
    }

    /// The pyramid of `image`.
    pub fn of(image: &Gray, n_levels: usize) -> Self {
        let mut p = Self::default();
        p.rebuild(image, n_levels);
        p
    }
}

/// A 5×5 box blur of `img` into `out`: running sums along rows, then
/// down the columns, all columns at once so the image is read row by row
/// (the border clamped), `O(1)` a pixel.
pub fn box_blur(img: &Gray, out: &mut Gray, row: &mut Vec<f32>) {
    let (w, h) = (img.width, img.height);
    out.width = w;
    out.height = h;
    out.px.resize(w * h, 0.0);
    // The row-blurred image, then one row of column sums.
    row.resize(w * h + w, 0.0);
    if w == 0 || h == 0 {
        return;
    }
    let (row, sums) = row.split_at_mut(w * h);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    for (r, o) in img.px.chunks_exact(w).zip(row.chunks_exact_mut(w)) {
        if w < 6 {
            let mut s: f32 = (-2isize..=2).map(|d| r[clamp(d, w)]).sum();
            for (x, o) in o.iter_mut().enumerate() {
                *o = s / 5.0;
                s += r[clamp(x as isize + 3, w)] - r[clamp(x as isize - 2, w)];
            }
            continue;
        }
        // The two columns at each end clamped; between them, five
        // neighbours always inside.
        for x in [0, 1, w - 2, w - 1] {
            o[x] = (-2isize..=2).map(|d| r[clamp(x as isize + d, w)]).sum::<f32>() / 5.0;
        }
        // Five shifted runs of equal length, so the pass vectorises.
        let n = w - 4;
        let (r0, r1, r2, r3, r4) = (&r[..n], &r[1..n + 1], &r[2..n + 2], &r[3..n + 3], &r[4..n + 4]);
        for (x, o) in o[2..w - 2].iter_mut().enumerate() {
            *o = (r0[x] + r1[x] + r2[x] + r3[x] + r4[x]) / 5.0;
        }
    }
    // The column sums of rows y-2..=y+2.
    sums.fill(0.0);
    for d in -2isize..=2 {
        let r = &row[clamp(d, h) * w..][..w];
        for (s, v) in sums.iter_mut().zip(r) {
            *s += v;
        }
    }
    for y in 0..h {
        for (o, s) in out.px[y * w..(y + 1) * w].iter_mut().zip(sums.iter()) {
            *o = s / 5.0;
        }
        let (add, sub) = (clamp(y as isize + 3, h) * w, clamp(y as isize - 2, h) * w);
        for ((s, a), b) in sums
            .iter_mut()
            .zip(row[add..add + w].iter())
            .zip(row[sub..sub + w].iter())
        {
            *s += a - b;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_sampling_and_halving() {
        let mut g = Gray::new(4, 4);
        for y in 0..4 {
            for x in 0..4 {
                g.px[y * 4 + x] = (10 * x + y) as f32;
            }
        }
        // A linear image is sampled exactly.
        assert!((g.sample(1.5, 2.25) - 17.25).abs() < 1e-5);
        assert_eq!(g.sample(-3.0, 0.0), 0.0);
        let p = Pyramid::of(&g, 2);
        assert_eq!((p.levels[1].width, p.levels[1].height), (2, 2));
        // Mean of (0,0),(1,0),(0,1),(1,1): (0 + 10 + 1 + 11) / 4.
        assert!((p.levels[1].px[0] - 5.5).abs() < 1e-6);
        assert!(Gray::from_u8(2, 2, &[1, 2, 3]).is_none());
    }

    /// The smoothing is the binomial `[1 2 1]/4` along each axis, borders
    /// clamped, and leaves `SMOOTH_NOISE_FACTOR` of white noise's sigma.
    #[test]
    fn smoothing_is_the_binomial_kernel() {
        let g = crate::synthetic::textured(40, 30, 2, 0.0, 0.0);
        let (mut out, mut row) = (Gray::default(), Vec::new());
        g.smooth_into(&mut out, &mut row);
        let w = [0.25f32, 0.5, 0.25];
        for &(x, y) in &[(0usize, 0usize), (1, 7), (20, 15), (39, 29), (39, 0)] {
            let mut s = 0.0;
            for (j, wy) in w.iter().enumerate() {
                for (i, wx) in w.iter().enumerate() {
                    let xx = (x as isize + i as isize - 1).clamp(0, 39);
                    let yy = (y as isize + j as isize - 1).clamp(0, 29);
                    s += wx * wy * g.at(xx, yy);
                }
            }
            assert!((out.px[y * 40 + x] - s).abs() < 1e-3, "({x}, {y})");
        }
        // White noise of sigma 10: what is left, away from the borders.
        let mut rng = crate::synthetic::SplitMix::new(7);
        let mut noise = Gray::new(200, 200);
        for p in noise.px.iter_mut() {
            *p = 10.0 * ((0..12).map(|_| rng.unit() as f32).sum::<f32>() - 6.0);
        }
        noise.smooth_into(&mut out, &mut row);
        let inner: Vec<f32> = (2..198)
            .flat_map(|y| (2..198).map(move |x| (x, y)))
            .map(|(x, y)| out.px[y * 200 + x])
            .collect();
        let sd = (inner.iter().map(|v| v * v).sum::<f32>() / inner.len() as f32).sqrt();
        assert!((sd / 10.0 - SMOOTH_NOISE_FACTOR).abs() < 0.02, "{sd}");
    }

    #[test]
    fn the_running_blur_is_the_5x5_mean() {
        let g = crate::synthetic::textured(40, 30, 2, 0.0, 0.0);
        let (mut out, mut row) = (Gray::default(), Vec::new());
        box_blur(&g, &mut out, &mut row);
        for &(x, y) in &[(0usize, 0usize), (1, 7), (20, 15), (39, 29)] {
            let mut s = 0.0;
            for dy in -2isize..=2 {
                for dx in -2isize..=2 {
                    s += g.at(x as isize + dx, y as isize + dy);
                }
            }
            assert!((out.px[y * 40 + x] - s / 25.0).abs() < 1e-3);
        }
    }
}
