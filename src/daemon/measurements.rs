//! The measurements waiting for IMU to cover their time, and their fusing:
//! GNSS epochs and camera frames in time order, their filter events to the
//! log, and their counters.

use std::collections::VecDeque;

use cmsckf_models::geodesy::NedFrame;
use cmsckf_models::gnss::SatMeas;
use cmsckf_models::stats::chi2_quantile;
use serde_json::json;

use super::base_use::BaseUse;
use super::frames::LandmarkCloud;
use super::rebase::{dispatch_rebase, RebaseExec};
use super::PENDING_FRAMES;
use crate::counters::{Counter, Counters};
use crate::estimator::frontend::NormFrame;
use crate::estimator::{BaroOutcome, Estimator, FilterEvent, FrameReport};
use crate::io::mcap_log::{McapLogger, Topic};
use crate::status::Tracker;

/// A measurement waiting for IMU to cover its time.
#[derive(Debug)]
pub(super) enum Pending {
    Frame(NormFrame),
    Gnss(Vec<SatMeas>),
    /// A barometer reading as the standard atmosphere's height (m, up).
    Baro(f64),
}

/// The measurements waiting for IMU, in time order (bounded: the oldest is
/// dropped), the last frame's time, and the landmarks of the fused tracks
/// gathered for the log.
#[derive(Debug)]
pub(super) struct MeasurementQueue {
    pending: VecDeque<(f64, Pending)>,
    last_frame_t: f64,
    landmarks: LandmarkCloud,
}

/// What fusing a measurement reports to: the filter's generation and the
/// rebase worker (for the global updates it starts), the status tracker,
/// the log, the world frame (GNSS needs its origin) and the counters.
pub(super) struct FuseCtx<'a> {
    pub(super) rebase: &'a mut RebaseExec,
    pub(super) est_gen: u64,
    pub(super) tracker: &'a mut Tracker,
    pub(super) log: Option<&'a McapLogger>,
    pub(super) frame: Option<NedFrame>,
    pub(super) counters: &'a Counters,
    /// The base's use: told how its corrected codes fared.
    pub(super) base: &'a mut BaseUse,
}

impl Default for MeasurementQueue {
    fn default() -> Self {
        Self {
            pending: VecDeque::with_capacity(PENDING_FRAMES),
            last_frame_t: f64::NEG_INFINITY,
            landmarks: LandmarkCloud::default(),
        }
    }
}

impl MeasurementQueue {
    /// Autopilot time of the last frame accepted (−∞ before the first).
    pub(super) fn last_frame_t(&self) -> f64 {
        self.last_frame_t
    }

    /// Queues a camera frame at `t`, which must be after the last one.
    pub(super) fn push_frame(&mut self, t: f64, frame: NormFrame, counters: &Counters) {
        self.last_frame_t = t;
        self.enqueue(t, Pending::Frame(frame), counters);
    }

    /// Queues a measurement in time order (bounded: the oldest barometer
    /// reading is dropped first, a 10 Hz height being worth less than a
    /// frame or an epoch; else the oldest).
    pub(super) fn enqueue(&mut self, t: f64, item: Pending, counters: &Counters) {
        if self.pending.len() == PENDING_FRAMES {
            match self.pending.iter().position(|(_, p)| matches!(p, Pending::Baro(_))) {
                Some(i) => {
                    self.pending.remove(i);
                }
                None => {
                    self.pending.pop_front();
                }
            }
            counters.add(Counter::PendingOverflow, 1);
        }
        let at = self.pending.partition_point(|(u, _)| *u <= t);
        self.pending.insert(at, (t, item));
    }

    /// Drops what a filter started at `t_s` cannot take.
    pub(super) fn drop_before(&mut self, t_s: f64) {
        self.pending.retain(|(t, _)| *t >= t_s);
    }

    /// Forgets every measurement and time (the autopilot's clock restarted).
    pub(super) fn clear(&mut self) {
        self.pending.clear();
        self.last_frame_t = f64::NEG_INFINITY;
    }

    /// The measurements now covered by IMU (up to `t_imu_s`), into `est` in
    /// time order. A frame older than the filter is late and counted; a
    /// GNSS epoch goes to the filter whatever its time, which fuses it at
    /// that time through its clone or refuses it as late (§8b).
    pub(super) fn fuse_covered(&mut self, t_imu_s: f64, est: &mut Estimator, mut cx: FuseCtx<'_>) -> Fused {
        let mut fused = Fused::default();
        while let Some((t, item)) = self.pending.front() {
            // A frame is fused at its stamp plus the time offset (§3b): that
            // is the time IMU must cover, and the filter must not be past.
            let is_frame = matches!(item, Pending::Frame(_));
            let t_fused = *t + if is_frame { est.time_offset().0 } else { 0.0 };
            if t_fused > t_imu_s {
                break;
            }
            let Some((t, item)) = self.pending.pop_front() else {
                break;
            };
            if is_frame && t_fused < est.time_s() {
                cx.counters.add(Counter::FeatureLate, 1);
                continue;
            }
            match item {
                Pending::Frame(fr) => {
                    fused.camera_moved |= fuse_frame(est, t, &fr, &mut self.landmarks, &mut cx);
                }
                Pending::Gnss(sats) => fuse_gnss(est, t, &sats, &mut cx),
                Pending::Baro(h_m) => fuse_baro(est, t, h_m, &cx),
            }
        }
        fused
    }
}

/// What [`MeasurementQueue::fuse_covered`] fused, as the take-off logic
/// needs it.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Fused {
    /// A frame's features said the vehicle moved (`FrameReport::camera_moved`).
    pub camera_moved: bool,
}

/// One barometer reading into the filter (§3g), its update to the log.
fn fuse_baro(est: &mut Estimator, t: f64, h_m: f64, cx: &FuseCtx<'_>) {
    let counters = cx.counters;
    let outcome = match est.process_baro(t, h_m) {
        Ok(o) => o,
        Err(e) => {
            counters.add(
                if matches!(e, crate::estimator::InputError::BaroLate { .. }) {
                    Counter::BaroLate
                } else {
                    Counter::BaroTimeOff
                },
                1,
            );
            tracing::warn!(error = %e, "barometer reading not fused");
            return;
        }
    };
    let (name, residual, sigma) = match outcome {
        BaroOutcome::Anchored { offset_m, reanchored } => {
            if reanchored {
                counters.add(Counter::BaroReanchored, 1);
                tracing::warn!(
                    reason = "baro_reanchored",
                    offset_m,
                    "a barometer reading more than 10 m from our height: its offset set afresh"
                );
            }
            ("anchored", None, None)
        }
        BaroOutcome::Fused {
            residual_m, sigma_m, ..
        } => {
            counters.add(Counter::BaroUpdates, 1);
            ("fused", Some(residual_m), Some(sigma_m))
        }
        BaroOutcome::Refused {
            residual_m, sigma_m, ..
        } => {
            counters.add(Counter::BaroRefused, 1);
            ("refused", Some(residual_m), Some(sigma_m))
        }
        BaroOutcome::HeightReset {
            residual_m,
            sigma_m,
            added_var_m2,
        }
        | BaroOutcome::OffsetReset {
            residual_m,
            sigma_m,
            added_var_m2,
        } => {
            let (name, counter, what) = if matches!(outcome, BaroOutcome::HeightReset { .. }) {
                (
                    "height_reset",
                    Counter::BaroHeightReset,
                    "the height's (and its window's)",
                )
            } else {
                (
                    "offset_reset",
                    Counter::BaroOffsetReset,
                    "the barometer's offset's (it was suspect)",
                )
            };
            counters.add(Counter::BaroUpdates, 1);
            counters.add(counter, 1);
            tracing::warn!(
                reason = name,
                residual_m,
                sigma_m,
                added_sigma_m = added_var_m2.sqrt(),
                "the barometer disagreed with our height beyond its gate five times in a row: {what} variance \
                 was raised and the reading fused"
            );
            (name, Some(residual_m), Some(sigma_m))
        }
    };
    if let Some(l) = cx.log {
        let offset = est.baro_offset();
        l.log(
            Topic::FilterBaro,
            t,
            &json!({
                "t_s": t, "h_m": h_m, "outcome": name,
                "residual_m": residual.filter(|x| x.is_finite()),
                "sigma_m": sigma.filter(|x| x.is_finite()),
                "offset_m": offset.map(|o| o.0),
                "offset_sigma_m": offset.map(|o| o.1.max(0.0).sqrt()),
            }),
        );
    }
}

/// One GNSS epoch into the filter (once the world origin is known).
fn fuse_gnss(est: &mut Estimator, t: f64, sats: &[SatMeas], cx: &mut FuseCtx<'_>) {
    let Some(frame) = cx.frame else { return };
    let counters = cx.counters;
    match est.process_gnss(t, &frame, sats) {
        Ok(rep) => {
            if let Some(l) = cx.log {
                let (clock, clock_var) = est.clock();
                l.log(
                    Topic::FilterGnss,
                    t,
                    &json!({
                        "t_s": t, "pseudoranges_used": rep.pseudoranges_used, "range_rates_used": rep.range_rates_used,
                        "rejected": rep.rejected, "residuals": rep.residuals, "clock": clock.as_slice(),
                        "clock_var": clock_var.as_slice(),
                        "range_bias": est.range_biases().into_iter()
                            .map(|b| json!([format!("{}{:02}", b.system.letter(), b.prn), b.b_m, b.var_m2.sqrt()]))
                            .collect::<Vec<_>>(),
                        "troposphere_zenith": est.troposphere_zenith().map(|(t, var)| [t, var.sqrt()]),
                        "keyframe_sigma_m": est.keyframe_sigmas().into_iter().take(200).collect::<Vec<_>>(),
                    }),
                );
            }
            let codes_rejected = [Counter::GnssPseudorangeChi2, Counter::GnssPseudorangeOutlier]
                .iter()
                .filter_map(|k| rep.rejected.get(k))
                .sum::<u64>();
            let usable = rep.pseudoranges_used + rep.range_rates_used > 0;
            cx.tracker.gnss_epoch_usable(t, usable);
            if usable {
                counters.add(Counter::GnssEpochsFused, 1);
                cx.tracker.gnss_fused(t);
            } else {
                counters.add(Counter::GnssEpochUnusable, 1);
                tracing::warn!(
                    reason = "gnss_epoch_unusable",
                    refused = codes_rejected,
                    "GNSS epoch with no measurement the filter could use"
                );
            }
            cx.tracker.gnss_codes_rejected(t, codes_rejected);
            if rep.differential {
                cx.base
                    .on_fused(t, rep.pseudoranges_used, codes_rejected, counters, cx.tracker);
            }
            counters.add(Counter::GnssPseudorangesUsed, rep.pseudoranges_used as u64);
            counters.add(Counter::GnssRangeRatesUsed, rep.range_rates_used as u64);
            for (k, v) in &rep.rejected {
                counters.add(*k, *v);
            }
        }
        Err(e @ crate::estimator::InputError::GnssLate { .. }) => {
            counters.add(Counter::GnssLate, 1);
            tracing::warn!(reason = "gnss_late", error = %e, "GNSS epoch too late to fuse");
        }
        Err(e) => {
            counters.add(Counter::GnssRejected, 1);
            tracing::warn!(error = %e, "GNSS epoch rejected");
        }
    }
}

/// One camera frame into the filter; a global update it starts goes to the
/// rebase worker. Whether the camera saw the vehicle move
/// (`FrameReport::camera_moved`).
fn fuse_frame(
    est: &mut Estimator,
    t: f64,
    fr: &NormFrame,
    landmarks: &mut LandmarkCloud,
    cx: &mut FuseCtx<'_>,
) -> bool {
    let counters = cx.counters;
    let rej = fr.rejects;
    for (name, n) in [
        (Counter::FeatureNonFinite, rej.non_finite),
        (Counter::FeatureOutsideImage, rej.outside_image),
        (Counter::FeatureUndistortFailed, rej.undistort_failed),
        (Counter::FeatureDuplicateId, rej.duplicate_id),
    ] {
        if n > 0 {
            counters.add(name, n);
        }
    }
    let started = std::time::Instant::now();
    let result = est.process_frame(t, &fr.obs);
    let elapsed_us = started.elapsed().as_secs_f64() * 1e6;
    dispatch_rebase(cx.rebase, cx.est_gen, est, counters);
    match result {
        Ok(rep) => {
            if let Some(l) = cx.log {
                log_frame(l, est, t, fr.obs.len(), &rep, elapsed_us);
                landmarks.push(l, t, &rep.landmarks_W);
            }
            counters.add(Counter::FramesProcessed, 1);
            cx.tracker.frame_processed(t);
            counters.add(Counter::TracksUsed, rep.tracks_used as u64);
            if rep.zupt {
                counters.add(Counter::ZuptUpdates, 1);
            }
            let (nis, dof) = rep.nis.iter().fold((0.0, 0), |(n, d), (nis, dof)| (n + nis, d + dof));
            if dof > 0 && nis.is_finite() {
                counters.add(Counter::TrackNisMilli, (1000.0 * nis).round() as u64);
                counters.add(Counter::TrackNisDof, dof as u64);
            }
            counters.add(Counter::GlobalUpdates, rep.global_updates as u64);
            if rep.low_parallax_tracks > 0 {
                // Tracks used at their remembered depth (a hover).
                counters.add(Counter::LowParallaxTracks, rep.low_parallax_tracks as u64);
            }
            if rep.loop_closure_tracks > 0 {
                // Tracks that reached back to a keyframe: revisits.
                counters.add(Counter::LoopClosureTracks, rep.loop_closure_tracks as u64);
            }
            if rep.promoted > 0 {
                counters.add(Counter::KeyframesPromoted, rep.promoted as u64);
            }
            if rep.deferred > 0 {
                // Loop-closure observations left for a later track while
                // a rebase was computing the global part.
                counters.add(Counter::LoopClosureDeferred, rep.deferred as u64);
            }
            for (k, v) in &rep.rejected {
                counters.add(k.counter(), *v);
            }
            rep.camera_moved
        }
        Err(e) => {
            counters.add(Counter::FrameRejected, 1);
            tracing::warn!(error = %e, "frame rejected");
            false
        }
    }
}

/// `/filter/update/vision` and the frame's events: global updates,
/// keyframes created (`/filter/keyframes`) and promotions.
fn log_frame(l: &McapLogger, est: &Estimator, t: f64, features: usize, rep: &FrameReport, elapsed_us: f64) {
    // The frame's NIS per degree of freedom, `Σ NIS / Σ dof`, with the 95%
    // interval of `χ²(Σ dof) / Σ dof` it lies in when the filter is consistent.
    let dof: usize = rep.nis.iter().map(|x| x.1).sum();
    let (nis_per_dof, nis_per_dof_95) = if dof > 0 {
        let k = dof as f64;
        (
            Some(rep.nis.iter().map(|x| x.0).sum::<f64>() / k),
            Some([chi2_quantile(0.025, dof) / k, chi2_quantile(0.975, dof) / k]),
        )
    } else {
        (None, None)
    };
    l.log(
        Topic::FilterVision,
        t,
        &json!({
            "t_s": t, "features": features, "tracks_used": rep.tracks_used,
            "rejected": rep.rejected, "nis": rep.nis, "residual_rms": rep.residual_rms,
            "nis_per_dof": nis_per_dof, "nis_per_dof_95": nis_per_dof_95,
            "keyframe_created": rep.keyframe_created, "loop_closure_tracks": rep.loop_closure_tracks,
            "low_parallax_tracks": rep.low_parallax_tracks,
            "vibration_jitter_rad": est.stats.vibration_jitter_rad,
            "global_updates": rep.global_updates, "elapsed_us": elapsed_us,
            "local_dim": est.local_dim(), "global_keyframes": est.n_global_keyframes(),
            "keyframe_sigma_m": est.keyframe_sigmas().into_iter().take(200).collect::<Vec<_>>(),
        }),
    );
    for ev in &rep.events {
        match ev {
            FilterEvent::GlobalUpdate {
                reason,
                global_before,
                local_after,
            } => l.log(
                Topic::FilterGlobal,
                t,
                &json!({"t_s": t, "reason": format!("{reason:?}"), "global_before": global_before, "local_after": local_after}),
            ),
            FilterEvent::KeyframeCreated { id } => {
                if let Some(kf) = est.keyframes().find(|k| k.id == *id) {
                    let cov = est.keyframe_covariance(*id).map(|c| c.diagonal().as_slice().to_vec());
                    let q = kf.q_W_B();
                    l.log(
                        Topic::FilterKeyframes,
                        t,
                        &json!({"t_s": t, "id": id, "p_B_in_W": kf.p_B_in_W.as_slice(), "q_W_B_wxyz": [q.w, q.i, q.j, q.k], "cov_diag": cov}),
                    );
                }
                super::frames::log_keyframes(l, t, est);
            }
            FilterEvent::Promoted { keyframes } => l.log(
                Topic::FilterGlobal,
                t,
                &json!({"t_s": t, "reason": "Promotion", "promoted": keyframes}),
            ),
            FilterEvent::Update { .. } => {}
        }
    }
}
