//! The frame-to-frame tracker: why this exists is to turn a camera's images
//! into what the daemon's feature socket carries, landmarks with stable ids
//! and their pixel positions. Each frame: every track is followed by
//! pyramidal Lucas–Kanade with the forward–backward check (`klt.rs`), then
//! held to the window it was first seen with through an affine warp, or
//! dropped once it no longer matches it (`affine.rs`); the survivors must
//! agree with one epipolar geometry (`ransac.rs`, on
//! undistorted normalised coordinates through the project's camera model),
//! and the image is topped up to `max_features` with new corners where it
//! has room (`detect.rs`). A lost feature seen again gets a new id, unless
//! re-identification (`reid.rs`, on every frame for the new features)
//! recognises its landmark and gives it the old one back. When it
//! recognises a place flown before, the place's other landmarks are looked
//! for where it puts them and brought back too (`Tracker::reacquire`).
//!
//! The first-window checks (the anchors, and re-identification's stored
//! windows) read a smoothed copy of the frame (`Gray::smooth_into`): a
//! camera draws an edge over about two pixels, and bilinear sampling of it
//! at a sub-pixel shift misses by several grey levels, which on the
//! rendered racetrack alone failed three in four new features on the far
//! ground at their first check (measured at the true correspondence).

use cmsckf_models::camera::Camera;
use nalgebra::Vector2;

use crate::affine::Anchor;
use crate::detect::{DetectParams, Detector};
use crate::image::{Gray, Pyramid, SMOOTH_NOISE_FACTOR};
use crate::klt::{track_checked, KltParams, KltScratch};
use crate::ransac::epipolar_inliers;
use crate::reid::{Reid, ReidParams};

/// The tracker's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackerParams {
    /// Features kept per frame, at most.
    pub max_features: usize,
    /// Pyramid levels (1: no pyramid).
    pub pyramid_levels: usize,
    pub klt: KltParams,
    pub detect: DetectParams,
    /// RANSAC's Sampson threshold (px, divided by the focal length).
    pub ransac_threshold_px: f64,
    /// Re-identification of old landmarks (`None`: off). It needs the
    /// camera model.
    pub reid: Option<ReidParams>,
    /// Each track is checked against its first window through an affine
    /// warp (`affine.rs`) and moved to where it fits; it is dropped when
    /// the residual exceeds this share of the window's spread, beyond the
    /// noise's share (`Anchor::fits`; `None`: frame-to-frame tracking
    /// only, which drifts where the image scales).
    pub max_anchor_residual: Option<f32>,
    /// The camera's pixel noise (grey levels, one sigma): the anchor
    /// check allows for it on top of `max_anchor_residual`.
    pub noise_grey: f32,
    /// A track is dropped once its anchor's warp has stretched or shrunk
    /// its first window by more than this fraction along any direction
    /// (the singular values of the warp's linear part outside
    /// `[1/(1+x), 1+x]`), or sheared it that much (their ratio over `1+x`):
    /// an affine map stands for a surface seen from near the first
    /// viewpoint, and a track held to it across a larger change strays
    /// beyond its σ while its residual still passes (`None`: no limit).
    /// The place for a new corner and a fresh anchor. Measured with 0.2
    /// (docs/frontend.md, "Measured"): the tracks anchored while the
    /// vehicle stood and held through its take-off had been refused by the
    /// filter's χ² gate 28 times in 44.
    pub max_warp_stretch: Option<f32>,
}

/// Gauss–Newton steps of the anchor check a frame.
const ANCHOR_ITERATIONS: usize = 2;

/// Gauss–Newton steps of a re-identification's check against its
/// landmark's stored window (from the identity warp), at most.
const REID_ITERATIONS: usize = 10;

/// How far that check may move a re-identified feature (px).
const REID_MAX_SHIFT_PX: f32 = 3.0;

/// That check's residual bound, as a multiple of a live track's: a
/// revisit sees its landmark from further than one frame's motion, and a
/// look-alike lands far above it (measured on the rendered figure8, with
/// the bound on the share alone: the candidates' residuals cluster at
/// 0.1–0.2 of the window's spread).
const REID_RESIDUAL_FACTOR: f32 = 1.6;

/// How near a re-acquired landmark must land to a young feature to be
/// taken for the same point (px).
const SAME_POINT_PX: f32 = 1.5;

impl Default for TrackerParams {
    fn default() -> Self {
        Self {
            max_features: 150,
            pyramid_levels: 4,
            klt: KltParams::default(),
            detect: DetectParams::default(),
            ransac_threshold_px: 1.0,
            reid: Some(ReidParams::default()),
            max_anchor_residual: Some(0.07),
            noise_grey: 2.0,
            max_warp_stretch: Some(0.2),
        }
    }
}

/// One tracked feature: its landmark id and pixel position (distorted
/// image coordinates, as the socket carries them).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Feature {
    pub id: u64,
    pub u_px: f32,
    pub v_px: f32,
    /// Frames it has been tracked through (0: new in this frame).
    pub age: u32,
    /// How precisely this frame's position was found (px, one σ along the
    /// least certain direction; `Anchor::sigma_px`), or 0 if it was not
    /// measured (no anchor: the window did not fit or was flat).
    pub sigma_px: f32,
}

/// Why features were dropped, per frame and in total.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TrackStats {
    pub lost_klt: u64,
    pub lost_ransac: u64,
    /// Dropped for no longer matching their first window.
    pub lost_anchor: u64,
    /// Dropped for a first window stretched past `max_warp_stretch`.
    pub lost_warp: u64,
    pub detected: u64,
    /// Features given back an old landmark's id.
    pub reidentified: u64,
    /// Re-identifications refused by the landmark's stored window.
    pub reid_refused: u64,
    /// Landmarks of a recognised place found again where it put them
    /// (`Tracker::reacquire`).
    pub reacquired: u64,
}

/// The tracker and its reused buffers.
#[derive(Debug)]
pub struct Tracker {
    prm: TrackerParams,
    camera: Option<Camera>,
    prev: Pyramid,
    next: Pyramid,
    /// This frame smoothed (`Gray::smooth_into`): what the anchors and the
    /// stored windows of re-identification are cut from and matched in.
    smooth: Gray,
    smooth_row: Vec<f32>,
    features: Vec<Feature>,
    next_id: u64,
    detector: Detector,
    scratch: KltScratch,
    pairs: Vec<([f64; 2], [f64; 2])>,
    inliers: Vec<bool>,
    moved: Vec<Feature>,
    existing: Vec<[f32; 2]>,
    /// This frame's new corners (`Detector::detect_into`).
    new_corners: Vec<[f32; 2]>,
    frames: u64,
    reid: Option<Reid>,
    /// Each track's window as first seen, and its affine warp since, by id.
    anchors: std::collections::HashMap<u64, Anchor>,
    /// Anchors of lost tracks, kept for their buffers: a new track's
    /// anchor is refilled from one, so none is allocated per frame.
    spare: Vec<Anchor>,
    /// The anchor a stored window is checked with (`check_against`).
    check: Anchor,
    live_ids: Vec<u64>,
    /// This frame's features as re-identification takes them.
    reid_feats: Vec<(u64, f32, f32, u32)>,
    pub stats: TrackStats,
}

/// Most features a frame holds: `max_features` from detection, and up to
/// half as many again brought back by re-identification
/// ([`Tracker::reacquire`]; beside the simulator's textured ground a frame
/// reached 150 + 35). The per-feature buffers and the anchors' pool are
/// made this large at start, so that a flight's new high allocates nothing.
fn feature_capacity(prm: &TrackerParams) -> usize {
    prm.max_features + prm.max_features / 2
}

impl Tracker {
    /// A tracker; with `camera`, outliers are rejected on its undistorted
    /// normalised coordinates (without one, nothing is rejected by RANSAC).
    pub fn new(prm: TrackerParams, camera: Option<Camera>) -> Self {
        let reid = prm.reid.filter(|_| camera.is_some()).map(Reid::new);
        let cap = feature_capacity(&prm);
        let anchored = prm.max_anchor_residual.is_some();
        Self {
            prm,
            camera,
            prev: Pyramid::default(),
            next: Pyramid::default(),
            smooth: Gray::default(),
            smooth_row: Vec::new(),
            features: Vec::with_capacity(cap),
            next_id: 0,
            detector: Detector::default(),
            scratch: KltScratch::default(),
            pairs: Vec::with_capacity(cap),
            inliers: Vec::with_capacity(cap),
            moved: Vec::with_capacity(cap),
            existing: Vec::with_capacity(cap),
            new_corners: Vec::new(),
            frames: 0,
            reid,
            anchors: std::collections::HashMap::with_capacity(if anchored { cap } else { 0 }),
            spare: if anchored {
                (0..cap).map(|_| Anchor::with_buffers()).collect()
            } else {
                Vec::new()
            },
            check: Anchor::default(),
            live_ids: Vec::with_capacity(cap),
            reid_feats: Vec::with_capacity(cap),
            stats: TrackStats::default(),
        }
    }

    /// Tracks into `image` and returns this frame's features.
    pub fn process(&mut self, image: &Gray) -> &[Feature] {
        self.next.rebuild(image, self.prm.pyramid_levels);
        if self.prm.max_anchor_residual.is_some() {
            image.smooth_into(&mut self.smooth, &mut self.smooth_row);
        }
        let size_changed = self
            .prev
            .levels
            .first()
            .is_some_and(|l| (l.width, l.height) != (image.width, image.height));
        if size_changed {
            self.features.clear();
        }
        if self.frames > 0 && !size_changed {
            self.follow();
        }
        self.top_up();
        self.anchor_new();
        self.reidentify();
        std::mem::swap(&mut self.prev, &mut self.next);
        self.frames += 1;
        &self.features
    }

    /// Stores the window of each feature new in this frame (or without
    /// one), and forgets those of lost tracks.
    fn anchor_new(&mut self) {
        if self.prm.max_anchor_residual.is_none() {
            return;
        }
        // The live ids, sorted into a buffer kept from frame to frame.
        self.live_ids.clear();
        self.live_ids.extend(self.features.iter().map(|f| f.id));
        self.live_ids.sort_unstable();
        let live = &self.live_ids;
        let spare = &mut self.spare;
        for (_, a) in self.anchors.extract_if(|id, _| live.binary_search(id).is_err()) {
            spare.push(a);
        }
        // What a perfect match leaves: the noise of two smoothed frames.
        let noise_rms = SMOOTH_NOISE_FACTOR * std::f32::consts::SQRT_2 * self.prm.noise_grey;
        for k in 0..self.features.len() {
            let f = self.features[k];
            if f.age == 0 || !self.anchors.contains_key(&f.id) {
                self.anchor_at(f.id, [f.u_px, f.v_px]);
            }
            // A position no fit has measured (a new corner) is held to its
            // window's own precision.
            if f.sigma_px == 0.0 {
                if let Some(a) = self.anchors.get(&f.id) {
                    self.features[k].sigma_px = a.sigma_px(noise_rms);
                }
            }
        }
    }

    /// Track `id`'s anchor: the smoothed frame's window at `q`, in a spare
    /// anchor's buffers (none if the window does not fit or is flat).
    fn anchor_at(&mut self, id: u64, q: [f32; 2]) {
        self.drop_anchor(id);
        let mut a = self.spare.pop().unwrap_or_default();
        if a.reset_at(&self.smooth, q[0], q[1]) {
            self.anchors.insert(id, a);
        } else {
            self.spare.push(a);
        }
    }

    /// Forgets track `id`'s anchor, keeping its buffers.
    fn drop_anchor(&mut self, id: u64) {
        if let Some(a) = self.anchors.remove(&id) {
            self.spare.push(a);
        }
    }

    /// Lucas–Kanade with the forward–backward check, then RANSAC.
    fn follow(&mut self) {
        self.moved.clear();
        self.pairs.clear();
        for k in 0..self.features.len() {
            let f = self.features[k];
            match track_checked(
                &self.prev,
                &self.next,
                [f.u_px, f.v_px],
                [f.u_px, f.v_px],
                &self.prm.klt,
                &mut self.scratch,
            ) {
                Some(q) => {
                    // Held to its first window (affine.rs): corrected, or
                    // dropped once it no longer looks like it.
                    let mut q = q;
                    let mut sigma_px = 0.0;
                    if let (Some(max), Some(a)) = (self.prm.max_anchor_residual, self.anchors.get_mut(&f.id)) {
                        match a.refine(&self.smooth, q, ANCHOR_ITERATIONS) {
                            Some((rq, res))
                                if (rq[0] - q[0]).hypot(rq[1] - q[1]) < 2.0
                                    && a.fits(res, max, SMOOTH_NOISE_FACTOR * self.prm.noise_grey) =>
                            {
                                q = rq;
                                sigma_px = a.sigma_px(res);
                            }
                            _ => {
                                self.stats.lost_anchor += 1;
                                self.drop_anchor(f.id);
                                continue;
                            }
                        }
                        if self.prm.max_warp_stretch.is_some_and(|x| a_stretched(&a.a, x)) {
                            self.stats.lost_warp += 1;
                            self.drop_anchor(f.id);
                            continue;
                        }
                    }
                    let moved = Feature {
                        u_px: q[0],
                        v_px: q[1],
                        age: f.age + 1,
                        sigma_px,
                        ..f
                    };
                    if let Some(cam) = &self.camera {
                        let a = cam.undistort(&Vector2::new(f64::from(f.u_px), f64::from(f.v_px)));
                        let b = cam.undistort(&Vector2::new(f64::from(q[0]), f64::from(q[1])));
                        let (Some(a), Some(b)) = (a, b) else {
                            self.stats.lost_klt += 1;
                            continue;
                        };
                        self.pairs.push(([a.x, a.y], [b.x, b.y]));
                    }
                    self.moved.push(moved);
                }
                None => self.stats.lost_klt += 1,
            }
        }
        if let Some(cam) = &self.camera {
            let thr = self.prm.ransac_threshold_px / cam.fx;
            epipolar_inliers(&self.pairs, thr, self.frames, &mut self.inliers);
            let before = self.moved.len();
            let mut k = 0;
            let inliers = &self.inliers;
            self.moved.retain(|_| {
                k += 1;
                inliers[k - 1]
            });
            self.stats.lost_ransac += (before - self.moved.len()) as u64;
        }
        std::mem::swap(&mut self.features, &mut self.moved);
    }

    /// Old ids back for the features re-identified in this frame. Each
    /// candidate must also match its landmark's stored window: the affine
    /// check of `affine.rs`, from the identity and the feature's pixel,
    /// under `REID_RESIDUAL_FACTOR` times a live track's residual bound.
    /// That moves it onto the
    /// landmark's own point (a corner detected again lands a pixel or so
    /// from where it was first seen) and refuses a look-alike. The frame
    /// is then stored if a keyframe.
    fn reidentify(&mut self) {
        // Taken out for the while, so the anchors can be refilled.
        let Some(mut reid) = self.reid.take() else { return };
        self.reidentify_with(&mut reid);
        self.reid = Some(reid);
    }

    fn reidentify_with(&mut self, reid: &mut Reid) {
        let Some(cam) = self.camera.as_ref() else { return };
        self.reid_feats.clear();
        self.reid_feats
            .extend(self.features.iter().map(|f| (f.id, f.u_px, f.v_px, f.age)));
        reid.candidates(self.frames, &self.next.levels[0], &self.reid_feats, cam);
        let noise_grey = SMOOTH_NOISE_FACTOR * self.prm.noise_grey;
        for &(i, old) in reid.found() {
            let f = self.features[i];
            let Some(max) = self.prm.max_anchor_residual else {
                // Without anchors, the descriptors' word is taken.
                self.features[i].id = old;
                self.stats.reidentified += 1;
                continue;
            };
            let checked = check_against(
                &mut self.check,
                reid,
                old,
                &self.smooth,
                [f.u_px, f.v_px],
                REID_RESIDUAL_FACTOR * max,
                noise_grey,
            );
            match checked {
                Some((q, sigma_px)) => {
                    self.features[i] = Feature {
                        id: old,
                        u_px: q[0],
                        v_px: q[1],
                        sigma_px,
                        ..f
                    };
                    // From here the track is held to the window it is
                    // seen with now, at its landmark's point.
                    self.drop_anchor(f.id);
                    self.anchor_at(old, q);
                    self.stats.reidentified += 1;
                }
                None => self.stats.reid_refused += 1,
            }
        }
        if let Some(max) = self.prm.max_anchor_residual {
            self.reacquire(reid, max);
        }
        self.live_ids.clear();
        self.live_ids.extend(self.features.iter().map(|f| f.id));
        reid.commit(&self.smooth, &self.live_ids);
    }

    /// The landmarks of a recognised place that this frame does not hold
    /// (`Reid::predicted`), each looked for where the place's verified
    /// pairs put it, with its stored window (`check_against`, bound
    /// `max` times `REID_RESIDUAL_FACTOR`). One found where no feature is
    /// joins the frame; one found on a young feature (the same point,
    /// within `SAME_POINT_PX`) gives it its id; one found beside an older
    /// feature is left. This is what brings a place's landmarks back on a
    /// revisit: detection picks whichever corners score best, and those are
    /// seldom the ones the place's keyframes hold.
    fn reacquire(&mut self, reid: &Reid, max: f32) {
        let search_frames = self.prm.reid.map_or(0, |r| r.search_frames);
        let noise_grey = SMOOTH_NOISE_FACTOR * self.prm.noise_grey;
        let min_distance = self.prm.detect.min_distance_px;
        for &(id, q0) in reid.predicted() {
            if self.features.iter().any(|f| f.id == id) {
                continue;
            }
            let Some((q, sigma_px)) = check_against(
                &mut self.check,
                reid,
                id,
                &self.smooth,
                q0,
                REID_RESIDUAL_FACTOR * max,
                noise_grey,
            ) else {
                continue;
            };
            let nearest = self
                .features
                .iter()
                .enumerate()
                .map(|(i, f)| ((f.u_px - q[0]).hypot(f.v_px - q[1]), i))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let at = match nearest {
                Some((d, i)) if d < SAME_POINT_PX && self.features[i].age < search_frames => Some(i),
                Some((d, _)) if d < min_distance => continue,
                // A new feature only while the frame has room for it
                // (`feature_capacity`): the buffers are that large.
                _ if self.features.len() >= feature_capacity(&self.prm) => continue,
                _ => None,
            };
            let f = Feature {
                id,
                u_px: q[0],
                v_px: q[1],
                age: 0,
                sigma_px,
            };
            match at {
                Some(i) => {
                    self.drop_anchor(self.features[i].id);
                    self.features[i] = Feature {
                        age: self.features[i].age,
                        ..f
                    };
                }
                None => self.features.push(f),
            }
            self.anchor_at(id, q);
            self.stats.reacquired += 1;
        }
    }

    /// New corners where the image has room, up to `max_features`.
    fn top_up(&mut self) {
        let wanted = self.prm.max_features.saturating_sub(self.features.len());
        if wanted == 0 {
            return;
        }
        // Corners are found on the first pyramid level above the image (a
        // quarter of the pixels; a corner there is one at twice the scale,
        // which Lucas–Kanade's window tracks as well), then placed on the
        // image at twice their position.
        let level = usize::from(self.next.levels.len() > 1);
        let scale = (1 << level) as f32;
        self.existing.clear();
        self.existing
            .extend(self.features.iter().map(|f| [f.u_px / scale, f.v_px / scale]));
        let mut prm = self.prm.detect;
        prm.min_distance_px /= scale;
        prm.border_px = prm.border_px.div_ceil(1 << level);
        self.detector.detect_into(
            &self.next.levels[level],
            &self.existing,
            wanted,
            &prm,
            &mut self.new_corners,
        );
        self.stats.detected += self.new_corners.len() as u64;
        for &p in &self.new_corners {
            self.features.push(Feature {
                id: self.next_id,
                u_px: p[0] * scale,
                v_px: p[1] * scale,
                age: 0,
                sigma_px: 0.0,
            });
            self.next_id += 1;
        }
    }
}

/// Whether the warp's linear part `a` stretches, shrinks or shears the
/// window by more than the fraction `x` (`TrackerParams::max_warp_stretch`):
/// its singular values outside `[1/(1+x), 1+x]`, or their ratio over `1+x`.
/// A mirrored window (a negative determinant) or a non-finite warp is
/// stretched too: neither is a surface seen again.
fn a_stretched(a: &nalgebra::Matrix2<f32>, x: f32) -> bool {
    if !(a.iter().all(|v| v.is_finite()) && a.determinant() > 0.0) {
        return true;
    }
    let sv = a.singular_values();
    let (hi, lo) = (sv[0].max(sv[1]), sv[0].min(sv[1]));
    let limit = 1.0 + x;
    !(hi <= limit && lo * limit >= 1.0 && hi <= lo * limit)
}

/// Landmark `id`'s first stored look (`Reid::window`) matched at `pos` in
/// `img` by the affine check from the identity (in `a`'s buffers): the point it lands on
/// and its σ against the landmark's first look (`Anchor::sigma_px` of the
/// check's own residual), if the residual is within `share` (and the noise
/// of `noise_grey`) and the point within `REID_MAX_SHIFT_PX` of `pos`.
fn check_against(
    a: &mut Anchor,
    reid: &Reid,
    id: u64,
    img: &Gray,
    pos: [f32; 2],
    share: f32,
    noise_grey: f32,
) -> Option<([f32; 2], f32)> {
    if !a.reset_from_window_bytes(reid.window(id)?) {
        return None;
    }
    let (q, res) = a.refine(img, pos, REID_ITERATIONS)?;
    ((q[0] - pos[0]).hypot(q[1] - pos[1]) < REID_MAX_SHIFT_PX && a.fits(res, share, noise_grey))
        .then(|| (q, a.sigma_px(res)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{apply, Texture};
    use nalgebra::Matrix3;

    #[test]
    fn a_warp_is_stretched_past_its_fraction_in_any_direction() {
        let d = |x: f32, y: f32| nalgebra::Matrix2::new(x, 0.0, 0.0, y);
        let turn = |r: f32| nalgebra::Matrix2::new(r.cos(), -r.sin(), r.sin(), r.cos());
        assert!(!a_stretched(&nalgebra::Matrix2::identity(), 0.2));
        // A turn stretches nothing; a zoom of 1.19 or 1/1.19 is within.
        assert!(!a_stretched(&(turn(0.7) * d(1.19, 1.19)), 0.2));
        assert!(!a_stretched(&d(1.0 / 1.19, 1.0 / 1.19), 0.2));
        assert!(a_stretched(&d(1.21, 1.21), 0.2));
        assert!(a_stretched(&(turn(-0.3) * d(0.82, 0.82)), 0.2));
        // A shear: each direction within, their ratio not.
        assert!(!a_stretched(&d(1.1, 0.95), 0.2));
        assert!(a_stretched(&d(1.15, 0.93), 0.2));
        assert!(a_stretched(&d(f32::NAN, 1.0), 0.2));
        assert!(a_stretched(&d(f32::INFINITY, 1.0), 0.2));
        // A mirror keeps every length: still no view of the same surface.
        assert!(a_stretched(&d(1.0, -1.0), 0.2));
        assert!(a_stretched(&nalgebra::Matrix2::zeros(), 0.2));
    }

    /// A plane zoomed 1 % a frame: a track held to its first window
    /// through more than `max_warp_stretch` of zoom ends there, and the
    /// image is topped up with fresh corners; without the limit the first
    /// frame's tracks live on.
    #[test]
    fn a_track_ends_once_its_window_is_stretched_past_the_limit() {
        let (w, h) = (752usize, 480usize);
        let tex = Texture::new(5, 900.0);
        let fly = |limit: Option<f32>| {
            let mut tracker = Tracker::new(
                TrackerParams {
                    max_warp_stretch: limit,
                    ..TrackerParams::default()
                },
                None,
            );
            let (mut first, mut last_first_seen) = (Vec::new(), 0);
            for k in 0..40 {
                // About the image's centre, 1.01^k: 1.2 after 18 frames.
                let s = 1.01f64.powi(k);
                let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
                let hmat = Matrix3::new(s, 0.0, cx * (1.0 - s), 0.0, s, cy * (1.0 - s), 0.0, 0.0, 1.0);
                let feats = tracker.process(&tex.render(w, h, &hmat)).to_vec();
                assert!(feats.len() >= 100, "frame {k}: {} features", feats.len());
                if k == 0 {
                    first = feats.iter().map(|f| f.id).collect();
                } else if feats.iter().any(|f| first.contains(&f.id)) {
                    last_first_seen = k;
                }
            }
            (last_first_seen, tracker.stats.lost_warp)
        };
        let (last_limited, lost) = fly(Some(0.2));
        let (last_free, lost_free) = fly(None);
        eprintln!(
            "first frame's tracks seen last at frame {last_limited} (limit 0.2, {lost} dropped) / {last_free} (none)"
        );
        // 1.01^19 = 1.208: none of them past frame 19 (the warp's estimate
        // may run a frame behind the zoom).
        assert!((15..=20).contains(&last_limited), "{last_limited}");
        assert!(lost > 50, "{lost} dropped for their warp");
        assert_eq!(lost_free, 0);
        assert_eq!(last_free, 39, "without the limit the first tracks live on");
    }

    /// A textured plane seen by a camera that pans and zooms (a homography
    /// per frame, so every pixel's truth is known): over 40 frames at
    /// 752×480, at least 95 % of the tracks stay within 1 px of the point
    /// they started on, and the tracker keeps its 150 features.
    #[test]
    fn tracks_follow_their_points() {
        let (w, h) = (752usize, 480usize);
        let tex = Texture::new(11, 900.0);
        let mut tracker = Tracker::new(TrackerParams::default(), None);
        // Texture point of each id where first seen, and its largest
        // distance from it since.
        let mut origin: std::collections::BTreeMap<u64, ([f64; 2], f64, u32)> = Default::default();
        for k in 0..40 {
            let t = k as f64;
            // Pan 3 px a frame right and 1.5 down, a slow zoom and roll.
            let s = 1.0 + 0.002 * t;
            let a = 0.002 * t;
            let hmat = Matrix3::new(
                s * a.cos(),
                -s * a.sin(),
                3.0 * t,
                s * a.sin(),
                s * a.cos(),
                1.5 * t,
                0.0,
                0.0,
                1.0,
            );
            let img = tex.render(w, h, &hmat);
            let inv = hmat.try_inverse().unwrap();
            let feats = tracker.process(&img).to_vec();
            assert!(feats.len() >= 140, "frame {k}: {} features", feats.len());
            for f in &feats {
                let p = apply(&inv, [f64::from(f.u_px), f64::from(f.v_px)]);
                let e = origin.entry(f.id).or_insert((p, 0.0, 0));
                e.1 = e.1.max(((p[0] - e.0[0]).powi(2) + (p[1] - e.0[1]).powi(2)).sqrt());
                e.2 = f.age;
            }
        }
        let tracked: Vec<_> = origin.values().filter(|v| v.2 > 0).collect();
        let good = tracked.iter().filter(|v| v.1 < 1.0).count();
        let share = good as f64 / tracked.len() as f64;
        let mean_life = tracked.iter().map(|v| f64::from(v.2)).sum::<f64>() / tracked.len() as f64;
        eprintln!(
            "{good} of {} tracks within 1 px of their point over their life ({:.1} %), mean life {mean_life:.1} frames",
            tracked.len(),
            100.0 * share
        );
        assert!(share >= 0.95, "{share}");
        assert!(mean_life > 10.0, "{mean_life}");
    }
}
