//! Re-identification: why this exists is that a loop closure reaches the
//! filter only as a landmark id it has seen before. The tracker loses a
//! feature when it leaves the image, is hidden, or no longer matches its
//! first window; when the landmark is seen again (a moment later, or when
//! the drone comes back to the place), it is detected under a new id. So
//! on every frame the new features get binary descriptors and are matched
//! against stored keyframes: the newest few (a landmark lost a moment
//! ago) and the older ones whose thumbnails look most like this frame (a
//! place seen before: the block means of the image on a 32×20 grid,
//! compared by correlation). A match that is mutual (each the other's
//! nearest) and survives the ratio test is verified with its keyframe's
//! other pairs, the tracks both frames share included: one epipolar
//! geometry and one affine image motion. The tracker then checks it
//! against the landmark's window as first stored (`affine.rs`), which
//! moves it onto the landmark's own point, and gives it its old id.
//!
//! A recognised place also predicts where its other landmarks are now
//! (`predict`: each moved with its nearest verified pairs), and the tracker
//! looks for them there with their stored windows. Detection alone picks
//! whichever corners score best, and on a revisit those are seldom the ones
//! the place's keyframes hold: on the rendered racetrack, of the landmarks
//! a daemon keyframe held, more were seen again on the next lap under
//! other ids than under their own, until this.
//!
//! The descriptor is steered BRIEF, as in ORB: 256 intensity comparisons
//! between point pairs of a 31×31 patch of a box-blurred image, the pattern
//! turned by the patch's orientation (the angle of its intensity centroid,
//! `atan2(m₀₁, m₁₀)`), so a drone that yawed between its visits still
//! matches.

use std::collections::{BTreeMap, BTreeSet, HashMap, VecDeque};

use cmsckf_models::camera::Camera;
use nalgebra::Vector2;

use crate::affine::window_bytes;
use crate::image::{box_blur, dot, Gray};
use crate::ransac::{affine_inliers, epipolar_inliers};
use crate::synthetic::SplitMix;

/// A 256-bit binary descriptor.
pub type Descriptor = [u64; 4];

/// Re-identification's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReidParams {
    /// A keyframe is stored every this many frames.
    pub keyframe_every_frames: u64,
    /// A new feature is searched for on each of its first this many
    /// frames (a landmark is often detected again a frame or two before
    /// its descriptor matches).
    pub search_frames: u32,
    /// The newest stored keyframes, searched on every frame: a landmark
    /// lost a moment ago and detected again is found there.
    pub recent_keyframes: usize,
    /// The older keyframes searched on every frame: those whose thumbnail
    /// looks most like this frame's (a place seen before).
    pub place_keyframes: usize,
    /// How old (frames) a keyframe must be to be searched as a place: a
    /// revisit means the drone left and came back, and recent frames look
    /// alike by their thumbnails (sky above ground) without being one.
    pub place_min_age_frames: u64,
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
            keyframe_every_frames: 2,
            search_frames: 5,
            recent_keyframes: 3,
            place_keyframes: 3,
            place_min_age_frames: 200,
            max_keyframes: 1000,
            max_distance: 50,
            ratio: 0.8,
            min_matches: 10,
            affine_tolerance_px: 10.0,
        }
    }
}

/// One stored keyframe: its features' ids (and, sorted, with their
/// indices), pixels, normalised coordinates and descriptors, and the
/// frame's thumbnail.
#[derive(Clone, Debug)]
struct Keyframe {
    frame: u64,
    ids: Vec<u64>,
    by_id: Vec<(u64, usize)>,
    uv: Vec<[f64; 2]>,
    xn: Vec<[f64; 2]>,
    desc: Vec<Descriptor>,
    thumb: Vec<f32>,
}

/// The keyframe database and the steered-BRIEF pattern.
#[derive(Clone, Debug)]
pub struct Reid {
    prm: ReidParams,
    /// The pattern's point pairs by coordinate (`x₀, y₀, x₁, y₁`, 256
    /// each), so turning all of them is one pass that vectorises.
    pattern: [Vec<f32>; 4],
    /// Each pair's two points as offsets in the image, once turned
    /// (scratch of [`Reid::describe`]).
    offsets: [Vec<i32>; 2],
    keyframes: VecDeque<Keyframe>,
    blurred: Gray,
    row: Vec<f32>,
    inliers: Vec<bool>,
    affine_ok: Vec<bool>,
    /// This keyframe's features, described by [`Reid::candidates`] and
    /// stored by [`Reid::commit`] under the ids they end up with.
    pending: Option<Pending>,
    /// Each landmark's window as first stored (`affine.rs`), for the
    /// photometric check of a re-identification, with the number of
    /// stored keyframes that hold its id: at most `max_keyframes ×
    /// features` windows of 441 bytes (21²), dropped with the last keyframe that
    /// holds them.
    windows: HashMap<u64, (Vec<u8>, u32)>,
    ring: Vec<f32>,
    /// See [`Reid::predicted`].
    predicted: Vec<(u64, [f32; 2])>,
}

/// A frame being matched: its number, its features' indices in the frame,
/// their pixels, normalised coordinates and descriptors, and its thumbnail.
#[derive(Clone, Debug)]
struct Pending {
    frame: u64,
    keep: Vec<usize>,
    uv: Vec<[f64; 2]>,
    xn: Vec<[f64; 2]>,
    desc: Vec<Descriptor>,
    thumb: Vec<f32>,
}

/// The patch's half side (px).
const HALF: i32 = 15;

/// A row's pixel offsets from the patch centre, `-HALF..=HALF`, and as
/// many ones: the weights of the centroid's two sums.
const DX: [f32; 2 * HALF as usize + 1] = {
    let mut d = [0.0f32; 2 * HALF as usize + 1];
    let mut i = 0;
    while i < d.len() {
        d[i] = i as f32 - HALF as f32;
        i += 1;
    }
    d
};
const ONES: [f32; 2 * HALF as usize + 1] = [1.0; 2 * HALF as usize + 1];

/// The disc of radius `HALF`: each row's half width, `dy` from `-HALF`.
const DISC_HALF_WIDTH: [i32; 2 * HALF as usize + 1] = {
    let mut w = [0i32; 2 * HALF as usize + 1];
    let mut i = 0;
    while i < w.len() {
        let dy = i as i32 - HALF;
        let mut hw = 0;
        while (hw + 1) * (hw + 1) + dy * dy <= HALF * HALF {
            hw += 1;
        }
        w[i] = hw;
        i += 1;
    }
    w
};

impl Reid {
    pub fn new(prm: ReidParams) -> Self {
        // 256 point pairs, Gaussian-ish around the centre (the sum of two
        // uniforms), inside the patch once turned.
        let mut r = SplitMix::new(0x5eed);
        let mut c = || {
            let v = ((r.unit() + r.unit() - 1.0) * 11.0).round() as i8;
            v.clamp(-11, 11)
        };
        let mut pattern: [Vec<f32>; 4] = Default::default();
        for _ in 0..256 {
            for p in pattern.iter_mut() {
                p.push(f32::from(c()));
            }
        }
        Self {
            prm,
            pattern,
            offsets: [vec![0; 256], vec![0; 256]],
            keyframes: VecDeque::new(),
            blurred: Gray::default(),
            row: Vec::new(),
            inliers: Vec::new(),
            affine_ok: Vec::new(),
            pending: None,
            windows: HashMap::new(),
            ring: Vec::new(),
            predicted: Vec::new(),
        }
    }

    /// Whether `frame` is stored as a keyframe (every
    /// `keyframe_every_frames`-th).
    pub fn is_keyframe(&self, frame: u64) -> bool {
        frame.is_multiple_of(self.prm.keyframe_every_frames.max(1))
    }

    /// On every frame: describes the features `(id, u, v, age)`, matches
    /// those younger than `search_frames` against the newest keyframes and the
    /// older ones whose thumbnails look most alike, and returns
    /// `(feature index, old id)` for each feature recognised (never an id
    /// present in this frame, never two features to one id). The caller
    /// checks each against its landmark's stored window ([`Reid::window`])
    /// and then gives the ids the frame ends with to [`Reid::commit`],
    /// which stores it if it is a keyframe.
    pub fn candidates(
        &mut self,
        frame: u64,
        img: &Gray,
        feats: &[(u64, f32, f32, u32)],
        cam: &Camera,
    ) -> Vec<(usize, u64)> {
        self.pending = None;
        let search_frames = self.prm.search_frames;
        let young = |age: u32| age < search_frames;
        let store = self.is_keyframe(frame);
        if feats.is_empty() || !(store || feats.iter().any(|f| young(f.3))) {
            return Vec::new();
        }
        box_blur(img, &mut self.blurred, &mut self.row);
        let mut p = Pending {
            frame,
            keep: Vec::with_capacity(feats.len()),
            uv: Vec::with_capacity(feats.len()),
            xn: Vec::with_capacity(feats.len()),
            desc: Vec::with_capacity(feats.len()),
            thumb: thumbnail(&self.blurred),
        };
        // Every feature's pixel and normalised coordinates; descriptors for
        // the young ones, and on a keyframe for all (it is stored), where a
        // feature without one (its patch leaves the image) is left out.
        let mut matchable: Vec<usize> = Vec::new();
        for (i, &(_, u, v, age)) in feats.iter().enumerate() {
            let Some(x) = cam.undistort(&Vector2::new(f64::from(u), f64::from(v))) else {
                continue;
            };
            let d = if store || young(age) { self.describe(u, v) } else { None };
            if store && d.is_none() {
                continue;
            }
            if d.is_some() && young(age) {
                matchable.push(p.keep.len());
            }
            p.desc.push(d.unwrap_or_default());
            p.xn.push([x.x, x.y]);
            p.uv.push([f64::from(u), f64::from(v)]);
            p.keep.push(i);
        }
        let present: BTreeSet<u64> = feats.iter().map(|f| f.0).collect();
        let thr = 1.5 / cam.fx;
        // The keyframes searched: the newest, and the older ones most like
        // this frame by their thumbnails' correlation.
        let n_kf = self.keyframes.len();
        let recent_from = n_kf.saturating_sub(self.prm.recent_keyframes);
        let mut searched: Vec<usize> = (recent_from..n_kf).collect();
        let old_enough = frame.saturating_sub(self.prm.place_min_age_frames);
        let mut alike: Vec<(f32, usize)> = (0..recent_from)
            .take_while(|&n| self.keyframes[n].frame <= old_enough)
            .map(|n| (dot(&self.keyframes[n].thumb, &p.thumb), n))
            .collect();
        let top = self.prm.place_keyframes.min(alike.len());
        if top > 0 {
            alike.select_nth_unstable_by(top - 1, |a, b| b.0.total_cmp(&a.0));
            searched.extend(alike[..top].iter().map(|&(_, n)| n));
        }
        // Each searched keyframe's pairs: the young features' mutual
        // descriptor matches, and the tracks it shares with this frame
        // (same id: a correspondence by construction, which holds the
        // geometric check steady).
        let mut ranked: Vec<(usize, usize)> = Vec::new();
        let mut places: Vec<(usize, usize)> = Vec::new();
        let mut pairs_of: Vec<(usize, Vec<Pair>)> = Vec::with_capacity(searched.len());
        for &n in &searched {
            let kf = &self.keyframes[n];
            let mut m: Vec<Pair> = Vec::new();
            for j in 0..p.keep.len() {
                let id = feats[p.keep[j]].0;
                if let Ok(at) = kf.by_id.binary_search_by_key(&id, |e| e.0) {
                    m.push((j, kf.by_id[at].1, false));
                }
            }
            for &j in &matchable {
                // Mutual: the keyframe's feature must also find this one
                // (among the young: an older feature on the same landmark
                // would carry the keyframe's id, present and so refused).
                let young_desc = matchable.iter().map(|&y| (y, &p.desc[y]));
                if let Some(k) = self.best_match(&p.desc[j], kf.desc.iter().enumerate()) {
                    if self.best_match(&kf.desc[k], young_desc) == Some(j) {
                        m.push((j, k, true));
                    }
                }
            }
            let new_ids = m
                .iter()
                .filter(|&&(j, k, by_desc)| by_desc && !present.contains(&kf.ids[k]) && feats[p.keep[j]].0 != kf.ids[k])
                .count();
            if m.len() >= self.prm.min_matches && new_ids > 0 {
                ranked.push((new_ids, pairs_of.len()));
            }
            // The place that shares the most pairs with this frame, ids
            // already given back or not: its other landmarks are predicted.
            if n < recent_from && m.len() >= self.prm.min_matches {
                places.push((m.len(), pairs_of.len()));
            }
            pairs_of.push((n, m));
        }
        ranked.sort_by(|a, b| b.cmp(a));
        ranked.truncate(VERIFIED_KEYFRAMES);
        places.sort_by(|a, b| b.cmp(a));
        for &(_, r) in places.iter().take(PREDICTED_PLACES) {
            if !ranked.iter().any(|x| x.1 == r) {
                ranked.push((0, r));
            }
        }

        // Each of the best few verified on its own: the epipolar geometry,
        // then one affine image motion. A match along its epipolar line but
        // elsewhere in the image passes the first (a camera moving along x
        // has rows for epipolar lines); a revisit is from about the same
        // place, so the second holds to within `affine_tolerance_px`.
        let mut verified: Vec<(usize, u64)> = Vec::new();
        self.predicted.clear();
        for &(_, r) in &ranked {
            let (n, m) = &pairs_of[r];
            let kf = &self.keyframes[*n];
            let pairs: Vec<_> = m.iter().map(|&(j, k, _)| (kf.xn[k], p.xn[j])).collect();
            let pix: Vec<_> = m.iter().map(|&(j, k, _)| (kf.uv[k], p.uv[j])).collect();
            epipolar_inliers(&pairs, thr, frame, &mut self.inliers);
            affine_inliers(&pix, self.prm.affine_tolerance_px, frame, &mut self.affine_ok);
            let ok = |t: usize| self.inliers[t] && self.affine_ok[t];
            if (0..m.len()).filter(|&t| ok(t)).count() < self.prm.min_matches {
                continue;
            }
            verified.extend(
                m.iter()
                    .enumerate()
                    .filter(|&(t, &(_, _, by_desc))| by_desc && ok(t))
                    .map(|(_, &(j, k, _))| (p.keep[j], kf.ids[k])),
            );
            // A place seen before: its other landmarks, where its verified
            // pairs say they are now.
            if *n < recent_from {
                let pix_ok: Vec<_> = (0..m.len()).filter(|&t| ok(t)).map(|t| pix[t]).collect();
                predict(kf, &pix_ok, &present, &mut self.predicted);
            }
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
        if store {
            self.pending = Some(p);
        }
        out
    }

    /// The landmarks of the places recognised by the last
    /// [`Reid::candidates`] that this frame does not hold, each with the
    /// pixel where it should be now (`predict`): the tracker looks for each
    /// there with its stored window, and takes it back if it is found.
    pub fn predicted(&self) -> &[(u64, [f32; 2])] {
        &self.predicted
    }

    /// Landmark `id`'s window as the first stored keyframe holding it saw
    /// it (`affine::window_bytes`), if one does.
    pub fn window(&self, id: u64) -> Option<&[u8]> {
        self.windows.get(&id).map(|(w, _)| w.as_slice())
    }

    /// Stores the frame last passed to [`Reid::candidates`] (`img`) if a
    /// keyframe, its features under `ids` (the frame's ids once
    /// re-identified, by feature index), with the window of each landmark
    /// new to the store; the oldest keyframe goes when the store is full,
    /// and with it the windows no other keyframe holds.
    pub fn commit(&mut self, img: &Gray, ids: &[u64]) {
        let Some(Pending {
            frame,
            keep,
            uv,
            xn,
            desc,
            thumb,
        }) = self.pending.take()
        else {
            return;
        };
        let ids: Vec<u64> = keep.iter().map(|&i| ids.get(i).copied().unwrap_or(u64::MAX)).collect();
        let mut by_id: Vec<(u64, usize)> = ids.iter().enumerate().map(|(k, &id)| (id, k)).collect();
        by_id.sort_unstable();
        // A landmark keeps the window of the first keyframe that held it:
        // every later re-identification is checked against that one look,
        // so errors do not pass from one re-identification to the next.
        let mut bytes = Vec::new();
        for (&id, p) in ids.iter().zip(&uv) {
            match self.windows.get_mut(&id) {
                Some(w) => w.1 += 1,
                None => {
                    if window_bytes(img, p[0] as f32, p[1] as f32, &mut self.ring, &mut bytes) {
                        self.windows.insert(id, (bytes.clone(), 1));
                    }
                }
            }
        }
        self.keyframes.push_back(Keyframe {
            frame,
            ids,
            by_id,
            uv,
            xn,
            desc,
            thumb,
        });
        while self.keyframes.len() > self.prm.max_keyframes {
            let Some(old) = self.keyframes.pop_front() else { break };
            for id in old.ids {
                if let Some(w) = self.windows.get_mut(&id) {
                    w.1 -= 1;
                    if w.1 == 0 {
                        self.windows.remove(&id);
                    }
                }
            }
        }
    }

    /// The index of `d`'s match in `set`: the nearest within
    /// `max_distance`, clearly nearer than the second (ratio test).
    fn best_match<'a>(&self, d: &Descriptor, set: impl Iterator<Item = (usize, &'a Descriptor)>) -> Option<usize> {
        let (mut b1, mut b2, mut k1) = (u32::MAX, u32::MAX, 0);
        for (k, e) in set {
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
    fn describe(&mut self, u: f32, v: f32) -> Option<Descriptor> {
        let img = &self.blurred;
        // Rounded to the nearest pixel by adding a half and truncating
        // (a position outside the image is refused below either way).
        let (cx, cy) = ((u + 0.5) as i32, (v + 0.5) as i32);
        if cx < HALF + 1 || cy < HALF + 1 || cx >= img.width as i32 - HALF - 1 || cy >= img.height as i32 - HALF - 1 {
            return None;
        }
        // The intensity centroid's angle over the disc of radius HALF, a
        // row's run of pixels at a time (`DISC_HALF_WIDTH`): Σ dx·p along
        // the row, and dy times the row's sum.
        let (mut m10, mut m01) = (0.0f32, 0.0f32);
        for dy in -HALF..=HALF {
            let hw = DISC_HALF_WIDTH[(dy + HALF) as usize];
            let at = (cy + dy) as usize * img.width + cx as usize;
            let row = &img.px[at - hw as usize..=at + hw as usize];
            let xs = &DX[(HALF - hw) as usize..=(HALF + hw) as usize];
            m10 += dot(row, xs);
            m01 += dy as f32 * dot(row, &ONES[..row.len()]);
        }
        let (s, c) = m01.atan2(m10).sin_cos();
        // Each pair's points turned by the angle, rounded to the nearest
        // pixel (the turned offsets lie within ±16, so shifted by 32.5
        // they are positive and truncation is the rounding, without a
        // call to `roundf`), as offsets in the image.
        let w = img.width as i32;
        let round = |v: f32| (v + 32.5) as i32 - 32;
        let [x0, y0, x1, y1] = &self.pattern;
        let [o0, o1] = &mut self.offsets;
        for (o, (x, y)) in [(&mut *o0, (x0, y0)), (&mut *o1, (x1, y1))] {
            for ((o, &x), &y) in o.iter_mut().zip(x.iter()).zip(y.iter()) {
                *o = round(s * x + c * y) * w + round(c * x - s * y);
            }
        }
        let centre = cy * w + cx;
        let mut d = [0u64; 4];
        for (word, (a, b)) in d.iter_mut().zip(o0.chunks_exact(64).zip(o1.chunks_exact(64))) {
            for (bit, (&a, &b)) in a.iter().zip(b).enumerate() {
                let (pa, pb) = (img.px[(centre + a) as usize], img.px[(centre + b) as usize]);
                *word |= u64::from(pa < pb) << bit;
            }
        }
        Some(d)
    }
}

/// How many verified pairs nearest a landmark (in the keyframe's image)
/// carry it into this frame, and how far the farthest of them may be (px):
/// the image motion of a revisit varies across the image with depth, and
/// the nearest pairs share the landmark's.
const PREDICT_PAIRS: usize = 3;
const PREDICTED_PLACES: usize = 2;
const PREDICT_REACH_PX: f64 = 120.0;

/// Appends to `out` each landmark of `kf` absent from this frame
/// (`present`), with where it should be now: its keyframe pixel moved by
/// the mean motion of the `PREDICT_PAIRS` verified pairs `pix` (keyframe
/// pixel, this frame's pixel) nearest it, all within `PREDICT_REACH_PX`.
fn predict(kf: &Keyframe, pix: &[([f64; 2], [f64; 2])], present: &BTreeSet<u64>, out: &mut Vec<(u64, [f32; 2])>) {
    if pix.len() < PREDICT_PAIRS {
        return;
    }
    let mut near: Vec<(f64, usize)> = Vec::with_capacity(pix.len());
    for (k, &id) in kf.ids.iter().enumerate() {
        if present.contains(&id) || out.iter().any(|o| o.0 == id) {
            continue;
        }
        let a = kf.uv[k];
        near.clear();
        near.extend(
            pix.iter()
                .enumerate()
                .map(|(t, p)| ((p.0[0] - a[0]).hypot(p.0[1] - a[1]), t)),
        );
        near.select_nth_unstable_by(PREDICT_PAIRS - 1, |x, y| x.0.total_cmp(&y.0));
        let nearest = &near[..PREDICT_PAIRS];
        if nearest.iter().any(|x| x.0 > PREDICT_REACH_PX) {
            continue;
        }
        let mut d = [0.0f64; 2];
        for &(_, t) in nearest {
            d[0] += (pix[t].1[0] - pix[t].0[0]) / PREDICT_PAIRS as f64;
            d[1] += (pix[t].1[1] - pix[t].0[1]) / PREDICT_PAIRS as f64;
        }
        out.push((id, [(a[0] + d[0]) as f32, (a[1] + d[1]) as f32]));
    }
}

/// The thumbnail's side in blocks, across and down.
const THUMB: (usize, usize) = (32, 20);

/// A frame's thumbnail for place recognition: the image's block means on a
/// `THUMB` grid, less their mean, scaled to unit length (so the dot
/// product of two is their correlation, whatever the exposure).
fn thumbnail(img: &Gray) -> Vec<f32> {
    let (tw, th) = THUMB;
    let mut t = vec![0.0f32; tw * th];
    if img.width < tw || img.height < th {
        return t;
    }
    let (bw, bh) = (img.width / tw, img.height / th);
    for (k, v) in t.iter_mut().enumerate() {
        let (bx, by) = (k % tw, k / tw);
        // Every fourth pixel of every fourth row of the block: the image
        // is blurred already.
        let (mut sum, mut n) = (0.0f32, 0.0f32);
        for y in (by * bh..(by + 1) * bh).step_by(4) {
            for x in (bx * bw..(bx + 1) * bw).step_by(4) {
                sum += img.px[y * img.width + x];
                n += 1.0;
            }
        }
        *v = sum / n.max(1.0);
    }
    let mean = t.iter().sum::<f32>() / t.len() as f32;
    t.iter_mut().for_each(|v| *v -= mean);
    let norm = dot(&t, &t).sqrt();
    if norm > 0.0 {
        t.iter_mut().for_each(|v| *v /= norm);
    }
    t
}

/// A pair of a frame's feature and a keyframe's, by index, and whether it
/// is a descriptor match (else the same track in both).
type Pair = (usize, usize, bool);

/// Keyframes verified per re-identification, at most.
const VERIFIED_KEYFRAMES: usize = 2;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_disc_rows_hold_exactly_the_disc() {
        for dy in -HALF..=HALF {
            let n = (-HALF..=HALF).filter(|dx| dx * dx + dy * dy <= HALF * HALF).count() as i32;
            assert_eq!(n, 2 * DISC_HALF_WIDTH[(dy + HALF) as usize] + 1, "dy {dy}");
        }
    }

    /// A place's landmarks absent from the frame are carried by the mean
    /// motion of their nearest verified pairs; those present, and those
    /// with no pair within reach, are not predicted.
    #[test]
    fn absent_landmarks_move_with_their_nearest_pairs() {
        let uv = vec![
            [100.0, 100.0],
            [120.0, 100.0],
            [100.0, 120.0],
            [110.0, 110.0],
            [400.0, 300.0],
            [115.0, 105.0],
        ];
        let ids: Vec<u64> = vec![1, 2, 3, 4, 5, 6];
        let kf = Keyframe {
            frame: 0,
            by_id: ids.iter().enumerate().map(|(k, &id)| (id, k)).collect(),
            ids,
            xn: vec![[0.0; 2]; uv.len()],
            desc: vec![[0; 4]; uv.len()],
            uv: uv.clone(),
            thumb: Vec::new(),
        };
        // Pairs 1-3 moved by (+10, -5), 4 by (+13, -5): the nearest three
        // to landmark 6 are 2, 4 and 1 or 3.
        let pix: Vec<_> = (0..4)
            .map(|k| (uv[k], [uv[k][0] + if k == 3 { 13.0 } else { 10.0 }, uv[k][1] - 5.0]))
            .collect();
        let present: BTreeSet<u64> = [1, 2, 3, 4].into_iter().collect();
        let mut out = Vec::new();
        predict(&kf, &pix, &present, &mut out);
        assert_eq!(out.len(), 1, "{out:?}");
        assert_eq!(out[0].0, 6);
        assert!(
            (out[0].1[0] - 126.0).abs() < 1e-4 && (out[0].1[1] - 100.0).abs() < 1e-4,
            "{out:?}"
        );
    }
}
