//! Every event the daemon counts, as a type: [`Counter`] names one reason
//! (an input received, a rejection and why, an update, a restart), and
//! [`Counters`] holds one atomic count per reason, shared by the daemon's
//! tasks, the fusion thread and the status judge.
//!
//! The estimator reports its rejections as [`Counter`]s too, so a reason is
//! spelt once: its name in the log's `/diagnostics`, the review and the
//! tests is [`Counter::as_str`], and whether it is outside input rejected
//! (which degrades the `HEARTBEAT`) is [`Counter::is_input_rejection`],
//! decided by the type, never by the spelling of a name.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

/// Declares [`Counter`]: each variant with its name in the log and whether
/// it counts outside input that was rejected (`reject`) or not (`event`).
macro_rules! counters {
    ($($(#[$doc:meta])* $variant:ident = $name:literal, $kind:ident;)*) => {
        /// One counted reason. Its name ([`Counter::as_str`]) is what the
        /// log's `/diagnostics`, `demo --json` and the review show.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
        pub enum Counter {
            $($(#[$doc])* $variant,)*
        }

        impl Counter {
            /// Every counter, in declaration order (`ALL[c as usize] == c`).
            pub const ALL: &'static [Counter] = &[$(Counter::$variant,)*];

            /// The counter's name in the log and the reports.
            pub const fn as_str(self) -> &'static str {
                match self {
                    $(Counter::$variant => $name,)*
                }
            }

            /// Outside input refused (malformed, non-finite, out of time
            /// order, from the wrong sender): holds `input_rejected` in the
            /// `HEARTBEAT` for 2 s.
            pub const fn is_input_rejection(self) -> bool {
                match self {
                    $(Counter::$variant => counters!(@kind $kind),)*
                }
            }
        }
    };
    (@kind reject) => { true };
    (@kind event) => { false };
}

counters! {
    // The MAVLink link.
    MavlinkMessages = "mavlink_messages", event;
    MavlinkUndecodable = "mavlink_undecodable", event;
    MavlinkIoError = "mavlink_io_error", event;
    MavlinkReconnected = "mavlink_reconnected", event;
    MavlinkFramesLostOrCorrupt = "mavlink_frames_lost_or_corrupt", event;
    MavlinkAutopilotAddressLearned = "mavlink_autopilot_address_learned", event;
    MavlinkAutopilotAddressStale = "mavlink_autopilot_address_stale", event;
    /// A message before the autopilot's first HEARTBEAT told us who it is.
    MavlinkBeforeAutopilotHeartbeat = "mavlink_before_autopilot_heartbeat", event;
    /// A HEARTBEAT from a system other than the autopilot.
    MavlinkHeartbeatOther = "mavlink_heartbeat_other", event;
    MavlinkSendError = "mavlink_send_error", event;
    MavlinkSendNoAutopilot = "mavlink_send_no_autopilot", event;
    MavlinkRejectedNonFinite = "mavlink_rejected_non_finite", reject;
    MavlinkRejectedImuOutOfRange = "mavlink_rejected_imu_out_of_range", reject;
    /// A `SCALED_PRESSURE` no barometer reads (outside 100–1200 hPa; 0, the
    /// message of an airspeed sensor without a barometer reading, is not
    /// counted).
    MavlinkRejectedPressureOutOfRange = "mavlink_rejected_pressure_out_of_range", reject;
    MavlinkRejectedUnsigned = "mavlink_rejected_unsigned", reject;
    MavlinkRejectedBadSignature = "mavlink_rejected_bad_signature", reject;
    MavlinkRejectedGarbageDatagram = "mavlink_rejected_garbage_datagram", reject;
    MavlinkRejectedAutopilotIdFromOtherAddress = "mavlink_rejected_autopilot_id_from_other_address", reject;
    MavlinkRejectedOther = "mavlink_rejected_other", reject;
    MavlinkRejectedForeignImu = "mavlink_rejected_foreign_imu", reject;
    MavlinkRejectedForeignAttitude = "mavlink_rejected_foreign_attitude", reject;
    MavlinkRejectedForeignLocalPosition = "mavlink_rejected_foreign_local_position", reject;
    MavlinkRejectedForeignPressure = "mavlink_rejected_foreign_pressure", reject;
    MavlinkRejectedForeignGps = "mavlink_rejected_foreign_gps", reject;
    MavlinkRejectedForeignSystemTime = "mavlink_rejected_foreign_system_time", reject;
    MavlinkRejectedForeignTimesync = "mavlink_rejected_foreign_timesync", reject;
    MavlinkRejectedForeignOrigin = "mavlink_rejected_foreign_origin", reject;
    MavlinkRejectedForeignLandedState = "mavlink_rejected_foreign_landed_state", reject;
    MavlinkRejectedForeignSimState = "mavlink_rejected_foreign_sim_state", reject;
    MavlinkRejectedForeignEstimatorStatus = "mavlink_rejected_foreign_estimator_status", reject;
    /// A `PARAM_VALUE` from another system or component (a ground
    /// station's parameter editor): not the autopilot's.
    MavlinkRejectedForeignParam = "mavlink_rejected_foreign_param", reject;
    /// A STATUSTEXT from another system (a ground station): not the autopilot's.
    MavlinkStatusTextOther = "mavlink_statustext_other", event;
    LinkDown = "link_down", event;
    LinkUp = "link_up", event;
    AutopilotSendsNoImu = "autopilot_sends_no_imu", event;
    // What the autopilot sent, by message.
    ImuHighres = "imu_highres", event;
    ImuScaled = "imu_scaled", event;
    ImuRaw = "imu_raw", event;
    /// IMU samples in a message other than the one taken
    /// (`mavlink.imu_message`): counted, never fused.
    ImuMessageIgnored = "imu_message_ignored", event;
    /// The same IMU sample (time and values) sent again: PX4 repeats its
    /// last `SCALED_IMU` when only the magnetometer moved. Dropped.
    ImuDuplicate = "imu_duplicate", event;
    /// `mavlink.imu_message = "auto"` beside an autopilot other than PX4
    /// turned to another IMU message: from `HIGHRES_IMU` after 2 s without
    /// one, or back to it.
    ImuMessageSwitched = "imu_message_switched", event;
    Attitude = "attitude", event;
    LocalPosition = "local_position", event;
    /// `SCALED_PRESSURE` readings taken (logged; fused with `barometer.fuse`).
    Pressure = "pressure", event;
    GpsAccuracy = "gps_accuracy", event;
    SimState = "sim_state", event;
    EstimatorStatus = "autopilot_estimator_status", event;
    /// The autopilot's EKF reported a position test ratio over 1: it
    /// rejected our estimate.
    AutopilotRejectedOurPosition = "autopilot_rejected_our_position", event;
    HeartbeatIn = "heartbeat_in", event;
    StatusTextIn = "statustext_in", event;
    ExtendedSysState = "extended_sys_state", event;
    SystemTime = "system_time", event;
    SystemTimeUnset = "system_time_unset", event;
    SystemTimeOutlier = "system_time_outlier", reject;
    GpsGlobalOrigin = "gps_global_origin", event;
    Timesync = "timesync", event;
    TimesyncReply = "timesync_reply", event;
    /// The autopilot's own TIMESYNC requests, answered or not: the rate of
    /// its stream (PX4's is sped up to 50 Hz).
    TimesyncRequestIn = "timesync_request_in", event;
    TimesyncRequestUnanswered = "timesync_request_unanswered", event;
    StreamRequestedAgain = "stream_requested_again", event;
    // The IMU on the fusion thread.
    ImuSamples = "imu_samples", event;
    ImuTimeBackwards = "imu_time_backwards", reject;
    /// An IMU sample stamped with the time of the one before it but other
    /// values: two samples cannot share a time, so the later is refused
    /// (the first stands). Not a time going back.
    ImuConflictingDuplicate = "imu_conflicting_duplicate", reject;
    ImuTimeOutlier = "imu_time_outlier", reject;
    ImuRejected = "imu_rejected", reject;
    /// A non-finite sample reached the estimator.
    ImuNonFinite = "imu_non_finite", event;
    /// The estimator's IMU buffer was full.
    ImuOverflow = "imu_overflow", event;
    ImuGap = "imu_gap", event;
    ImuGapRestart = "imu_gap_restart", event;
    AutopilotClockReset = "autopilot_clock_reset", event;
    // Camera frames: the socket, the fusion queue, the filter.
    FeatureConnections = "feature_connections", event;
    FeatureDisconnects = "feature_disconnects", event;
    FeatureAcceptError = "feature_accept_error", event;
    FeatureIdleDropped = "feature_idle_dropped", event;
    FeatureSocketGone = "feature_socket_gone", event;
    FeatureSocketReplaced = "feature_socket_replaced", event;
    FeatureFrames = "feature_frames", event;
    FeatureQueueFull = "feature_queue_full", event;
    FeatureLate = "feature_late", event;
    FeatureLineTooLong = "feature_line_too_long", reject;
    FeatureLineSyntax = "feature_line_syntax", reject;
    FeatureLineVersion = "feature_line_version", reject;
    FeatureLineTooMany = "feature_line_too_many", reject;
    FeatureNonFinite = "feature_non_finite", reject;
    FeatureBadSigma = "feature_bad_sigma", reject;
    FeatureOutsideImage = "feature_outside_image", event;
    FeatureUndistortFailed = "feature_undistort_failed", event;
    FeatureDuplicateId = "feature_duplicate_id", event;
    FeatureNoTimesync = "feature_no_timesync", event;
    FeatureBeforeImu = "feature_before_imu", event;
    FeatureTimeImplausible = "feature_time_implausible", reject;
    FeatureTimeBackwards = "feature_time_backwards", reject;
    FrameRejected = "frame_rejected", reject;
    /// A frame not after the filter's time (the estimator's own check).
    FrameTimeBackwards = "frame_time_backwards", event;
    FramesProcessed = "frames_processed", event;
    FusionQueueFull = "fusion_queue_full", event;
    FusionFramesFull = "fusion_frames_full", event;
    PendingOverflow = "pending_overflow", event;
    // Vision updates.
    TracksUsed = "tracks_used", event;
    LoopClosureTracks = "loop_closure_tracks", event;
    LowParallaxTracks = "low_parallax_tracks", event;
    LoopClosureDeferred = "loop_closure_deferred", event;
    KeyframesPromoted = "keyframes_promoted", event;
    GlobalUpdates = "global_updates", event;
    TrackRejectedTooFewObservations = "track_rejected_too_few_observations", event;
    TrackRejectedNonFinite = "track_rejected_non_finite", event;
    TrackRejectedPoorParallax = "track_rejected_poor_parallax", event;
    TrackRejectedBadDepth = "track_rejected_bad_depth", event;
    TrackRejectedNotConverged = "track_rejected_not_converged", event;
    TrackRejectedChi2 = "track_rejected_chi2", event;
    /// A frame taken as a zero-velocity update (standing still).
    ZuptUpdates = "zupt_updates", event;
    /// A zero-velocity update failed its χ² gate.
    ZuptChi2 = "zupt_chi2", event;
    /// Barometer readings fused as a height (§3g), refused by their χ²
    /// gate, and refused as older than the filter by more than 0.2 s.
    BaroUpdates = "baro_updates", event;
    BaroRefused = "baro_refused", event;
    BaroLate = "baro_late", event;
    /// The gate refused five readings in a row: the variance of the body's
    /// and its window's heights was raised and the reading fused
    /// (estimator README §3g, B3).
    BaroHeightReset = "baro_height_reset", event;
    /// Five refused in a row while the offset was suspect (set, carried or
    /// the height reset to it within 10 s): the offset took the excess.
    BaroOffsetReset = "baro_offset_reset", event;
    /// A reading more than 10 m from our height: the offset set afresh
    /// from it.
    BaroReanchored = "baro_reanchored", event;
    /// A reading stamped at or before the last one (a duplicate, or out
    /// of order): not fused.
    BaroOutOfOrder = "baro_out_of_order", event;
    /// A reading stamped over 1 s ahead of the IMU or 5 s behind it, or
    /// whose pressure gives no height: not fused.
    BaroTimeOff = "baro_time_off", event;
    /// The accepted tracks' NIS, summed (in thousandths), and their degrees
    /// of freedom: their ratio is the NIS per degree of freedom, 1 for a
    /// consistent filter (`demo --json`'s `nis_per_dof`).
    TrackNisMilli = "track_nis_milli", event;
    TrackNisDof = "track_nis_dof", event;
    /// An update whose innovation covariance was not positive definite.
    UpdateNotPd = "update_not_pd", event;
    // Compressed mode's global updates on the worker thread.
    RebasesStarted = "rebases_started", event;
    RebasesInstalled = "rebases_installed", event;
    RebaseStale = "rebase_stale", event;
    RebaseThreadLost = "rebase_thread_lost", event;
    // RTCM and GNSS.
    RtcmMessages = "rtcm_messages", event;
    RtcmBytes = "rtcm_bytes", event;
    RtcmOtherSource = "rtcm_other_source", event;
    RtcmSourcesFull = "rtcm_sources_full", event;
    RtcmCrcFailure = "rtcm_crc_failure", reject;
    RtcmFragmentTooLong = "rtcm_fragment_too_long", reject;
    RtcmFragmentMissing = "rtcm_fragment_missing", reject;
    UbxChecksumFailure = "ubx_checksum_failure", event;
    GnssStreamConnected = "gnss_stream_connected", event;
    GnssStreamOpenError = "gnss_stream_open_error", event;
    GnssStreamBytes = "gnss_stream_bytes", event;
    GnssEpochs = "gnss_epochs", event;
    GnssEpochsFused = "gnss_epochs_fused", event;
    GnssPseudorangesUsed = "gnss_pseudoranges_used", event;
    GnssRangeRatesUsed = "gnss_range_rates_used", event;
    GnssBelowMask = "gnss_below_mask", event;
    GnssPseudorangeOutlier = "gnss_pseudorange_outlier", event;
    GnssPseudorangeChi2 = "gnss_pseudorange_chi2", event;
    GnssRangeRateChi2 = "gnss_range_rate_chi2", event;
    /// A single-point code whose satellite found the range-bias block full
    /// (40 satellites used within the last 10 s): weighted by DG6's window
    /// instead of a state.
    GnssRangeBiasFull = "gnss_range_bias_full", event;
    /// A satellite's range-bias state started again after the gate refused
    /// its codes five epochs in a row: its broadcast error stepped (a new
    /// ephemeris, another code).
    GnssRangeBiasRestart = "gnss_range_bias_restart", event;
    GnssLate = "gnss_late", event;
    GnssRejected = "gnss_rejected", event;
    GnssTimeInvalid = "gnss_time_invalid", event;
    GnssNoSystemTime = "gnss_no_system_time", event;
    GnssDgnssEpochs = "gnss_dgnss_epochs", event;
    GnssDgnssUnavailable = "gnss_dgnss_unavailable", event;
    /// A base epoch that copies one already held (a base relayed by two
    /// ground stations): dropped.
    GnssBaseDuplicateEpoch = "gnss_base_duplicate_epoch", event;
    /// A base epoch older than the newest held of its station: dropped.
    GnssBaseOutOfOrderEpoch = "gnss_base_out_of_order_epoch", event;
    /// A base correction that came out non-finite: dropped.
    GnssBaseNonFiniteCorrection = "gnss_base_non_finite_correction", reject;
    /// A rover epoch without differential codes while the base's announced
    /// position is not yet checked against its own fixes.
    GnssBasePositionUnchecked = "gnss_base_position_unchecked", event;
    /// A rover epoch without differential codes because the base's
    /// announced position is too far from its own fixes.
    GnssBasePositionWrong = "gnss_base_position_wrong", event;
    /// The base set aside for `gnss.base_holdoff_s` because most of its
    /// corrected codes failed the filter's gate.
    GnssBaseSetAside = "gnss_base_set_aside", event;
    /// A rover epoch fused as single point while the base is set aside.
    GnssBaseSetAsideEpochs = "gnss_base_set_aside_epochs", event;
    /// A rover satellite's code left out of a differential epoch because the
    /// base has no correction for it (its range rate is still fused).
    GnssDgnssSatNotAtBase = "gnss_dgnss_sat_not_at_base", event;
    /// A constellation the base does not serve, fused as single point in a
    /// differential epoch.
    GnssDgnssSystemNotAtBase = "gnss_dgnss_system_not_at_base", event;
    /// Another system's station claiming the rover's station id (an antenna
    /// position, MT1005/1006, from a ground station): ignored.
    GnssStationIdConflict = "gnss_station_id_conflict", reject;
    /// An epoch that gave the filter no usable measurement (no ephemeris,
    /// a wrong week, every code refused).
    GnssEpochUnusable = "gnss_epoch_unusable", event;
    /// The GPS week taken from the autopilot's clock (SYSTEM_TIME) or a
    /// Galileo ephemeris, overruling the hint.
    GnssWeekResolved = "gnss_week_resolved", event;
    /// An ephemeris from a ground station left out: the rover's own stream
    /// gives that satellite's.
    GnssEphemerisFromOtherIgnored = "gnss_ephemeris_from_other_ignored", event;
    GnssRoverMsmFromReceiver = "gnss_rover_msm_from_receiver", event;
    GnssRoverMsmFromLink = "gnss_rover_msm_from_link", event;
    GnssBaseMsmFromLink = "gnss_base_msm_from_link", event;
    GnssBaseMsmFromGroundStation = "gnss_base_msm_from_ground_station", event;
    GnssRoverIdIsABase = "gnss_rover_id_is_a_base", event;
    GnssBaseStationPosition = "gnss_base_station_position", event;
    GnssOriginFromFix = "gnss_origin_from_fix", event;
    GnssOriginFromAutopilot = "gnss_origin_from_autopilot", event;
    PriorFromFix = "prior_from_fix", event;
    // Our origin, sent to the autopilot.
    GpsOriginSent = "gps_origin_sent", event;
    GpsOriginConfirmed = "gps_origin_confirmed", event;
    GpsOriginMismatch = "gps_origin_mismatch", event;
    GpsOriginUnconfirmed = "gps_origin_unconfirmed", event;
    /// `output.set_gps_origin` towards PX4: not sent, and said why (PX4
    /// keeps its altitude across a new origin, so its local heights would
    /// move by the origin's altitude).
    GpsOriginWithheld = "gps_origin_withheld", event;
    /// Our filter runs, the autopilot reports no EKF origin: said (with
    /// what to do) each time this is counted.
    AutopilotOriginMissing = "autopilot_origin_missing", event;
    /// One of the autopilot's navigation parameters came (`PARAM_VALUE`).
    AutopilotParamValue = "autopilot_param_value", event;
    /// A parameter that makes the autopilot's EKF ignore, or mis-weigh, our
    /// estimates: said with its fix (`daemon/nav_params.rs`).
    AutopilotParamMisconfigured = "autopilot_param_misconfigured", event;
    /// A navigation parameter the autopilot never answered for, after
    /// every request: the check went on without it.
    AutopilotParamUnanswered = "autopilot_param_unanswered", event;
    /// A start on the ground again when the origin came late, so that the
    /// compass yaw has its declination.
    RestartLocated = "restart_located", event;
    /// The filter's yaw conditioned on a better compass mean while the
    /// vehicle stood (estimator README eq. H1).
    CompassYawConditioned = "compass_yaw_conditioned", event;
    /// Compass readings not averaged: their heading far from the mean.
    CompassOutlier = "compass_outlier", event;
    // Starts, restarts and outputs.
    InitStatic = "init_static", event;
    InitInFlight = "init_in_flight", event;
    InitFromCarriedEstimate = "init_from_carried_estimate", event;
    /// A start that cannot happen, said (STATUSTEXT and the log) with why.
    InitWaiting = "init_waiting", event;
    FilterReset = "filter_reset", event;
    EstimatesSent = "estimates_sent", event;
    OutputQueueFull = "output_queue_full", event;
    // The flight log and systemd.
    LogMessages = "log_messages", event;
    LogChunks = "log_chunks", event;
    /// Records written out of log-time order (later than the writer's
    /// one-second reordering).
    LogLateRecords = "log_late_records", event;
    LogError = "log_error", event;
    LogDropped = "log_dropped", event;
    /// Writes that failed (disk full, an I/O error).
    LogWriteFailed = "log_write_failed", event;
    /// Records dropped while the log could not be written.
    LogRecordsDroppedWriteError = "log_records_dropped_write_error", event;
    WatchdogPings = "watchdog_pings", event;
    WatchdogWithheld = "watchdog_withheld", event;
}

impl Counter {
    /// The counter named `name`, if there is one.
    pub fn from_name(name: &str) -> Option<Counter> {
        Counter::ALL.iter().copied().find(|c| c.as_str() == name)
    }
}

impl std::fmt::Display for Counter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl serde::Serialize for Counter {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

/// A counter read back by its name (`evaluate --merge` reads the flights'
/// statistics back); a name no counter has is an error that says so.
impl<'de> serde::Deserialize<'de> for Counter {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = <std::borrow::Cow<'de, str>>::deserialize(d)?;
        Counter::ALL
            .iter()
            .copied()
            .find(|c| c.as_str() == name)
            .ok_or_else(|| serde::de::Error::custom(format!("no counter is named {name:?}")))
    }
}

/// One atomic count per [`Counter`], shared by the daemon's tasks (cheap to
/// clone: the counts are behind one `Arc`). Adding never allocates or locks.
#[derive(Clone, Debug)]
pub struct Counters(Arc<[Slot]>);

/// A count, and whether it was ever added to (even 0): a counter that was
/// touched is reported, one that never was is not.
#[derive(Debug, Default)]
struct Slot {
    n: AtomicU64,
    touched: AtomicBool,
}

impl Default for Counters {
    fn default() -> Self {
        Self(Counter::ALL.iter().map(|_| Slot::default()).collect())
    }
}

impl Counters {
    pub fn add(&self, c: Counter, n: u64) {
        let slot = &self.0[c as usize];
        slot.n.fetch_add(n, Ordering::Relaxed);
        slot.touched.store(true, Ordering::Relaxed);
    }

    pub fn get(&self, c: Counter) -> u64 {
        self.0[c as usize].n.load(Ordering::Relaxed)
    }

    /// The counter named `name` (0 for a name that is no counter): for
    /// tests and tools that read names from a report.
    pub fn get_by_name(&self, name: &str) -> u64 {
        Counter::from_name(name).map_or(0, |c| self.get(c))
    }

    /// Outside input rejected so far, every reason together.
    pub fn input_rejections(&self) -> u64 {
        Counter::ALL
            .iter()
            .filter(|c| c.is_input_rejection())
            .map(|c| self.get(*c))
            .sum()
    }

    /// The counters added to so far, by name (as `/diagnostics` logs them).
    pub fn snapshot(&self) -> BTreeMap<String, u64> {
        Counter::ALL
            .iter()
            .filter(|c| self.0[**c as usize].touched.load(Ordering::Relaxed))
            .map(|c| (c.as_str().to_string(), self.get(*c)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_round_trip() {
        let mut names: Vec<_> = Counter::ALL.iter().map(|c| c.as_str()).collect();
        names.sort_unstable();
        let n = names.len();
        names.dedup();
        assert_eq!(names.len(), n, "two counters share a name");
        for (i, c) in Counter::ALL.iter().enumerate() {
            assert_eq!(*c as usize, i);
            assert_eq!(Counter::from_name(c.as_str()), Some(*c));
        }
        assert_eq!(Counter::from_name("no_such_counter"), None);
    }

    #[test]
    fn rejections_are_told_by_the_type() {
        let c = Counters::default();
        c.add(Counter::ImuSamples, 100);
        c.add(Counter::RtcmCrcFailure, 2);
        c.add(Counter::MavlinkRejectedForeignImu, 1);
        c.add(Counter::GnssRangeRatesUsed, 0);
        assert_eq!(c.input_rejections(), 3);
        assert_eq!(c.get_by_name("imu_samples"), 100);
        let snap = c.snapshot();
        assert_eq!(snap.len(), 4, "only the counters added to: {snap:?}");
        assert_eq!(snap["gnss_range_rates_used"], 0);
        assert_eq!(snap["rtcm_crc_failure"], 2);
    }
}
