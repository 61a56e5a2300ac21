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
//! The descriptors are steered BRIEF (`brief.rs`); each landmark's first
//! stored look is kept by `landmark_windows.rs`.

use std::collections::VecDeque;

use cmsckf_models::camera::Camera;
use nalgebra::Vector2;

use crate::brief::{best_match, Brief, Descriptor};
use crate::image::{dot, Gray};
use crate::landmark_windows::LandmarkWindows;
use crate::ransac::{affine_inliers, epipolar_inliers};

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
#[derive(Clone, Debug, Default)]
struct Keyframe {
    frame: u64,
    ids: Vec<u64>,
    by_id: Vec<(u64, usize)>,
    uv: Vec<[f64; 2]>,
    xn: Vec<[f64; 2]>,
    desc: Vec<Descriptor>,
    thumb: Vec<f32>,
}

/// The keyframe database.
#[derive(Clone, Debug)]
pub struct Reid {
    prm: ReidParams,
    brief: Brief,
    keyframes: VecDeque<Keyframe>,
    inliers: Vec<bool>,
    affine_ok: Vec<bool>,
    /// This frame's features, described by [`Reid::candidates`] and, if
    /// it is a keyframe (`pending_frame`), stored by [`Reid::commit`]
    /// under the ids they end up with.
    pending: Pending,
    pending_frame: Option<u64>,
    /// The last keyframe to leave the store: its lists hold the next one
    /// stored.
    spare_keyframe: Option<Keyframe>,
    /// See [`Reid::found`].
    found: Vec<(usize, u64)>,
    scratch: Scratch,
    /// Each landmark's window as first stored, for the photometric check
    /// of a re-identification, held while a stored keyframe holds its id.
    windows: LandmarkWindows,
    /// See [`Reid::predicted`].
    predicted: Vec<(u64, [f32; 2])>,
}

/// A frame being matched: its features' indices in the frame, their
/// pixels, normalised coordinates and descriptors, and its thumbnail.
#[derive(Clone, Debug, Default)]
struct Pending {
    keep: Vec<usize>,
    uv: Vec<[f64; 2]>,
    xn: Vec<[f64; 2]>,
    desc: Vec<Descriptor>,
    thumb: Vec<f32>,
}

/// The lists one [`Reid::candidates`] call builds, kept from call to call.
#[derive(Clone, Debug, Default)]
struct Scratch {
    /// The young features that have a descriptor (indices into the
    /// pending frame).
    matchable: Vec<usize>,
    /// The frame's ids, sorted.
    present: Vec<u64>,
    searched: Vec<usize>,
    alike: Vec<(f32, usize)>,
    ranked: Vec<(usize, usize)>,
    places: Vec<(usize, usize)>,
    /// Per searched keyframe (the first `searched.len()`): its index and
    /// its pairs with this frame.
    pairs_of: Vec<(usize, Vec<Pair>)>,
    pairs: Vec<([f64; 2], [f64; 2])>,
    pix: Vec<([f64; 2], [f64; 2])>,
    pix_ok: Vec<([f64; 2], [f64; 2])>,
    verified: Vec<(usize, u64)>,
    near: Vec<(f64, usize)>,
}

impl Reid {
    pub fn new(prm: ReidParams) -> Self {
        Self {
            prm,
            brief: Brief::new(),
            keyframes: VecDeque::new(),
            inliers: Vec::new(),
            affine_ok: Vec::new(),
            pending: Pending::default(),
            pending_frame: None,
            spare_keyframe: None,
            found: Vec::new(),
            scratch: Scratch::default(),
            windows: LandmarkWindows::default(),
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
    /// older ones whose thumbnails look most alike, and finds
    /// `(feature index, old id)` for each feature recognised (never an id
    /// present in this frame, never two features to one id), read with
    /// [`Reid::found`]. The caller checks each against its landmark's
    /// stored window ([`Reid::window`]) and then gives the ids the frame
    /// ends with to [`Reid::commit`], which stores it if it is a keyframe.
    /// Every list it builds is a buffer kept from call to call, so once
    /// they have grown a frame allocates nothing.
    pub fn candidates(&mut self, frame: u64, img: &Gray, feats: &[(u64, f32, f32, u32)], cam: &Camera) {
        self.pending_frame = None;
        self.found.clear();
        self.predicted.clear();
        let search_frames = self.prm.search_frames;
        let young = |age: u32| age < search_frames;
        let store = self.is_keyframe(frame);
        if feats.is_empty() || !(store || feats.iter().any(|f| young(f.3))) {
            return;
        }
        self.brief.set_image(img);
        let mut p = std::mem::take(&mut self.pending);
        p.keep.clear();
        p.uv.clear();
        p.xn.clear();
        p.desc.clear();
        // Lists that came back from the store may be short of this frame.
        let cap = feats.len().max(KEYFRAME_CAPACITY);
        p.keep.reserve(cap);
        p.uv.reserve(cap);
        p.xn.reserve(cap);
        p.desc.reserve(cap);
        thumbnail(self.brief.blurred(), &mut p.thumb);
        // Every feature's pixel and normalised coordinates; descriptors for
        // the young ones, and on a keyframe for all (it is stored), where a
        // feature without one (its patch leaves the image) is left out.
        let mut sc = std::mem::take(&mut self.scratch);
        sc.matchable.clear();
        for (i, &(_, u, v, age)) in feats.iter().enumerate() {
            let Some(x) = cam.undistort(&Vector2::new(f64::from(u), f64::from(v))) else {
                continue;
            };
            let d = if store || young(age) {
                self.brief.describe(u, v)
            } else {
                None
            };
            if store && d.is_none() {
                continue;
            }
            if d.is_some() && young(age) {
                sc.matchable.push(p.keep.len());
            }
            p.desc.push(d.unwrap_or_default());
            p.xn.push([x.x, x.y]);
            p.uv.push([f64::from(u), f64::from(v)]);
            p.keep.push(i);
        }
        sc.present.clear();
        sc.present.extend(feats.iter().map(|f| f.0));
        sc.present.sort_unstable();
        let present = &sc.present;
        let is_present = |id: &u64| present.binary_search(id).is_ok();
        let thr = 1.5 / cam.fx;
        // The keyframes searched: the newest, and the older ones most like
        // this frame by their thumbnails' correlation.
        let n_kf = self.keyframes.len();
        let recent_from = n_kf.saturating_sub(self.prm.recent_keyframes);
        sc.searched.clear();
        sc.searched.extend(recent_from..n_kf);
        let old_enough = frame.saturating_sub(self.prm.place_min_age_frames);
        sc.alike.clear();
        sc.alike.extend(
            (0..recent_from)
                .take_while(|&n| self.keyframes[n].frame <= old_enough)
                .map(|n| (dot(&self.keyframes[n].thumb, &p.thumb), n)),
        );
        let top = self.prm.place_keyframes.min(sc.alike.len());
        if top > 0 {
            sc.alike.select_nth_unstable_by(top - 1, |a, b| b.0.total_cmp(&a.0));
            sc.searched.extend(sc.alike[..top].iter().map(|&(_, n)| n));
        }
        // Each searched keyframe's pairs: the young features' mutual
        // descriptor matches, and the tracks it shares with this frame
        // (same id: a correspondence by construction, which holds the
        // geometric check steady).
        sc.ranked.clear();
        sc.places.clear();
        if sc.pairs_of.len() < sc.searched.len() {
            sc.pairs_of.resize_with(sc.searched.len(), Default::default);
        }
        for (r, &n) in sc.searched.iter().enumerate() {
            let kf = &self.keyframes[n];
            let (kf_at, m) = &mut sc.pairs_of[r];
            *kf_at = n;
            m.clear();
            for j in 0..p.keep.len() {
                let id = feats[p.keep[j]].0;
                if let Ok(at) = kf.by_id.binary_search_by_key(&id, |e| e.0) {
                    m.push((j, kf.by_id[at].1, false));
                }
            }
            for &j in &sc.matchable {
                // Mutual: the keyframe's feature must also find this one
                // (among the young: an older feature on the same landmark
                // would carry the keyframe's id, present and so refused).
                let young_desc = sc.matchable.iter().map(|&y| (y, &p.desc[y]));
                let (max_d, ratio) = (self.prm.max_distance, self.prm.ratio);
                if let Some(k) = best_match(&p.desc[j], kf.desc.iter().enumerate(), max_d, ratio) {
                    if best_match(&kf.desc[k], young_desc, max_d, ratio) == Some(j) {
                        m.push((j, k, true));
                    }
                }
            }
            let new_ids = m
                .iter()
                .filter(|&&(j, k, by_desc)| by_desc && !is_present(&kf.ids[k]) && feats[p.keep[j]].0 != kf.ids[k])
                .count();
            if m.len() >= self.prm.min_matches && new_ids > 0 {
                sc.ranked.push((new_ids, r));
            }
            // The place that shares the most pairs with this frame, ids
            // already given back or not: its other landmarks are predicted.
            if n < recent_from && m.len() >= self.prm.min_matches {
                sc.places.push((m.len(), r));
            }
        }
        sc.ranked.sort_by(|a, b| b.cmp(a));
        sc.ranked.truncate(VERIFIED_KEYFRAMES);
        sc.places.sort_by(|a, b| b.cmp(a));
        for &(_, r) in sc.places.iter().take(PREDICTED_PLACES) {
            if !sc.ranked.iter().any(|x| x.1 == r) {
                sc.ranked.push((0, r));
            }
        }

        // Each of the best few verified on its own: the epipolar geometry,
        // then one affine image motion. A match along its epipolar line but
        // elsewhere in the image passes the first (a camera moving along x
        // has rows for epipolar lines); a revisit is from about the same
        // place, so the second holds to within `affine_tolerance_px`.
        sc.verified.clear();
        for &(_, r) in &sc.ranked {
            let (n, m) = &sc.pairs_of[r];
            let kf = &self.keyframes[*n];
            sc.pairs.clear();
            sc.pairs.extend(m.iter().map(|&(j, k, _)| (kf.xn[k], p.xn[j])));
            sc.pix.clear();
            sc.pix.extend(m.iter().map(|&(j, k, _)| (kf.uv[k], p.uv[j])));
            epipolar_inliers(&sc.pairs, thr, frame, &mut self.inliers);
            affine_inliers(&sc.pix, self.prm.affine_tolerance_px, frame, &mut self.affine_ok);
            let ok = |t: usize| self.inliers[t] && self.affine_ok[t];
            if (0..m.len()).filter(|&t| ok(t)).count() < self.prm.min_matches {
                continue;
            }
            sc.verified.extend(
                m.iter()
                    .enumerate()
                    .filter(|&(t, &(_, _, by_desc))| by_desc && ok(t))
                    .map(|(_, &(j, k, _))| (p.keep[j], kf.ids[k])),
            );
            // A place seen before: its other landmarks, where its verified
            // pairs say they are now.
            if *n < recent_from {
                sc.pix_ok.clear();
                sc.pix_ok.extend((0..m.len()).filter(|&t| ok(t)).map(|t| sc.pix[t]));
                predict_landmarks(kf, &sc.pix_ok, present, &mut sc.near, &mut self.predicted);
            }
        }
        // One feature per old id, one old id per feature, and no id
        // already in the frame (`found` holds the old ids taken, and each
        // feature is relabelled at most once: both checked on it).
        for &(i, old) in &sc.verified {
            if feats[i].0 != old && !is_present(&old) && !self.found.iter().any(|&(fi, fo)| fi == i || fo == old) {
                self.found.push((i, old));
            }
        }
        self.scratch = sc;
        self.pending = p;
        if store {
            self.pending_frame = Some(frame);
        }
    }

    /// The features recognised by the last [`Reid::candidates`]:
    /// `(feature index, old id)`.
    pub fn found(&self) -> &[(usize, u64)] {
        &self.found
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
        self.windows.get(id)
    }

    /// Stores the frame last passed to [`Reid::candidates`] (`img`) if a
    /// keyframe, its features under `ids` (the frame's ids once
    /// re-identified, by feature index), with the window of each landmark
    /// new to the store; the oldest keyframe goes when the store is full,
    /// and with it the windows no other keyframe holds. A keyframe's
    /// lists are taken from the one that left the store (and a window's
    /// slot from one dropped, `LandmarkWindows`), so a full store
    /// allocates only when it holds more windows than ever before.
    pub fn commit(&mut self, img: &Gray, ids: &[u64]) {
        let Some(frame) = self.pending_frame.take() else {
            return;
        };
        let mut kf = self.spare_keyframe.take().unwrap_or_default();
        let p = &mut self.pending;
        kf.frame = frame;
        kf.ids.clear();
        kf.ids.reserve(p.keep.len().max(KEYFRAME_CAPACITY));
        kf.ids
            .extend(p.keep.iter().map(|&i| ids.get(i).copied().unwrap_or(u64::MAX)));
        kf.by_id.clear();
        kf.by_id.reserve(p.keep.len().max(KEYFRAME_CAPACITY));
        kf.by_id.extend(kf.ids.iter().enumerate().map(|(k, &id)| (id, k)));
        kf.by_id.sort_unstable();
        std::mem::swap(&mut kf.uv, &mut p.uv);
        std::mem::swap(&mut kf.xn, &mut p.xn);
        std::mem::swap(&mut kf.desc, &mut p.desc);
        std::mem::swap(&mut kf.thumb, &mut p.thumb);
        // A landmark keeps the window of the first keyframe that held it:
        // every later re-identification is checked against that one look,
        // so errors do not pass from one re-identification to the next.
        for (&id, q) in kf.ids.iter().zip(&kf.uv) {
            self.windows.hold(id, img, [q[0] as f32, q[1] as f32]);
        }
        self.keyframes.push_back(kf);
        while self.keyframes.len() > self.prm.max_keyframes {
            let Some(old) = self.keyframes.pop_front() else { break };
            for &id in &old.ids {
                self.windows.release(id);
            }
            self.spare_keyframe = Some(old);
        }
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
/// `present` is sorted; `near` is scratch.
fn predict_landmarks(
    kf: &Keyframe,
    pix: &[([f64; 2], [f64; 2])],
    present: &[u64],
    near: &mut Vec<(f64, usize)>,
    out: &mut Vec<(u64, [f32; 2])>,
) {
    if pix.len() < PREDICT_PAIRS {
        return;
    }
    for (k, &id) in kf.ids.iter().enumerate() {
        if present.binary_search(&id).is_ok() || out.iter().any(|o| o.0 == id) {
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
fn thumbnail(img: &Gray, t: &mut Vec<f32>) {
    let (tw, th) = THUMB;
    t.clear();
    t.resize(tw * th, 0.0);
    if img.width < tw || img.height < th {
        return;
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
    let norm = dot(t, t).sqrt();
    if norm > 0.0 {
        t.iter_mut().for_each(|v| *v /= norm);
    }
}

/// A pair of a frame's feature and a keyframe's, by index, and whether it
/// is a descriptor match (else the same track in both).
type Pair = (usize, usize, bool);

/// The features a keyframe's lists are made room for: they pass from the
/// frame being matched to the store and, when a keyframe leaves it, back,
/// so each list is grown to this once and then reused (at 150 features a
/// frame, and past it only for a frame with more).
const KEYFRAME_CAPACITY: usize = 256;

/// Keyframes verified per re-identification, at most.
const VERIFIED_KEYFRAMES: usize = 2;

#[cfg(test)]
mod tests {
    use super::*;

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
        let present = [1, 2, 3, 4];
        let mut out = Vec::new();
        predict_landmarks(&kf, &pix, &present, &mut Vec::new(), &mut out);
        assert_eq!(out.len(), 1, "{out:?}");
        assert_eq!(out[0].0, 6);
        assert!(
            (out[0].1[0] - 126.0).abs() < 1e-4 && (out[0].1[1] - 100.0).abs() < 1e-4,
            "{out:?}"
        );
    }
}
