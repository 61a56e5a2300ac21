//! Corner detection over a grid: why this exists is that a filter needs its
//! features spread across the image (clustered ones constrain the pose
//! poorly), and a tracker loses features every frame, so new ones are taken
//! where the image has few, never on top of one already tracked.
//!
//! The score is Shi and Tomasi's: the least eigenvalue of the structure
//! tensor `G = Σ_w ∇I ∇Iᵀ` over a `(2r+1)²` window, whose three sums are
//! box sums of the gradient products (running down the columns, then
//! across), computed only in the cells that
//! hold fewer than their share of features. The image is cut into cells,
//! taken in turns, one corner a cell a round, each cell's best first: local
//! maxima above `quality × the image's best`, at least `min_distance_px`
//! from every feature kept or tracked.

use crate::image::Gray;

/// The detector's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DetectParams {
    /// Grid cells across and down.
    pub cells: (usize, usize),
    /// Shortest distance between two features (px).
    pub min_distance_px: f32,
    /// A corner's least eigenvalue must reach this share of the image's
    /// strongest.
    pub quality: f32,
    /// And it must reach this, per pixel of the window (grey²/px²): a
    /// floor above what the camera's noise alone makes (a noise of σ grey
    /// levels gives about σ²/2), so a flat sky yields no corners.
    pub min_eigenvalue: f32,
    /// Half the structure tensor's window side (px).
    pub half_window: usize,
    /// Pixels at the border never used (the tracker's window must fit).
    pub border_px: usize,
}

impl Default for DetectParams {
    fn default() -> Self {
        Self {
            cells: (8, 6),
            min_distance_px: 15.0,
            quality: 0.01,
            min_eigenvalue: 8.0,
            half_window: 2,
            border_px: 10,
        }
    }
}

/// Corners kept per cell before the distance check, best first.
const CANDIDATES_PER_CELL: usize = 24;

/// Reused buffers: a cell's gradient products, the score map and the
/// candidates.
#[derive(Clone, Debug, Default)]
pub struct Detector {
    sxx: Vec<f32>,
    sxy: Vec<f32>,
    syy: Vec<f32>,
    score: Vec<f32>,
    candidates: Vec<(f32, u32, u32)>,
    cell_start: Vec<usize>,
    cursor: Vec<usize>,
    count: Vec<usize>,
    /// Per cell, the calls it still sits out after a search that found no
    /// corner above the floor (a patch of sky or a blank wall: searching it
    /// on every frame would cost as much as a textured cell and yield
    /// nothing), and the grid and image size this holds for.
    barren: Vec<u8>,
    barren_grid: (usize, usize, usize, usize),
    /// The column sums of the three products, while scoring a region.
    col: [Vec<f32>; 3],
    /// A row's window sums of the three products.
    win: [Vec<f32>; 3],
    /// Over a region, each score's 3×3 neighbourhood's largest (within
    /// the region), and the rows' maxima of three on the way.
    max3: Vec<f32>,
    rowmax: Vec<f32>,
}

/// Calls a cell without corners sits out before it is searched again.
const BARREN_SKIP: u8 = 3;

impl Detector {
    /// Up to `wanted` new corners of `img`, none within `min_distance_px` of
    /// `existing` or of each other. Only the cells holding fewer than their
    /// share of features (`wanted + existing` over the cells) are searched,
    /// so a frame that lost a few tracks costs a few cells.
    pub fn detect(&mut self, img: &Gray, existing: &[[f32; 2]], wanted: usize, prm: &DetectParams) -> Vec<[f32; 2]> {
        let mut kept = Vec::new();
        self.detect_into(img, existing, wanted, prm, &mut kept);
        kept
    }

    /// [`Detector::detect`] into `kept` (cleared first), a buffer the
    /// caller keeps, so a frame allocates nothing.
    pub fn detect_into(
        &mut self,
        img: &Gray,
        existing: &[[f32; 2]],
        wanted: usize,
        prm: &DetectParams,
        kept: &mut Vec<[f32; 2]>,
    ) {
        kept.clear();
        let (w, h) = (img.width, img.height);
        let bd = prm.border_px.max(prm.half_window + 2);
        if wanted == 0 || w < 2 * bd + 3 || h < 2 * bd + 3 {
            return;
        }
        let (cols, rows) = prm.cells;
        let n_cells = cols * rows;
        let cell_of = |p: &[f32; 2]| {
            let cx = ((p[0].max(0.0) as usize) * cols / w).min(cols - 1);
            let cy = ((p[1].max(0.0) as usize) * rows / h).min(rows - 1);
            cy * cols + cx
        };
        self.count.clear();
        self.count.resize(n_cells, 0);
        for p in existing {
            self.count[cell_of(p)] += 1;
        }
        let share = (wanted + existing.len()).div_ceil(n_cells).max(1);
        self.score.resize(w * h, 0.0);
        if self.barren_grid != (cols, rows, w, h) {
            self.barren_grid = (cols, rows, w, h);
            self.barren.clear();
            self.barren.resize(n_cells, 0);
        }
        let side = (2 * prm.half_window + 1) as f32;
        let floor = prm.min_eigenvalue * side * side;
        // Each needy cell's best local maxima, best first.
        self.candidates.clear();
        self.cell_start.clear();
        let mut best = 0.0f32;
        for cy in 0..rows {
            for cx in 0..cols {
                self.cell_start.push(self.candidates.len());
                let c = cy * cols + cx;
                if self.count[c] >= share {
                    continue;
                }
                if self.barren[c] > 0 {
                    self.barren[c] -= 1;
                    continue;
                }
                let (x0, x1) = (bd.max(cx * w / cols), (w - bd).min((cx + 1) * w / cols));
                let (y0, y1) = (bd.max(cy * h / rows), (h - bd).min((cy + 1) * h / rows));
                if x0 >= x1 || y0 >= y1 {
                    continue;
                }
                self.region_scores(img, (x0, x1), (y0, y1), prm.half_window);
                let from = self.candidates.len();
                self.region_maxima(w, (x0, x1), (y0, y1));
                let rw = x1 - x0;
                for y in y0..y1 {
                    let (row, max3) = (&self.score[y * w + x0..][..rw], &self.max3[(y - y0) * rw..][..rw]);
                    for (x, (&s, &m)) in row.iter().zip(max3).enumerate() {
                        // A local maximum: no neighbour greater. Below the
                        // floor a corner is never kept (the threshold is
                        // at least the floor), so it is not even a
                        // candidate.
                        if s > 0.0 && s >= floor && s >= m {
                            self.candidates.push((s, (x0 + x) as u32, y as u32));
                        }
                    }
                }
                let cell = &mut self.candidates[from..];
                if cell.len() > CANDIDATES_PER_CELL {
                    cell.select_nth_unstable_by(CANDIDATES_PER_CELL, |a, b| b.0.total_cmp(&a.0));
                }
                let keep = cell.len().min(CANDIDATES_PER_CELL);
                cell[..keep].sort_by(|a, b| b.0.total_cmp(&a.0));
                let cell_best = cell.first().map_or(0.0, |c| c.0);
                if cell_best < floor {
                    self.barren[c] = BARREN_SKIP;
                }
                best = best.max(cell_best);
                self.candidates.truncate(from + keep);
            }
        }
        self.cell_start.push(self.candidates.len());
        if best <= 0.0 {
            return;
        }
        let threshold = (prm.quality * best).max(floor);
        let md2 = prm.min_distance_px.max(1.0).powi(2);
        // Round robin over the cells, one corner a cell a round, so the
        // corners spread before any cell gets a second.
        self.cursor.clear();
        self.cursor.extend_from_slice(&self.cell_start[..n_cells]);
        let mut progress = true;
        while kept.len() < wanted && progress {
            progress = false;
            for c in 0..n_cells {
                if kept.len() == wanted {
                    break;
                }
                if self.count[c] >= share {
                    continue;
                }
                while self.cursor[c] < self.cell_start[c + 1] {
                    let (sc, x, y) = self.candidates[self.cursor[c]];
                    self.cursor[c] += 1;
                    if sc < threshold {
                        self.cursor[c] = self.cell_start[c + 1];
                        break;
                    }
                    let p = [x as f32, y as f32];
                    let near = existing.iter().chain(kept.iter()).any(|q| {
                        let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
                        dx * dx + dy * dy < md2
                    });
                    if !near {
                        kept.push(p);
                        self.count[c] += 1;
                        progress = true;
                        break;
                    }
                }
            }
        }
    }

    /// The Shi–Tomasi score of every pixel of the region `xs × ys`: the
    /// gradient products over the region grown by the window, their sums
    /// down each column's `2r + 1` rows kept running from row to row, then
    /// across `2r + 1` columns (`O(r)` a pixel, every pass along rows, so
    /// each vectorises).
    fn region_scores(&mut self, img: &Gray, xs: (usize, usize), ys: (usize, usize), r: usize) {
        let w = img.width;
        // The grown region [gx0, gx1) × [gy0, gy1).
        let (gx0, gx1, gy0, gy1) = (xs.0 - r, xs.1 + r, ys.0 - r, ys.1 + r);
        let gw = gx1 - gx0;
        let n = gw * (gy1 - gy0);
        for v in [&mut self.sxx, &mut self.sxy, &mut self.syy] {
            v.clear();
            v.resize(n, 0.0);
        }
        // The products, row by row of the grown region.
        for y in gy0..gy1 {
            let at = y * w + gx0;
            let (mid, up, down) = (
                &img.px[at - 1..at + gw + 1],
                &img.px[at - w..at - w + gw],
                &img.px[at + w..at + w + gw],
            );
            let o = (y - gy0) * gw;
            let (pxx, pxy, pyy) = (
                &mut self.sxx[o..o + gw],
                &mut self.sxy[o..o + gw],
                &mut self.syy[o..o + gw],
            );
            for x in 0..gw {
                let ix = 0.5 * (mid[x + 2] - mid[x]);
                let iy = 0.5 * (down[x] - up[x]);
                pxx[x] = ix * ix;
                pxy[x] = ix * iy;
                pyy[x] = iy * iy;
            }
        }
        // Column sums over the window's first 2r rows, then slid down.
        let side = 2 * r + 1;
        let col = &mut self.col;
        for (c, buf) in col.iter_mut().zip([&self.sxx, &self.sxy, &self.syy]) {
            c.clear();
            c.resize(gw, 0.0);
            for k in 0..side - 1 {
                for (s, v) in c.iter_mut().zip(&buf[k * gw..(k + 1) * gw]) {
                    *s += v;
                }
            }
        }
        for y in ys.0..ys.1 {
            let top = y - r - gy0;
            let (bottom, out) = ((top + side - 1) * gw, &mut self.score[y * w + xs.0..y * w + xs.1]);
            for (c, buf) in col.iter_mut().zip([&self.sxx, &self.sxy, &self.syy]) {
                for (s, v) in c.iter_mut().zip(&buf[bottom..bottom + gw]) {
                    *s += v;
                }
            }
            // The window sums across, one offset at a time over the whole
            // row (so each pass vectorises), then the least eigenvalue.
            let len = out.len();
            for (wv, c) in self.win.iter_mut().zip(col.iter()) {
                wv.clear();
                wv.resize(len, 0.0);
                for d in 0..side {
                    for (s, v) in wv.iter_mut().zip(&c[d..d + len]) {
                        *s += v;
                    }
                }
            }
            let [wa, wb, wc] = &self.win;
            for (((o, &a), &b), &cc) in out.iter_mut().zip(wa).zip(wb).zip(wc) {
                let tr = 0.5 * (a + cc);
                *o = tr - (tr * tr - (a * cc - b * b)).max(0.0).sqrt();
            }
            for (c, buf) in col.iter_mut().zip([&self.sxx, &self.sxy, &self.syy]) {
                for (s, v) in c.iter_mut().zip(&buf[top * gw..(top + 1) * gw]) {
                    *s -= v;
                }
            }
        }
    }

    /// Into `max3`, the largest score of each pixel's 3×3 neighbourhood
    /// within the region `xs × ys` (whose scores are current), row by row
    /// of the region: the maxima of three along each row, then of three of
    /// those down each column, each pass over whole rows (so it vectorises).
    fn region_maxima(&mut self, w: usize, xs: (usize, usize), ys: (usize, usize)) {
        let (rw, rh) = (xs.1 - xs.0, ys.1 - ys.0);
        self.rowmax.clear();
        self.rowmax.resize(rw * rh, 0.0);
        self.max3.clear();
        self.max3.resize(rw * rh, 0.0);
        for y in 0..rh {
            let r = &self.score[(ys.0 + y) * w + xs.0..][..rw];
            let m = &mut self.rowmax[y * rw..][..rw];
            max_of_three(r, m);
        }
        for y in 0..rh {
            let here = &self.rowmax[y * rw..][..rw];
            let up = &self.rowmax[y.saturating_sub(1) * rw..][..rw];
            let down = &self.rowmax[(y + 1).min(rh - 1) * rw..][..rw];
            let o = &mut self.max3[y * rw..][..rw];
            for x in 0..rw {
                o[x] = here[x].max(up[x]).max(down[x]);
            }
        }
    }
}

/// Each element's largest of itself and its two neighbours along `r`
/// (one at each end), into `m`.
fn max_of_three(r: &[f32], m: &mut [f32]) {
    let n = r.len();
    match n {
        0 => {}
        1 => m[0] = r[0],
        _ => {
            m[0] = r[0].max(r[1]);
            m[n - 1] = r[n - 1].max(r[n - 2]);
            for (((o, &a), &b), &c) in m[1..n - 1].iter_mut().zip(&r[..n - 2]).zip(&r[1..n - 1]).zip(&r[2..]) {
                *o = a.max(b).max(c);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::textured;

    /// The separable 3×3 maximum finds exactly the scores with no greater
    /// neighbour inside the region (ties included, borders clamped to it).
    #[test]
    fn region_maxima_are_the_local_maxima() {
        let (w, h) = (23usize, 17usize);
        let mut rng = crate::synthetic::SplitMix::new(3);
        // Few levels, so ties occur.
        let mut d = Detector {
            score: (0..w * h).map(|_| (rng.unit() * 6.0).floor() as f32).collect(),
            ..Default::default()
        };
        let (xs, ys) = ((2usize, 19usize), (1usize, 15usize));
        d.region_maxima(w, xs, ys);
        let rw = xs.1 - xs.0;
        for y in ys.0..ys.1 {
            for x in xs.0..xs.1 {
                let v = d.score[y * w + x];
                let mut local = true;
                for yy in y.saturating_sub(1).max(ys.0)..(y + 2).min(ys.1) {
                    for xx in x.saturating_sub(1).max(xs.0)..(x + 2).min(xs.1) {
                        local &= d.score[yy * w + xx] <= v;
                    }
                }
                assert_eq!(v >= d.max3[(y - ys.0) * rw + x - xs.0], local, "({x}, {y})");
            }
        }
    }

    #[test]
    fn corners_are_spread_and_apart() {
        let img = textured(752, 480, 3, 0.0, 0.0);
        let prm = DetectParams::default();
        let mut d = Detector::default();
        let existing = [[100.0f32, 100.0f32]];
        let pts = d.detect(&img, &existing, 150, &prm);
        assert!(pts.len() >= 120, "{} corners", pts.len());
        for (i, p) in pts.iter().enumerate() {
            for q in pts[i + 1..].iter().chain(existing.iter()) {
                let dist = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt();
                assert!(dist >= prm.min_distance_px, "{p:?} {q:?}");
            }
        }
        // Every one of the 48 cells gets some.
        let mut cells = std::collections::BTreeSet::new();
        for p in &pts {
            cells.insert(((p[0] as usize) * 8 / 752, (p[1] as usize) * 6 / 480));
        }
        assert!(cells.len() >= 44, "{} cells", cells.len());
    }
}
