//! The MSCKF track update (README.md §3): each camera frame adds a clone or
//! a keyframe, then the tracks that end (or would lose their oldest view as
//! the window slides) are triangulated, projected onto the left null space
//! of their feature Jacobian, χ²-gated, stacked, QR-compressed and applied as
//! one EKF update through [`Estimator::ekf_update`]. A track that re-observes
//! a landmark held by a keyframe also constrains that keyframe (§4); in
//! compressed mode a global keyframe is first made local (§5 P1–P3).

use crate::counters::Counter;
use std::collections::BTreeSet;
use std::rc::Rc;

use nalgebra::{DMatrix, DVector};

use super::feature::{self, Obs, Reject, View};
use super::math;
use super::{
    CloneState, Estimator, FilterEvent, FrameReport, GlobalReason, InputError, Mode, NormObs, Stats, Track,
    MAX_KEYFRAMES_PER_TRACK, PENDING_PROMOTIONS_PER_FRAME,
};

/// A track's bearings must spread over this many angular sigmas of one
/// observation to be triangulated (§3c).
const PARALLAX_NOISE_SIGMAS: f64 = 5.0;

/// A track that fails to triangulate with less than this many times the
/// parallax bound counts as poor parallax, not as inconsistent (§3c).
const WEAK_PARALLAX_FACTOR: f64 = 4.0;

/// Landmarks remembered for low-parallax tracks (§3e): each for this long
/// after it was last triangulated (s), at most this many.
const LANDMARK_MEMORY_S: f64 = 30.0;
const MAX_REMEMBERED_LANDMARKS: usize = 4096;

/// Fastest estimated speed at which low-parallax tracks are used (m/s, §3e).
const LOW_PARALLAX_MAX_SPEED_MPS: f64 = 1.0;

/// A remembered landmark's inverse depth is known to this fraction of it
/// (§3e, LP3).
const REMEMBERED_INVERSE_DEPTH_SIGMA: f64 = 0.6;

/// The gated tracks' rows of one frame, in buffers the filter keeps (issue
/// 43: each passing track's rows were two allocations, and the stack one
/// more): each track's projected Jacobian, column-major over its columns
/// `idx` of `P`, and its projected residual, appended in order; the columns
/// are shared with the other tracks over the same views (most span the
/// whole window). Also the stack `[H | r]` they are written into and its
/// union of columns.
#[derive(Default)]
pub(super) struct StackRows {
    h: Vec<f64>,
    r: Vec<f64>,
    tracks: Vec<(usize, Rc<[usize]>)>,
    union: Vec<usize>,
    hr: DMatrix<f64>,
}

impl StackRows {
    fn clear(&mut self) {
        self.h.clear();
        self.r.clear();
        self.tracks.clear();
    }

    /// Appends one track's `rows` rows: its Jacobian's columns (one slice
    /// of `rows` entries for each of `idx`) and its residual.
    fn push<'a>(&mut self, columns: impl Iterator<Item = &'a [f64]>, r: &[f64], idx: Rc<[usize]>) {
        for c in columns {
            debug_assert_eq!(c.len(), r.len());
            self.h.extend_from_slice(c);
        }
        self.r.extend_from_slice(r);
        self.tracks.push((r.len(), idx));
    }

    fn len(&self) -> usize {
        self.tracks.len()
    }
}

/// The columns of the last gated track's `P_sub`, shared with the rows of
/// every track over the same views (most span the whole window): a frame's
/// own, since `P` changes with each update.
#[derive(Default)]
struct GateCache {
    idx: Option<Rc<[usize]>>,
}

impl GateCache {
    /// `P_sub` over the pose columns of the views at `cols`, into `p_sub`
    /// (gathered again, and its columns allocated again, only when they
    /// change); the indices.
    fn gather(
        &mut self,
        (buf, p_sub): (&mut Vec<usize>, &mut DMatrix<f64>),
        p: &DMatrix<f64>,
        cols: &[usize],
    ) -> Rc<[usize]> {
        buf.clear();
        buf.extend(cols.iter().flat_map(|&c| c..c + 6));
        match &self.idx {
            Some(idx) if **idx == **buf => Rc::clone(idx),
            _ => {
                math::reshape_zeroed(p_sub, buf.len(), buf.len());
                math::gather_block(p, buf, p_sub);
                let idx: Rc<[usize]> = Rc::from(buf.as_slice());
                self.idx = Some(Rc::clone(&idx));
                idx
            }
        }
    }
}

/// What a track's gate works in, kept by the filter across tracks and
/// frames so that its working buffers allocate nothing once they have grown
/// (issue 43; a new column set's index list and a low-parallax track's
/// system still do): the track's views, their columns in `P` and its
/// observations as [`Estimator::track_views`] lays them out, its matrices
/// ([`feature::TrackScratch`]), the gathered `P_sub` with its columns, and
/// the frame's passing rows ([`StackRows`]).
/// The filter holds it in a [`math::Scratch`]: a clone starts empty.
#[derive(Default)]
pub(super) struct GateScratch {
    views: Vec<View>,
    view_cols: Vec<usize>,
    obs: Vec<Obs>,
    track: feature::TrackScratch,
    cols: Vec<usize>,
    p_sub: DMatrix<f64>,
    stack: StackRows,
}

/// The χ² test of a NIS of `dof` degrees of freedom against the `prob`
/// quantile of `χ²(dof)`: the NIS if under it, `over` if not (a NaN NIS
/// too).
fn chi2_check(nis: f64, dof: usize, prob: f64, over: Reject) -> Result<f64, Reject> {
    if nis.is_nan() || nis > cmsckf_models::stats::chi2_quantile(prob, dof) {
        Err(over)
    } else {
        Ok(nis)
    }
}

/// The χ² gate of a low-parallax track (§3e, G1 with LP4's rows):
/// `rᵀ S⁻¹ r` with `S = H P_sub Hᵀ + I` (unit, whitened noise), through
/// [`chi2_check`]. `hph` is `H P_sub Hᵀ`; `S` and `S⁻¹ r` are formed in the
/// two buffers given (a failed factorisation drops `S`'s, which the next
/// track grows again). `NonFinite` if `S` is not positive definite.
fn chi2_gate(
    hph: nalgebra::DMatrixView<f64>,
    r: nalgebra::DVectorView<f64>,
    (s, s_inv_r): (&mut DMatrix<f64>, &mut DVector<f64>),
    (prob, over): (f64, Reject),
) -> Result<f64, Reject> {
    let n = hph.nrows();
    math::reshape_zeroed(s, n, n);
    s.copy_from(&hph);
    for i in 0..n {
        s[(i, i)] += 1.0;
    }
    let ch = std::mem::replace(s, DMatrix::zeros(0, 0))
        .cholesky()
        .ok_or(Reject::NonFinite)?;
    math::reshape_zeroed_vector(s_inv_r, n);
    s_inv_r.copy_from(&r);
    ch.solve_mut(s_inv_r);
    let nis = r.dot(s_inv_r);
    *s = ch.unpack();
    chi2_check(nis, r.len(), prob, over)
}

/// Counts a rejected track in the frame's report and the filter's stats.
fn reject(rep: &mut FrameReport, st: &mut Stats, r: Reject) {
    *rep.rejected.entry(r).or_default() += 1;
    *st.rejected.entry(r.counter()).or_default() += 1;
}

/// The buffers one camera frame's bookkeeping works in, kept by the filter
/// so that a frame allocates none of them again (issue 43): the frame's
/// landmark ids (sorted, distinct), the ids and tracks ready for the
/// update, and the observation lists of tracks that ended, for new tracks
/// to take.
#[derive(Default)]
pub(super) struct FrameScratch {
    present: Vec<u64>,
    ready: Vec<u64>,
    ready_tracks: Vec<(u64, Track)>,
    track_pool: Vec<Vec<(u64, NormObs)>>,
}

/// Lists kept for new tracks at most, whatever the input: more ended
/// tracks than that in one frame are freed. With the lists' own bound
/// (`recycle`), the pool holds at most 1024 window-sized lists; the other
/// buffers keep the largest frame's size (`camera.max_features` bounds it).
const TRACK_POOL_MAX: usize = 1024;

/// Gives an ended track's list back for a new track to take, emptied; only
/// a list of the window's size (`cap`, the size new tracks are made with):
/// one that grew past it is freed, so the pool cannot keep outsized lists.
fn recycle(pool: &mut Vec<Vec<(u64, NormObs)>>, mut list: Vec<(u64, NormObs)>, cap: usize) {
    if pool.len() < TRACK_POOL_MAX && (1..=cap).contains(&list.capacity()) {
        list.clear();
        pool.push(list);
    }
}

impl Estimator {
    /// Processes one camera frame stamped `t_cam_s` by the camera's clock
    /// (§3–§5): it is fused at `t_cam_s + t_d` on the IMU clock, with `t_d`
    /// the time offset estimate (§3b). The IMU samples up to (and preferably
    /// just past) that time must have been added.
    pub(super) fn update_with_frame(&mut self, t_cam_s: f64, obs: &[NormObs]) -> Result<FrameReport, InputError> {
        let t_s = t_cam_s + self.t_d_s;
        self.advance_to(t_s, Counter::FrameTimeBackwards)?;
        self.stats.frames += 1;
        let mut report = FrameReport::default();
        self.global_update_if_due(&mut report);
        let still = std::mem::take(&mut self.still);
        // The body rate the time offset's column takes (§3b, T3): smoothed
        // about the frame's instant, not the last sample nor the interval's
        // mean, which a multirotor's motors shake by more than a slow turn.
        self.frame_rate_B = self
            .smoothed_rate_radps(t_s)
            .or_else(|| still.mean_rate_radps())
            .map(|w| w - self.imu.b_g);
        let (disparity, camera_moved) = self.camera_disparity(obs);
        report.camera_moved = camera_moved;
        if self.zero_velocity_update(&still, disparity) {
            self.monitor.push_frame(t_s, &[], 0, 0);
            report.zupt = true;
            return Ok(report);
        }

        // The frame's landmarks, sorted and distinct, in a kept buffer.
        let mut fs = std::mem::take(&mut self.frame_scratch.0);
        fs.present.clear();
        fs.present.extend(obs.iter().map(|o| o.landmark_id));
        fs.present.sort_unstable();
        fs.present.dedup();
        self.add_view(t_s, obs, &mut fs.track_pool, &mut report);

        // Tracks to use now: lost ones, and those that would lose their
        // oldest observation when the window slides.
        let oldest = if self.clones.len() > self.s.max_clones {
            self.clones.front().map(|c| c.seq)
        } else {
            None
        };
        let present = &fs.present;
        fs.ready.clear();
        fs.ready.extend(
            self.tracks
                .iter()
                .filter(|(l, tr)| {
                    present.binary_search(l).is_err()
                        || oldest.is_some_and(|s| tr.obs.first().is_some_and(|o| o.0 == s))
                })
                .map(|(l, _)| *l),
        );
        fs.ready_tracks.clear();
        for l in &fs.ready {
            if let Some(t) = self.tracks.remove(l) {
                fs.ready_tracks.push((*l, t));
            }
        }
        self.update_tracks(&mut fs.ready_tracks, &mut fs.track_pool, &mut report);

        // Keyframe observations become usable once their landmark has left view
        // (after this frame's update, so only a later re-detection uses them).
        self.release_keyframe_observations(&fs.present);
        if let Some(seq) = oldest {
            self.marginalise_clone(seq, &mut fs.track_pool);
        }
        self.frame_scratch.0 = fs;
        // Tracks the poses cannot explain: failed the χ² gate, or failed to
        // triangulate to a depth or a fit (§9 D1).
        let count = |r: Reject| report.rejected.get(&r).copied().unwrap_or(0);
        let tri_failed = count(Reject::BadDepth) + count(Reject::NotConverged);
        // The monitor judges the triangulated tracks alone, as it did before
        // low-parallax tracks were used: those it cannot count fairly (their
        // refusals are not counted, §3e), so their acceptances are not
        // counted either. The report's NIS holds both.
        self.monitor
            .push_frame(t_s, &report.nis, count(Reject::Chi2), tri_failed);
        report.nis.append(&mut self.low_parallax_nis);
        Ok(report)
    }

    /// Compressed: leaving the local region triggers a global update and
    /// moves the centre to the vehicle (§5). So does a local part over its
    /// keyframe bound. While a rebase is still being computed the next one
    /// waits.
    fn global_update_if_due(&mut self, report: &mut FrameReport) {
        let left = (self.imu.p_B_in_W - self.centre_W).norm() > self.s.local_radius_m;
        let full = self.local_kfs.len() > self.s.max_local_keyframes;
        if self.s.mode == Mode::Compressed && self.pending.is_none() && (left || full) {
            if left {
                self.centre_W = self.imu.p_B_in_W;
            }
            let reason = if left {
                GlobalReason::LeftLocalRegion
            } else {
                GlobalReason::LocalPartFull
            };
            if let Some(ev) = self.begin_rebase(reason) {
                report.events.push(ev);
                report.global_updates += 1;
            }
        }
    }

    /// The frame's pose enters the state: as a keyframe when one is due
    /// (its observations kept beside it, §4), else as a new clone appended
    /// after the last one, its observations extending the window's tracks.
    fn add_view(&mut self, t_s: f64, obs: &[NormObs], pool: &mut Vec<Vec<(u64, NormObs)>>, report: &mut FrameReport) {
        let make_kf = self.s.mode != Mode::Msckf
            && self.s.keyframe_max > 0
            && t_s - self.last_kf_t_s >= self.s.keyframe_interval_s - 1e-9;
        if make_kf {
            let id = self.create_keyframe(t_s, obs);
            report.events.push(FilterEvent::KeyframeCreated { id });
            report.keyframe_created = true;
        } else {
            let at = self.gnss_clones_offset();
            self.augment_view(at);
            let seq = self.next_seq;
            self.next_seq += 1;
            self.clones.push_back(CloneState {
                seq,
                q_W_B: self.imu.q_W_B,
                p_B_in_W: self.imu.p_B_in_W,
                p_fej_in_W: self.p_first_estimate(),
            });
            // Room for a track's views once, not grown sample by sample, and
            // taken from the lists of tracks that ended when there are any.
            let cap = self.track_capacity();
            for o in obs {
                self.tracks
                    .entry(o.landmark_id)
                    .or_insert_with(|| Track {
                        obs: pool.pop().unwrap_or_else(|| Vec::with_capacity(cap)),
                    })
                    .obs
                    .push((seq, *o));
            }
        }
    }

    /// The views a track can hold: the window's, and one more while it
    /// slides. New tracks' lists are made this size, and only lists of it
    /// are recycled.
    fn track_capacity(&self) -> usize {
        self.s.max_clones + 1
    }

    /// Marginalises the oldest clone; tracks still holding it drop it (an
    /// emptied track's list goes back to `pool`).
    fn marginalise_clone(&mut self, seq: u64, pool: &mut Vec<Vec<(u64, NormObs)>>) {
        if let Some(at) = self.clone_offset_by_seq(seq) {
            self.remove_block(at, 6);
        }
        self.clones.pop_front();
        for tr in self.tracks.values_mut() {
            tr.obs.retain(|o| o.0 != seq);
        }
        let cap = self.track_capacity();
        self.tracks.retain(|_, t| {
            if t.obs.is_empty() {
                recycle(pool, std::mem::take(&mut t.obs), cap);
                false
            } else {
                true
            }
        });
    }

    /// Triangulates, projects and gates each track, then applies one stacked
    /// update (§3).
    fn update_tracks(
        &mut self,
        ready: &mut Vec<(u64, Track)>,
        pool: &mut Vec<Vec<(u64, NormObs)>>,
        report: &mut FrameReport,
    ) {
        let mut kf_use = self.keyframes_for_tracks(ready);
        if self.s.mode == Mode::Compressed {
            self.promote_for_tracks(&mut kf_use, report);
        }
        let mut involved = BTreeSet::new();
        let mut gate = GateCache::default();
        let mut scratch = std::mem::take(&mut self.gate_scratch.0);
        scratch.stack.clear();
        let cap = self.track_capacity();
        for ((l, tr), ks) in ready.drain(..).zip(kf_use) {
            let passed = self.gate_track(l, &tr, &ks, (&mut gate, &mut scratch), report);
            recycle(pool, tr.obs, cap);
            if passed {
                involved.extend(ks.iter().copied());
            }
        }
        self.forget_landmarks();
        let used = scratch.stack.len();
        report.tracks_used = used;
        self.stats.tracks_used += used as u64;
        self.stats.low_parallax_tracks += report.low_parallax_tracks as u64;
        self.stats.loop_closure_updates += report.loop_closure_tracks as u64;
        if used > 0 {
            self.stacked_update(&mut scratch.stack, report);
        }
        self.gate_scratch.0 = scratch;
        if used == 0 {
            return;
        }
        report.events.push(FilterEvent::Update {
            tracks: used,
            keyframes: involved.into_iter().collect(),
        });
    }

    /// The keyframe observations each ready track may use: eligible ones
    /// (§4), at most `MAX_KEYFRAMES_PER_TRACK`, spread from the oldest to
    /// the newest: dense keyframes add little beyond that, and each one
    /// costs a column block (and, if global, a promotion).
    fn keyframes_for_tracks(&self, ready: &[(u64, Track)]) -> Vec<Vec<u64>> {
        let mut kf_use: Vec<Vec<u64>> = Vec::with_capacity(ready.len());
        for (l, _) in ready {
            let mut ks = Vec::new();
            if let Some(set) = self.kf_by_landmark.get(l) {
                for k in set {
                    if self
                        .keyframes
                        .get(k)
                        .and_then(|kf| kf.obs.get(l))
                        .is_some_and(|o| o.eligible)
                    {
                        ks.push(*k);
                    }
                }
            }
            if ks.len() > MAX_KEYFRAMES_PER_TRACK {
                let n = ks.len() - 1;
                ks = (0..MAX_KEYFRAMES_PER_TRACK)
                    .map(|i| ks[i * n / (MAX_KEYFRAMES_PER_TRACK - 1)])
                    .collect();
            }
            kf_use.push(ks);
        }
        kf_use
    }

    /// A measurement that touches a global keyframe first makes it local
    /// (§5 P1–P3). While a rebase is out (§5 R5) the local part cannot shed
    /// keyframes, and each one promoted makes every update until the rebase
    /// after next dearer: promote at most `PENDING_PROMOTIONS_PER_FRAME`,
    /// those the most observations need, within the local bound; the other
    /// observations wait for a later track (removed from `kf_use`).
    fn promote_for_tracks(&mut self, kf_use: &mut [Vec<u64>], report: &mut FrameReport) {
        let global_needed: Vec<u64> = self
            .global
            .as_ref()
            .map(|g| {
                kf_use
                    .iter()
                    .flatten()
                    .filter(|k| g.live.contains_key(k))
                    .copied()
                    .collect::<BTreeSet<u64>>()
                    .into_iter()
                    .collect()
            })
            .unwrap_or_default();
        if global_needed.is_empty() {
            return;
        }
        let mut chosen = global_needed.clone();
        if self.pending.is_some() {
            let room =
                (self.s.max_local_keyframes.saturating_sub(self.local_kfs.len())).min(PENDING_PROMOTIONS_PER_FRAME);
            let uses = |id: &u64| kf_use.iter().flatten().filter(|k| *k == id).count();
            chosen.sort_by_key(|id| (std::cmp::Reverse(uses(id)), *id));
            chosen.truncate(room);
            chosen.sort_unstable();
        }
        if chosen.is_empty() || !self.promote(&chosen) {
            chosen.clear();
        } else {
            report.promoted = chosen.len();
            report.events.push(FilterEvent::Promoted {
                keyframes: chosen.clone(),
            });
        }
        let waiting: Vec<u64> = global_needed.into_iter().filter(|k| !chosen.contains(k)).collect();
        if !waiting.is_empty() {
            let mut deferred = 0;
            for ks in kf_use.iter_mut() {
                let before = ks.len();
                ks.retain(|k| !waiting.contains(k));
                deferred += before - ks.len();
            }
            report.deferred += deferred;
            self.stats.loop_closure_deferred += deferred as u64;
        }
    }

    /// The views of track `l`: its clones, then the keyframes `ks`; with
    /// each view's column in `P` (`usize::MAX` for a keyframe not in the
    /// state) and the number of clone observations.
    fn track_views(&self, l: u64, tr: &Track, ks: &[u64], buf: &mut GateScratch) -> usize {
        let GateScratch {
            views,
            view_cols: cols,
            obs,
            ..
        } = buf;
        views.clear();
        cols.clear();
        obs.clear();
        for (seq, o) in &tr.obs {
            let Some(off) = self.clone_offset_by_seq(*seq) else {
                continue;
            };
            let c = &self.clones[((seq - self.clones[0].seq) as usize).min(self.clones.len() - 1)];
            obs.push(Obs {
                view: views.len(),
                xn: o.xn,
                W: o.W,
            });
            views.push(View {
                R_W_B: c.q_W_B.to_rotation_matrix().into_inner(),
                p_B_in_W: c.p_B_in_W,
                p_lin_in_W: c.p_fej_in_W,
            });
            cols.push(off);
        }
        let clone_obs = obs.len();
        for k in ks {
            let kf = &self.keyframes[k];
            let off = self.local_kfs.iter().position(|x| x == k).map(|j| self.kf_offset(j));
            let o = kf.obs[&l].obs;
            obs.push(Obs {
                view: views.len(),
                xn: o.xn,
                W: o.W,
            });
            views.push(View {
                R_W_B: kf.q_W_B().to_rotation_matrix().into_inner(),
                p_B_in_W: kf.p_B_in_W,
                p_lin_in_W: kf.p_fej_in_W,
            });
            // A keyframe in the state (local), or a Schmidt/full keyframe.
            cols.push(off.unwrap_or(usize::MAX));
        }
        clone_obs
    }

    /// One track through triangulation, the null-space projection and the
    /// χ² gate (§3); its rows if it passes. A loop-closure track uses each
    /// keyframe observation once.
    fn gate_track(
        &mut self,
        l: u64,
        tr: &Track,
        ks: &[u64],
        (gate, w): (&mut GateCache, &mut GateScratch),
        report: &mut FrameReport,
    ) -> bool {
        let clone_obs = self.track_views(l, tr, ks, w);
        let GateScratch {
            views,
            view_cols: cols,
            obs,
            track,
            cols: gather_buf,
            p_sub,
            stack,
        } = w;
        let (views, cols, obs) = (&views[..], &cols[..], &obs[..]);
        if clone_obs == 0 || obs.len() < self.s.min_track_len || cols.contains(&usize::MAX) {
            reject(report, &mut self.stats, Reject::TooFewObservations);
            return false;
        }
        // Too little parallax to triangulate (a hover, a standstill, a far
        // landmark): skipped, and not a sign of inconsistency (§3c). Pixel
        // noise alone spreads the rays of a still camera: the bound is at
        // least five times an observation's angular sigma (1/W). With a σ
        // per observation, that of the track's mean information,
        // `1/√mean(W²)`: one loose observation (a large σ, weighing almost
        // nothing) barely moves it, as it barely moves the triangulation.
        let info = obs.iter().map(|o| o.W[(0, 0)] * o.W[(0, 0)]).sum::<f64>() / obs.len() as f64;
        let noise_rad = 1.0 / info.sqrt();
        let min_parallax = self.s.min_parallax_rad.max(PARALLAX_NOISE_SIGMAS * noise_rad);
        let parallax = feature::parallax_rad(views, &self.s.ext, obs);
        // NaN (a non-finite bearing) is not enough parallax either.
        if parallax.is_nan() || parallax < min_parallax {
            return self.gate_low_parallax(
                (l, ks),
                (views, cols, obs),
                (gate, gather_buf, p_sub, track, stack),
                report,
            );
        }
        let p_f = match feature::triangulate(views, &self.s.ext, obs, &self.s.tri) {
            Ok(p) => p,
            // With little more parallax than the bound, a depth out of range
            // or a fit that does not settle is the geometry's weakness, not
            // the poses' inconsistency: a low-parallax track.
            Err(Reject::BadDepth | Reject::NotConverged) if parallax < WEAK_PARALLAX_FACTOR * min_parallax => {
                return self.gate_low_parallax(
                    (l, ks),
                    (views, cols, obs),
                    (gate, gather_buf, p_sub, track, stack),
                    report,
                );
            }
            Err(r) => {
                reject(report, &mut self.stats, r);
                return false;
            }
        };
        // The projected rows, in `track`'s buffers until the track passes.
        feature::track_system_into(views, &self.s.ext, obs, &p_f, track);
        let (r0, keep) = feature::nullspace_project_into(&track.hx, &track.hf, &track.r, &mut track.projected);
        let nx = track.hx.ncols();
        // `[H_x | r]` is columns 3..=3 + n_x, each contiguous: checked as
        // slices (a strided view's element iterator was 2.8 % of an
        // `evaluate` run's samples on udel_gore).
        let finite = (3..=3 + nx).all(|c| math::all_finite(&track.projected.column(c).as_slice()[r0..r0 + keep]));
        let r_col = track.projected.column(3 + nx);
        let r = r_col.rows(r0, keep);
        if !finite {
            reject(report, &mut self.stats, Reject::NonFinite);
            return false;
        }
        // χ² gate on S = H P_sub Hᵀ + I (§3, eqs. G1, G1′): the NIS from the
        // unprojected rows, whose covariance is block by block.
        let idx = gate.gather((gather_buf, p_sub), &self.P, cols);
        let system = (&track.hx, &track.hf, &track.r);
        let nis = match feature::projected_nis_into(system, obs, p_sub, (&mut track.c, &mut track.y))
            .and_then(|(nis, dof)| chi2_check(nis, dof, self.s.chi2_gate_prob, Reject::Chi2))
        {
            Ok(nis) => nis,
            Err(why) => {
                reject(report, &mut self.stats, why);
                return false;
            }
        };
        report.nis.push((nis, r.len()));
        report.landmarks_W.push(p_f);
        if self.s.low_parallax_updates {
            // Where a later track of it with too little parallax is
            // linearised (§3e).
            self.landmark_memory.insert(l, p_f, self.t_s);
        }
        if !ks.is_empty() {
            report.loop_closure_tracks += 1;
            let now = self.t_s;
            for k in ks {
                if let Some(kf) = self.keyframes.get_mut(k) {
                    kf.obs.remove(&l);
                    kf.last_used_s = now;
                }
                if let Some(set) = self.kf_by_landmark.get_mut(&l) {
                    set.remove(k);
                }
            }
        }
        // The rows leave the track's buffers only for a track that passed.
        let (all, rows) = (track.projected.as_slice(), track.projected.nrows());
        let column = |c: usize| &all[c * rows + r0..c * rows + r0 + keep];
        stack.push((3..3 + nx).map(column), column(3 + nx), idx);
        true
    }

    /// A track with too little parallax to triangulate (§3e): used where
    /// its landmark was last triangulated, with its depth a nuisance, when
    /// the filter remembers it and the track holds no keyframe view. Its
    /// rows if they pass the χ² gate; otherwise it counts as poor parallax,
    /// and never against health: a landmark that was never triangulated,
    /// or that moved, is no divergence.
    fn gate_low_parallax(
        &mut self,
        (l, ks): (u64, &[u64]),
        (views, cols, obs): (&[View], &[usize], &[Obs]),
        (gate, gather_buf, p_sub, track, stack): (
            &mut GateCache,
            &mut Vec<usize>,
            &mut DMatrix<f64>,
            &mut feature::TrackScratch,
            &mut StackRows,
        ),
        report: &mut FrameReport,
    ) -> bool {
        // A still track says "no motion" as firmly as its remembered depth
        // allows. On a vehicle that is moving it is likelier a frozen camera
        // or a scene that moves with the vehicle than a distant landmark:
        // used only as slow as a hover.
        let slow = self.imu.v_B_in_W.norm() <= LOW_PARALLAX_MAX_SPEED_MPS;
        let remembered = self.landmark_memory.get(l);
        let prior = match remembered {
            Some(p_W) if self.s.low_parallax_updates && ks.is_empty() && slow => feature::DepthPrior {
                p_W,
                inverse_depth_sigma_ratio: REMEMBERED_INVERSE_DEPTH_SIGMA,
            },
            _ => {
                reject(report, &mut self.stats, Reject::PoorParallax);
                return false;
            }
        };
        let Ok(feature::LowParallaxRows { hx, r, .. }) =
            feature::low_parallax_system(views, &self.s.ext, obs, prior, self.s.tri.min_depth_m)
        else {
            reject(report, &mut self.stats, Reject::PoorParallax);
            return false;
        };
        if !(math::all_finite(hx.as_slice()) && math::all_finite(r.as_slice())) {
            reject(report, &mut self.stats, Reject::NonFinite);
            return false;
        }
        // G1 with the whitened rows of LP4: S = H P_sub Hᵀ + I.
        let idx = gate.gather((gather_buf, p_sub), &self.P, cols);
        let hph = &hx * &*p_sub * hx.transpose();
        // Refused, it counts as poor parallax, never against health.
        let gate_bufs = (&mut track.s, &mut track.s_inv_r);
        let nis = match chi2_gate(
            hph.as_view(),
            r.as_view(),
            gate_bufs,
            (self.s.chi2_gate_prob, Reject::PoorParallax),
        ) {
            Ok(nis) => nis,
            Err(why) => {
                reject(report, &mut self.stats, why);
                return false;
            }
        };
        self.low_parallax_nis.push((nis, r.len()));
        report.low_parallax_tracks += 1;
        stack.push(
            hx.as_slice().chunks_exact(r.len().max(1)).take(hx.ncols()),
            r.as_slice(),
            idx,
        );
        true
    }

    /// Forgets the landmarks triangulated more than `LANDMARK_MEMORY_S`
    /// ago (judged once a second), and the oldest beyond
    /// `MAX_REMEMBERED_LANDMARKS` (§3e).
    fn forget_landmarks(&mut self) {
        if self.t_s - self.landmarks_forgotten_s >= 1.0 {
            self.landmarks_forgotten_s = self.t_s;
            self.landmark_memory.forget_up_to(self.t_s - LANDMARK_MEMORY_S);
        }
        // More than the bound triangulated within the memory's span (a
        // dense scene): the excess oldest go.
        self.landmark_memory.bound(MAX_REMEMBERED_LANDMARKS);
    }

    /// Stacks the gated tracks over the union of their columns, in state
    /// order (keyframes by id, then clones by age), so every mode builds the
    /// same matrix whatever else its state holds; compresses it by QR when
    /// taller than the state (§3, eq. Q1) and applies it.
    fn stacked_update(&mut self, rows: &mut StackRows, report: &mut FrameReport) {
        let StackRows {
            h,
            r: rs,
            tracks,
            union,
            hr,
        } = rows;
        union.clear();
        union.extend(tracks.iter().flat_map(|t| t.1.iter().copied()));
        union.sort_unstable();
        union.dedup();
        let m = rs.len();
        let nc = union.len();
        // [H | r]: the residual rides along as the last column.
        math::reshape_zeroed(hr, m, nc + 1);
        let (mut row, mut at) = (0, 0);
        for (rows_k, idx) in tracks.iter() {
            for col in idx.iter() {
                let uc = union.binary_search(col).expect("column in union");
                hr.view_mut((row, uc), (*rows_k, 1))
                    .copy_from_slice(&h[at..at + rows_k]);
                at += rows_k;
            }
            row += rows_k;
        }
        debug_assert_eq!(at, h.len(), "each track pushed rows × its columns");
        debug_assert_eq!(row, m);
        hr.column_mut(nc).copy_from_slice(rs);
        report.residual_rms = (hr.column(nc).norm_squared() / m as f64).sqrt();
        // Qᵀ [H | r] = [T r_T; 0 r_⊥], keep (T, r_T).
        let keep = if m > nc {
            math::householder_in_place(hr, nc);
            nc
        } else {
            m
        };
        let hk = math::block_owned(hr, 0, 0, keep, nc);
        let r = DVector::from_column_slice(&hr.column(nc).as_slice()[..keep]);
        self.ekf_update(&hk, union, &r, m > nc);
        self.stats.updates += 1;
    }
}
