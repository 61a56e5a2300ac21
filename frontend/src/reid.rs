//! Re-identification: why this exists is that a loop closure reaches the
//! filter only as a landmark id it has seen before. Lucas–Kanade loses a
//! feature once it leaves the image, and when the drone comes back to the
//! place, the tracker gives the same point a new id. So every few frames the
//! tracked features get binary descriptors and are matched against older
//! keyframes' (not the recent ones, which the tracker already links); a
//! match that is mutual (each the other's nearest), survives the ratio test
//! and the keyframe's epipolar check gives the feature back its old id.
//!
//! The descriptor is steered BRIEF, as in ORB: 256 intensity comparisons
//! between point pairs of a 31×31 patch of a box-blurred image, the pattern
//! turned by the patch's orientation (the angle of its intensity centroid,
//! `atan2(m₀₁, m₁₀)`), so a drone that yawed between its visits still
//! matches.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use cmsckf_models::camera::Camera;
use nalgebra::Vector2;

use crate::image::Gray;
use crate::ransac::epipolar_inliers;
use crate::synthetic::SplitMix;

/// A 256-bit binary descriptor.
pub type Descriptor = [u64; 4];

/// Re-identification's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReidParams {
    /// A keyframe every this many frames.
    pub every_frames: u64,
    /// The most recent keyframes not searched (the tracker links those).
    pub skip_recent: usize,
    /// Keyframes kept, at most (the oldest go first).
    pub max_keyframes: usize,
    /// Largest Hamming distance of a match (of 256 bits).
    pub max_distance: u32,
    /// A match's distance must be below this share of the second best's.
    pub ratio: f32,
    /// Matches a keyframe must keep after the epipolar check.
    pub min_matches: usize,
    /// How far a match may land from the matches' common affine map (px).
    pub affine_tolerance_px: f64,
}

impl Default for ReidParams {
    fn default() -> Self {
        Self {
            every_frames: 5,
            skip_recent: 6,
            max_keyframes: 400,
            max_distance: 50,
            ratio: 0.8,
            min_matches: 10,
            affine_tolerance_px: 10.0,
        }
    }
}

/// One stored keyframe: its features' ids, normalised coordinates and
/// descriptors.
#[derive(Clone, Debug)]
struct Keyframe {
    ids: Vec<u64>,
    uv: Vec<[f64; 2]>,
    xn: Vec<[f64; 2]>,
    desc: Vec<Descriptor>,
}

/// The keyframe database and the steered-BRIEF pattern.
#[derive(Clone, Debug)]
pub struct Reid {
    prm: ReidParams,
    pattern: Vec<[i8; 4]>,
    keyframes: VecDeque<Keyframe>,
    blurred: Gray,
    row: Vec<f32>,
    inliers: Vec<bool>,
    affine_ok: Vec<bool>,
    /// Features given back an old id, in all.
    pub reidentified: u64,
}

/// The patch's half side (px).
const HALF: i32 = 15;

impl Reid {
    pub fn new(prm: ReidParams) -> Self {
        // 256 point pairs, Gaussian-ish around the centre (the sum of two
        // uniforms), inside the patch once turned.
        let mut r = SplitMix::new(0x5eed);
        let mut c = || {
            let v = ((r.unit() + r.unit() - 1.0) * 11.0).round() as i8;
            v.clamp(-11, 11)
        };
        let pattern = (0..256).map(|_| [c(), c(), c(), c()]).collect();
        Self {
            prm,
            pattern,
            keyframes: VecDeque::new(),
            blurred: Gray::default(),
            row: Vec::new(),
            inliers: Vec::new(),
            affine_ok: Vec::new(),
            reidentified: 0,
        }
    }

    /// Whether `frame` is a keyframe (every `every_frames`-th).
    pub fn is_keyframe(&self, frame: u64) -> bool {
        frame.is_multiple_of(self.prm.every_frames)
    }

    /// At every `every_frames`-th frame: describes the features
    /// `(id, u, v)`, matches them against the older keyframes, and returns
    /// `(feature index, old id)` for each feature re-identified (never an id
    /// present in this frame, never two features to one id). The frame is
    /// then stored as a keyframe under the ids it will carry.
    pub fn process(&mut self, frame: u64, img: &Gray, feats: &[(u64, f32, f32)], cam: &Camera) -> Vec<(usize, u64)> {
        if !self.is_keyframe(frame) || feats.is_empty() {
            return Vec::new();
        }
        box_blur(img, &mut self.blurred, &mut self.row);
        let mut desc = Vec::with_capacity(feats.len());
        let mut xn = Vec::with_capacity(feats.len());
        let mut uv = Vec::with_capacity(feats.len());
        let mut keep = Vec::with_capacity(feats.len());
        for (i, &(_, u, v)) in feats.iter().enumerate() {
            let (Some(d), Some(x)) = (
                self.describe(u, v),
                cam.undistort(&Vector2::new(f64::from(u), f64::from(v))),
            ) else {
                continue;
            };
            desc.push(d);
            xn.push([x.x, x.y]);
            uv.push([f64::from(u), f64::from(v)]);
            keep.push(i);
        }
        let present: BTreeSet<u64> = feats.iter().map(|f| f.0).collect();
        let thr = 1.5 / cam.fx;
        // Candidate keyframes: the older ones whose mutual matches include
        // the most features under another id than the keyframe's (matches
        // under the same id are tracks still alive, nothing to recognise).
        let searchable = self.keyframes.len().saturating_sub(self.prm.skip_recent);
        let mut ranked: Vec<(usize, usize)> = Vec::new();
        let mut matches: Vec<Vec<(usize, usize)>> = Vec::with_capacity(searchable);
        for (n, kf) in self.keyframes.iter().take(searchable).enumerate() {
            let mut m = Vec::new();
            for (j, d) in desc.iter().enumerate() {
                // Mutual: the keyframe's feature must also find this one.
                if let Some(k) = self.best_match(d, &kf.desc) {
                    if self.best_match(&kf.desc[k], &desc) == Some(j) {
                        m.push((j, k));
                    }
                }
            }
            let new_ids = m.iter().filter(|(j, k)| feats[keep[*j]].0 != kf.ids[*k]).count();
            if m.len() >= self.prm.min_matches && new_ids > 0 {
                ranked.push((new_ids, n));
            }
            matches.push(m);
        }
        ranked.sort_by(|a, b| b.cmp(a));
        // Each of the best few verified on its own: the epipolar geometry,
        // then one affine image motion. A match along its epipolar line but
        // elsewhere in the image passes the first (a camera moving along x
        // has rows for epipolar lines); a revisit is from about the same
        // place, so the second holds to within `affine_tolerance_px`.
        let mut verified: Vec<(usize, u64)> = Vec::new();
        for &(_, n) in ranked.iter().take(VERIFIED_KEYFRAMES) {
            let kf = &self.keyframes[n];
            let m = &matches[n];
            let pairs: Vec<_> = m.iter().map(|&(j, k)| (kf.xn[k], xn[j])).collect();
            let pix: Vec<_> = m.iter().map(|&(j, k)| (kf.uv[k], uv[j])).collect();
            epipolar_inliers(&pairs, thr, frame, &mut self.inliers);
            affine_inliers(&pix, self.prm.affine_tolerance_px, frame, &mut self.affine_ok);
            let ok = |t: usize| self.inliers[t] && self.affine_ok[t];
            if (0..m.len()).filter(|&t| ok(t)).count() < self.prm.min_matches {
                continue;
            }
            verified.extend(
                m.iter()
                    .enumerate()
                    .filter(|&(t, _)| ok(t))
                    .map(|(_, &(j, k))| (keep[j], kf.ids[k])),
            );
        }
        // One feature per old id, one old id per feature, and no id
        // already in the frame.
        let mut taken = BTreeMap::new();
        let mut relabelled = BTreeSet::new();
        let mut out = Vec::new();
        for (i, old) in verified {
            if feats[i].0 != old
                && !present.contains(&old)
                && !relabelled.contains(&i)
                && taken.insert(old, i).is_none()
            {
                relabelled.insert(i);
                out.push((i, old));
            }
        }
        self.reidentified += out.len() as u64;
        let mut ids: Vec<u64> = keep.iter().map(|&i| feats[i].0).collect();
        for &(i, old) in &out {
            if let Some(pos) = keep.iter().position(|&k| k == i) {
                ids[pos] = old;
            }
        }
        self.keyframes.push_back(Keyframe { ids, uv, xn, desc });
        while self.keyframes.len() > self.prm.max_keyframes {
            self.keyframes.pop_front();
        }
        out
    }

    /// The index of `d`'s match in `set`: the nearest within
    /// `max_distance`, clearly nearer than the second (ratio test).
    fn best_match(&self, d: &Descriptor, set: &[Descriptor]) -> Option<usize> {
        let (mut b1, mut b2, mut k1) = (u32::MAX, u32::MAX, 0);
        for (k, e) in set.iter().enumerate() {
            let dist = (0..4).map(|w| (d[w] ^ e[w]).count_ones()).sum::<u32>();
            if dist < b1 {
                b2 = b1;
                b1 = dist;
                k1 = k;
            } else if dist < b2 {
                b2 = dist;
            }
        }
        (b1 <= self.prm.max_distance && (b1 as f32) < self.prm.ratio * b2 as f32).then_some(k1)
    }

    /// The steered-BRIEF descriptor at `(u, v)`, if its patch fits.
    fn describe(&self, u: f32, v: f32) -> Option<Descriptor> {
        let img = &self.blurred;
        let (cx, cy) = (u.round() as i32, v.round() as i32);
        if cx < HALF + 1 || cy < HALF + 1 || cx >= img.width as i32 - HALF - 1 || cy >= img.height as i32 - HALF - 1 {
            return None;
        }
        // The intensity centroid's angle over the disc of radius HALF.
        let (mut m10, mut m01) = (0.0f32, 0.0f32);
        for dy in -HALF..=HALF {
            for dx in -HALF..=HALF {
                if dx * dx + dy * dy <= HALF * HALF {
                    let p = img.px[(cy + dy) as usize * img.width + (cx + dx) as usize];
                    m10 += dx as f32 * p;
                    m01 += dy as f32 * p;
                }
            }
        }
        let (s, c) = m01.atan2(m10).sin_cos();
        let at = |x: i8, y: i8| {
            let (x, y) = (f32::from(x), f32::from(y));
            let (rx, ry) = ((c * x - s * y).round() as i32, (s * x + c * y).round() as i32);
            img.px[(cy + ry) as usize * img.width + (cx + rx) as usize]
        };
        let mut d = [0u64; 4];
        for (k, p) in self.pattern.iter().enumerate() {
            if at(p[0], p[1]) < at(p[2], p[3]) {
                d[k / 64] |= 1 << (k % 64);
            }
        }
        Some(d)
    }
}

/// Keyframes verified per re-identification, at most.
const VERIFIED_KEYFRAMES: usize = 4;

/// Marks the pixel pairs `(a, b)` that one affine map `b ≈ A a + t` (from
/// three-pair RANSAC samples, `seed` driven) carries to within
/// `tolerance_px`.
fn affine_inliers(pairs: &[([f64; 2], [f64; 2])], tolerance_px: f64, seed: u64, ok: &mut Vec<bool>) {
    ok.clear();
    ok.resize(pairs.len(), false);
    if pairs.len() < 3 {
        return;
    }
    let mut rng = SplitMix::new(seed ^ 0xaff1);
    let t2 = tolerance_px * tolerance_px;
    let mut best: Option<(usize, [f64; 6])> = None;
    for _ in 0..100 {
        let idx: Vec<usize> = (0..3).map(|_| (rng.next_u64() % pairs.len() as u64) as usize).collect();
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

/// A 5×5 box blur of `img` into `out`: running sums along rows, then
/// along columns (the border clamped), `O(1)` a pixel.
fn box_blur(img: &Gray, out: &mut Gray, row: &mut Vec<f32>) {
    let (w, h) = (img.width, img.height);
    out.width = w;
    out.height = h;
    out.px.resize(w * h, 0.0);
    row.resize(w * h, 0.0);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    for y in 0..h {
        let r = &img.px[y * w..(y + 1) * w];
        let mut s: f32 = (-2isize..=2).map(|d| r[clamp(d, w)]).sum();
        for x in 0..w {
            row[y * w + x] = s / 5.0;
            s += r[clamp(x as isize + 3, w)] - r[clamp(x as isize - 2, w)];
        }
    }
    for x in 0..w {
        let mut s: f32 = (-2isize..=2).map(|d| row[clamp(d, h) * w + x]).sum();
        for y in 0..h {
            out.px[y * w + x] = s / 5.0;
            s += row[clamp(y as isize + 3, h) * w + x] - row[clamp(y as isize - 2, h) * w + x];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
