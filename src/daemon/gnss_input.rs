//! GNSS input: a receiver's raw RTCM3 stream read beside the link
//! (`gnss.source = "stream"`), and, for the fusion thread, RTCM decoding, the
//! receiver model, the world origin and the GPS-time → autopilot-time map
//! that turn each completed epoch into satellite measurements at an
//! autopilot time.

use cmsckf_models::geodesy::{ecef_to_llh, NedFrame, R_ecef_ned, C_MPS};
use cmsckf_models::gnss::{gps_to_unix_s, Klobuchar, SatMeas};
use serde_json::json;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::base_use::BaseUse;
use super::{DaemonError, FusionMsg, RtcmStream};
use crate::config::{Config, GnssSource};
use crate::counters::{Counter, Counters};
use crate::estimator::Estimator;
use crate::gnss::dgnss::{self, CodeModel};
use crate::gnss::rtcm::{GnssMessage, RtcmDecoder, System};
use crate::gnss::spp::{SppOptions, SppSolution};
use crate::gnss::{Epoch, IonoMode, IonoPolicy, RawSat, Receiver, StreamDecoder};
use crate::io::mcap_log::{McapLogger, Topic};
use crate::status::Tracker;

/// The stream reader's task and its forwarder's.
pub(super) type StreamTasks = (JoinHandle<()>, JoinHandle<()>);

/// A receiver wired to the companion computer: its raw RTCM3 is read and
/// forwarded to the fusion loop. `None` unless `gnss.source = "stream"`.
pub(super) fn spawn_stream(
    cfg: &Config,
    fusion_tx: &mpsc::Sender<FusionMsg>,
    counters: &Counters,
    stop_rx: &watch::Receiver<bool>,
) -> Result<Option<StreamTasks>, DaemonError> {
    if cfg.gnss.source != GnssSource::Stream {
        return Ok(None);
    }
    let spec =
        crate::io::gnss_stream::parse(&cfg.gnss.stream).map_err(|e| DaemonError::Config(format!("gnss.stream {e}")))?;
    let (tx, mut rx) = mpsc::channel::<Vec<u8>>(64);
    let fwd_tx = fusion_tx.clone();
    let counters2 = counters.clone();
    let mut stop = stop_rx.clone();
    let fwd = tokio::spawn(async move {
        loop {
            tokio::select! {
                b = rx.recv() => match b {
                    Some(bytes) => if fwd_tx.try_send(FusionMsg::Rtcm { bytes, stream: RtcmStream::Receiver }).is_err() {
                        counters2.add(Counter::FusionQueueFull, 1)
                    },
                    None => return,
                },
                _ = stop.changed() => return,
            }
        }
    });
    let reader = tokio::spawn(crate::io::gnss_stream::run(spec, tx, counters.clone(), stop_rx.clone()));
    Ok(Some((reader, fwd)))
}

/// GNSS input of the fusion loop: RTCM decoding, the receiver model, the
/// world origin and the GPS-time → autopilot-time map.
pub(super) struct GnssIn {
    /// RTCM3 from the MAVLink link (`GPS_RTCM_DATA`).
    dec: RtcmDecoder,
    /// The receiver's own stream (`gnss.source = "stream"`): RTCM3 or UBX,
    /// recognised from the bytes. Each stream has its own decoder, so a
    /// frame is never spliced from two.
    stream_dec: StreamDecoder,
    rx: Receiver,
    /// The world frame: configured, the autopilot's origin, or placed at
    /// the first fix.
    frame: Option<NedFrame>,
    /// Unix time minus autopilot boot time (s), from SYSTEM_TIME.
    unix_minus_boot_s: Option<f64>,
    msgs: Vec<GnssMessage>,
    epochs: Vec<Epoch>,
    klobuchar: Option<Klobuchar>,
    /// `gnss.iono`: how the measurements handle the ionosphere.
    iono: IonoMode,
    /// Set when the world origin was just placed at a single-point fix:
    /// that fix's position sigma (m), `PDOP · σ_pseudorange`.
    origin_fix_sigma_m: Option<f64>,
    pseudorange_sigma_m: f64,
    /// `gnss.rover_station_id`: the station id of the rover's own RTCM on
    /// the link (0: none there).
    rover_station_id: u16,
    /// Base stations seen (MT1005/1006): id and antenna position (ECEF, m).
    bases: Vec<(u16, [f64; 3])>,
    /// `gnss.dgnss`: fuse differential codes when a base is on the link.
    dgnss: bool,
    /// `gnss.source = "mavlink"`: the rover's observations may come on the
    /// link; with a receiver of its own, every observation there is a base's.
    rover_on_link: bool,
    /// Whether the base's corrections are used, and how much believed.
    base_use: BaseUse,
    /// `gnss.week_hint` as configured (0: none).
    configured_week: u32,
    /// Where the week now comes from, once better than the hint.
    week_source: Option<WeekSource>,
    /// The station-id conflict was logged (it is counted every time).
    said_id_conflict: bool,
}

/// What settled the GPS week.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum WeekSource {
    Autopilot,
    Galileo,
}

/// Where a decoded message goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Destination {
    Rover,
    Base,
    /// An ephemeris from another system: it only fills in satellites the
    /// rover's own stream has not given.
    OtherEphemeris,
    /// Nowhere: counted and dropped.
    Ignored,
}

/// Farthest ahead of the filter (s) a GNSS epoch may map and still wait
/// for IMU to cover it.
const MAX_EPOCH_LEAD_S: f64 = 10.0;

/// Unix time (s) before which an autopilot's SYSTEM_TIME is not a real
/// date (2015-01-01): a board that booted without GNSS or NTP.
const UNIX_PLAUSIBLE_S: f64 = 1_420_070_400.0;

/// Base stations remembered (more are still kept apart by stream and id).
const MAX_BASES: usize = 8;

impl GnssIn {
    pub(super) fn new(cfg: &Config) -> Self {
        let mut gnss = Self::with_receiver(cfg);
        gnss.rx.base_limits = dgnss::BaseLimits {
            max_age_s: cfg.gnss.dgnss_max_age_s,
            max_position_error_m: cfg.gnss.base_max_position_error_m,
        };
        gnss
    }

    fn with_receiver(cfg: &Config) -> Self {
        GnssIn {
            dec: RtcmDecoder::new(),
            stream_dec: StreamDecoder::default(),
            rx: Receiver::new(
                SppOptions {
                    elevation_mask_deg: cfg.gnss.elevation_mask_deg,
                    iono: cfg.gnss.iono,
                    // Validated with the config: the fallback is never taken.
                    systems: crate::gnss::parse_systems(&cfg.gnss.systems).unwrap_or(vec![System::Gps]),
                },
                if cfg.gnss.week_hint != 0 {
                    cfg.gnss.week_hint
                } else {
                    crate::gnss::gps_week_now()
                },
                // Which station is the rover's is decided per stream here
                // (`is_rovers`), not by the receiver model.
                0,
            ),
            frame: (cfg.gnss.origin_llh.len() == 3).then(|| {
                let o = &cfg.gnss.origin_llh;
                NedFrame::from_llh_deg(o[0], o[1], o[2])
            }),
            unix_minus_boot_s: None,
            origin_fix_sigma_m: None,
            pseudorange_sigma_m: cfg.gnss.pseudorange_sigma_m,
            rover_station_id: cfg.gnss.rover_station_id,
            bases: Vec::new(),
            dgnss: cfg.gnss.dgnss,
            rover_on_link: cfg.gnss.source == GnssSource::Mavlink,
            base_use: BaseUse::new(cfg.gnss.base_holdoff_s),
            configured_week: cfg.gnss.week_hint,
            week_source: None,
            said_id_conflict: false,
            msgs: Vec::new(),
            epochs: Vec::new(),
            iono: cfg.gnss.iono,
            klobuchar: (cfg.gnss.klobuchar_alpha.len() == 4 && cfg.gnss.klobuchar_beta.len() == 4).then(|| {
                let a = &cfg.gnss.klobuchar_alpha;
                let b = &cfg.gnss.klobuchar_beta;
                Klobuchar {
                    alpha: [a[0], a[1], a[2], a[3]],
                    beta: [b[0], b[1], b[2], b[3]],
                }
            }),
        }
    }
}

impl GnssIn {
    /// The world frame, once its origin is known.
    pub(super) fn frame(&self) -> Option<NedFrame> {
        self.frame
    }

    /// The world frame from the autopilot's origin.
    pub(super) fn set_frame(&mut self, frame: NedFrame) {
        self.frame = Some(frame);
    }

    /// The autopilot's Unix − boot offset (s), or `None` (unknown again
    /// after a reboot): how GNSS time maps onto the autopilot's clock.
    pub(super) fn set_unix_minus_boot(&mut self, offset_s: Option<f64>) {
        self.unix_minus_boot_s = offset_s;
    }

    /// The autopilot's Unix time (s, from SYSTEM_TIME, its GNSS time): the
    /// GPS week, which a companion without a network cannot know, and which
    /// neither a wrong `gnss.week_hint` nor an ephemeris (a ground station's
    /// may be anything) overrules. Before it, a Galileo ephemeris's week
    /// overrules the hint.
    pub(super) fn set_autopilot_unix_time(&mut self, unix_s: f64, counters: &Counters) {
        if !(unix_s.is_finite() && unix_s > UNIX_PLAUSIBLE_S) {
            return;
        }
        let week = ((unix_s - 315_964_800.0) / 604_800.0) as u32;
        self.rx.week_from_clock = true;
        if week == self.rx.week_hint {
            self.week_source = Some(WeekSource::Autopilot);
            return;
        }
        if self.configured_week != 0 && self.week_source.is_none() {
            tracing::warn!(
                reason = "gnss_week_resolved",
                configured = self.configured_week,
                autopilot = week,
                "gnss.week_hint disagrees with the autopilot's clock (SYSTEM_TIME): the autopilot's week is used; \
                 set gnss.week_hint = 0 or correct it"
            );
        } else {
            tracing::info!(week, "GPS week from the autopilot's clock (SYSTEM_TIME)");
        }
        counters.add(Counter::GnssWeekResolved, 1);
        self.rx.set_week_hint(week);
        self.week_source = Some(WeekSource::Autopilot);
    }

    /// The base's use, for the fused epochs' verdicts.
    pub(super) fn base_use_mut(&mut self) -> &mut BaseUse {
        &mut self.base_use
    }

    /// The sigma (m) of the single-point fix the world origin was just
    /// placed at, once: the filter takes it as a prior (§7).
    pub(super) fn take_origin_fix_sigma(&mut self) -> Option<f64> {
        self.origin_fix_sigma_m.take()
    }

    /// Where a decoded message goes. Ephemerides go to the rover's
    /// receiver model from any stream (broadcast orbits are the same
    /// whoever relays them: a base's serve a rover that sends none).
    /// Observations do only when they are the rover's (see
    /// [`RtcmStream`]); a base station's are counted and kept apart, and a
    /// station that sends its antenna position (MT1005/1006) is a base,
    /// whatever its id. The rover's own id is the rover's: another system
    /// (a ground station) announcing a position under it is counted and
    /// ignored, never taken as a reason to stop using the rover's codes.
    fn destination(&mut self, m: &GnssMessage, stream: RtcmStream, counters: &Counters) -> Destination {
        match m {
            GnssMessage::Station { station_id, arp_ecef_m } => {
                if self.rover_on_link
                    && self.rover_station_id != 0
                    && *station_id == self.rover_station_id
                    && stream == RtcmStream::LinkOther
                {
                    counters.add(Counter::GnssStationIdConflict, 1);
                    if std::mem::replace(&mut self.said_id_conflict, true) {
                        return Destination::Ignored;
                    }
                    tracing::warn!(
                        station_id,
                        reason = "gnss_station_id_conflict",
                        "a ground station announces an antenna position under the rover's station id \
                         (gnss.rover_station_id): ignored; give the base another id"
                    );
                    return Destination::Ignored;
                }
                counters.add(Counter::GnssBaseStationPosition, 1);
                if self.bases.len() < MAX_BASES && !self.bases.iter().any(|(id, _)| id == station_id) {
                    self.bases.push((*station_id, *arp_ecef_m));
                    let (lat, lon, h) = ecef_to_llh(&nalgebra::Vector3::from(*arp_ecef_m));
                    tracing::info!(
                        station_id,
                        lat_deg = lat.to_degrees(),
                        lon_deg = lon.to_degrees(),
                        h_m = h,
                        stream = stream.name(),
                        "a base station announces itself (MT1005/1006): its observations are kept apart"
                    );
                    if *station_id == self.rover_station_id {
                        counters.add(Counter::GnssRoverIdIsABase, 1);
                        tracing::warn!(
                            station_id,
                            reason = "gnss_rover_id_is_a_base",
                            "gnss.rover_station_id names a base station (it sends its antenna position): its \
                             observations are not taken as the rover's"
                        );
                    }
                }
                Destination::Base
            }
            GnssMessage::Msm(e) => {
                let is_base = self.bases.iter().any(|(id, _)| *id == e.station_id);
                let rovers = match stream {
                    RtcmStream::Receiver => true,
                    RtcmStream::LinkVehicle => {
                        self.rover_on_link
                            && self.rover_station_id != 0
                            && e.station_id == self.rover_station_id
                            && !is_base
                    }
                    RtcmStream::LinkOther => false,
                };
                counters.add(
                    match (rovers, stream) {
                        (true, RtcmStream::Receiver) => Counter::GnssRoverMsmFromReceiver,
                        (true, _) => Counter::GnssRoverMsmFromLink,
                        (false, RtcmStream::LinkOther) => Counter::GnssBaseMsmFromGroundStation,
                        (false, _) => Counter::GnssBaseMsmFromLink,
                    },
                    1,
                );
                if rovers {
                    Destination::Rover
                } else {
                    Destination::Base
                }
            }
            // A ground station's ephemerides only fill in (red-team F6: a
            // shifted one reset the filter 13 times).
            GnssMessage::Eph(_) if stream == RtcmStream::LinkOther => Destination::OtherEphemeris,
            GnssMessage::Eph(_) | GnssMessage::GlonassEph(_) | GnssMessage::Other(_) => Destination::Rover,
        }
    }

    /// Decodes a stream's bytes (RTCM3 or UBX) and completes epochs; each becomes the satellites'
    /// measurements at its autopilot time (GPS tag → Unix (leap seconds) →
    /// boot clock (SYSTEM_TIME), less the receiver clock offset), returned
    /// for the fusion loop to queue. `est` places the world origin at the
    /// first fix when none is configured; fixes go to `log`; an epoch with
    /// nothing usable is counted and told to `tracker`.
    pub(super) fn on_rtcm(
        &mut self,
        bytes: &[u8],
        stream: RtcmStream,
        est: Option<&Estimator>,
        log: Option<&McapLogger>,
        counters: &Counters,
        tracker: &mut Tracker,
    ) -> Vec<(f64, Vec<SatMeas>)> {
        let mut out = Vec::new();
        self.decode(bytes, stream, counters);
        let base_before = self.base_stats();
        let galileo_weeks = self.rx.stats.week_from_galileo;
        let others_ignored = self.rx.stats.ephemerides_from_others_ignored;
        let mut msgs = std::mem::take(&mut self.msgs);
        for m in msgs.drain(..) {
            match self.destination(&m, stream, counters) {
                Destination::Rover => self.rx.push(m, &mut self.epochs),
                // A base station's: its position and epochs make the
                // corrections of the differential solution.
                Destination::Base => self.rx.push_base(m),
                Destination::OtherEphemeris => self.rx.push_other_ephemeris(m),
                Destination::Ignored => {}
            }
        }
        self.msgs = msgs;
        self.count_base(base_before, counters);
        let ignored = self.rx.stats.ephemerides_from_others_ignored - others_ignored;
        if ignored > 0 {
            counters.add(Counter::GnssEphemerisFromOtherIgnored, ignored);
        }
        if self.rx.stats.week_from_galileo > galileo_weeks {
            counters.add(Counter::GnssWeekResolved, 1);
            self.week_source = Some(WeekSource::Galileo);
            tracing::warn!(
                reason = "gnss_week_resolved",
                week = self.rx.week_hint,
                "a Galileo ephemeris's week overrules the week in use (gnss.week_hint, the autopilot's or the \
                 companion's clock)"
            );
        }
        let epochs: Vec<_> = self.epochs.drain(..).collect();
        for ep in epochs {
            counters.add(Counter::GnssEpochs, 1);
            let Some(offset) = self.unix_minus_boot_s else {
                counters.add(Counter::GnssNoSystemTime, 1);
                continue;
            };
            let clock_m = ep.fix.as_ref().map_or(0.0, |f| f.clock_bias_m);
            let t = gps_to_unix_s(ep.week, ep.tow_s) - offset - clock_m / C_MPS;
            // An epoch far ahead of the filter (a wrong week, a bad tag)
            // would wait for IMU that never comes, holding a queue slot.
            if est.is_some_and(|e| t.is_nan() || t > e.time_s() + MAX_EPOCH_LEAD_S) {
                counters.add(Counter::GnssTimeInvalid, 1);
                tracing::warn!(
                    reason = "gnss_time_invalid",
                    week = ep.week,
                    tow_s = ep.tow_s,
                    "GNSS epoch far ahead of the autopilot's clock: refused"
                );
                continue;
            }
            if let (Ok(fix), Some(l)) = (&ep.fix, log) {
                log_fix(l, t, fix);
            }
            if self.frame.is_none() {
                self.origin_from_fix(&ep, est, counters);
            }
            let sats = self.measurements(&ep, t, counters, tracker);
            if sats.is_empty() {
                counters.add(Counter::GnssEpochUnusable, 1);
                tracker.gnss_epoch_usable(t, false);
                tracing::warn!(
                    reason = "gnss_epoch_unusable",
                    satellites = ep.sats.len(),
                    week = ep.week,
                    "GNSS epoch with no usable measurement (no ephemeris for its time: a wrong week?)"
                );
            } else {
                out.push((t, sats));
            }
        }
        out
    }

    /// The base's counts before a batch of messages.
    fn base_stats(&self) -> (u64, u64) {
        self.rx
            .base
            .as_ref()
            .map_or((0, 0), |b| (b.stats.duplicate_epochs, b.stats.out_of_order_epochs))
    }

    /// Counts the base epochs the batch dropped, by reason.
    fn count_base(&self, (dup0, late0): (u64, u64), counters: &Counters) {
        let (dup, late) = self.base_stats();
        if dup > dup0 {
            counters.add(Counter::GnssBaseDuplicateEpoch, dup - dup0);
        }
        if late > late0 {
            counters.add(Counter::GnssBaseOutOfOrderEpoch, late - late0);
        }
    }

    /// The filter's measurements of an epoch at autopilot time `t`:
    /// differential codes (§8c) when `gnss.dgnss` is on and a usable base
    /// has corrections for it, else the raw codes with the ionosphere
    /// handled per `gnss.iono`. In a differential epoch, a constellation
    /// the base does not serve is fused as single point, and a satellite
    /// the base lacks keeps its range rate; range rates are always the
    /// rover's own.
    fn measurements(&mut self, ep: &Epoch, t: f64, counters: &Counters, tracker: &mut Tracker) -> Vec<SatMeas> {
        let rx_ecef_m = ep.fix.as_ref().ok().map(|f| f.r_ecef_m);
        let corrections = self.corrections_for(ep, t, counters, tracker);
        let single = |obs: Vec<RawSat>| {
            let policy = IonoPolicy {
                mode: self.iono,
                klobuchar: self.klobuchar.as_ref(),
                rx_ecef_m,
            };
            crate::gnss::sat_measurements(&self.rx.ephs, ep.week, ep.tow_s, policy, obs)
        };
        let obs: Vec<RawSat> = ep.sats.iter().map(RawSat::from_obs).collect();
        let Some((corr, shared_by)) = corrections else {
            return single(obs);
        };
        counters.add(Counter::GnssDgnssEpochs, 1);
        let served = |sys: System| corr.values.iter().any(|(k, _)| k.0 == sys);
        let (diff_obs, spp_obs): (Vec<RawSat>, Vec<RawSat>) = obs.into_iter().partition(|s| served(s.system));
        let mut systems_alone: Vec<char> = spp_obs.iter().map(|s| s.system.letter()).collect();
        systems_alone.dedup();
        if !systems_alone.is_empty() {
            counters.add(Counter::GnssDgnssSystemNotAtBase, systems_alone.len() as u64);
        }
        let mut missing = 0;
        let corrected = diff_obs.into_iter().map(|s| {
            let c = corr
                .values
                .iter()
                .find(|(k, _)| *k == (s.system, s.prn))
                .map(|(_, c)| *c);
            if c.is_none() && s.l1_pseudorange_m.is_some() {
                missing += 1;
            }
            RawSat {
                l1_pseudorange_m: s.l1_pseudorange_m.zip(c).map(|(p, c)| p - c),
                l2_pseudorange: None,
                ..s
            }
        });
        let policy = IonoPolicy {
            mode: IonoMode::Off,
            klobuchar: None,
            rx_ecef_m,
        };
        let mut sats = crate::gnss::sat_measurements(&self.rx.ephs, ep.week, ep.tow_s, policy, corrected);
        if missing > 0 {
            counters.add(Counter::GnssDgnssSatNotAtBase, missing);
        }
        for s in sats.iter_mut().filter(|s| s.pseudorange_m.is_some()) {
            let step = corr.reference_steps_m.iter().find(|(sys, _)| *sys == s.system);
            s.correction = Some(cmsckf_models::gnss::CodeCorrection {
                base_station_id: corr.station_id,
                base_tow_s: corr.base_tow_s,
                age_s: corr.age_s,
                shared_by,
                reference_step_m: step.map_or(0.0, |(_, d)| *d),
            });
        }
        sats.extend(single(spp_obs));
        sats
    }

    /// The base's corrections for epoch `ep` at autopilot time `t`, and how
    /// many rover epochs share them, when `gnss.dgnss` is on and the base
    /// is usable; refusals are counted by [`BaseUse`].
    fn corrections_for(
        &mut self,
        ep: &Epoch,
        t: f64,
        counters: &Counters,
        tracker: &mut Tracker,
    ) -> Option<(dgnss::BaseCorrections, f64)> {
        let base = self.rx.base.as_ref().filter(|_| self.dgnss)?;
        if !self.base_use.usable(t, counters) {
            return None;
        }
        let mask = self.rx.opts.elevation_mask_deg.to_radians();
        let c = dgnss::corrections(
            ep.week,
            ep.tow_s,
            base,
            &self.rx.ephs,
            mask,
            self.rx.base_limits,
            CodeModel::Single,
        );
        let shared_by = self.base_use.take(ep.tow_s, t, &c, counters, tracker)?;
        c.ok().map(|c| (c, shared_by))
    }

    /// Decodes one stream's bytes into `self.msgs`, counting the frames whose
    /// checksum failed.
    fn decode(&mut self, bytes: &[u8], stream: RtcmStream, counters: &Counters) {
        let (link_before, stream_before, ubx_before) = (
            self.dec.stats.crc_failures,
            self.stream_dec.rtcm.stats.crc_failures,
            self.stream_dec.ubx.stats.checksum_failures,
        );
        match stream {
            RtcmStream::Receiver => self.stream_dec.push(bytes, &mut self.msgs),
            RtcmStream::LinkVehicle | RtcmStream::LinkOther => self.dec.push(bytes, &mut self.msgs),
        }
        // A UBX receiver's bytes fail RTCM's CRC by the hundred: the stream's
        // are counted only while it is RTCM3 (or nothing yet).
        let mut rtcm_failures = self.dec.stats.crc_failures - link_before;
        if self.stream_dec.rtcm_in_use() {
            rtcm_failures += self.stream_dec.rtcm.stats.crc_failures - stream_before;
        }
        if rtcm_failures > 0 {
            counters.add(Counter::RtcmCrcFailure, rtcm_failures);
            tracing::warn!(reason = "rtcm_crc_failure", "RTCM frame with a bad CRC skipped");
        }
        let ubx_failures = self.stream_dec.ubx.stats.checksum_failures - ubx_before;
        if ubx_failures > 0 {
            counters.add(Counter::UbxChecksumFailure, ubx_failures);
            tracing::warn!(reason = "ubx_checksum_failure", "UBX frame with a bad checksum skipped");
        }
    }

    /// No configured or autopilot origin: anchor the world frame so that the
    /// current estimate sits at the first fix, whose error (its sigma,
    /// `PDOP · σ_pseudorange`) every position then shares.
    fn origin_from_fix(&mut self, ep: &Epoch, est: Option<&Estimator>, counters: &Counters) {
        if let (Ok(fix), Some(est)) = (&ep.fix, est) {
            let (lat, lon, _) = ecef_to_llh(&fix.r_ecef_m);
            let r = R_ecef_ned(lat, lon);
            let origin = fix.r_ecef_m - r * est.imu_state().p_B_in_W;
            self.frame = Some(NedFrame::from_ecef(&origin));
            self.origin_fix_sigma_m = Some(fix.pdop.max(1.0) * self.pseudorange_sigma_m);
            counters.add(Counter::GnssOriginFromFix, 1);
        }
    }
}

/// The single-point fix, to `/gnss/fix` (foxglove.LocationFix).
fn log_fix(l: &McapLogger, t: f64, fix: &SppSolution) {
    let (lat, lon, h) = ecef_to_llh(&fix.r_ecef_m);
    let ts = super::records::Stamp::at(t);
    // Variance approximated from the residuals and the PDOP.
    let var = (fix.residual_rms_m.max(1.0) * fix.pdop).powi(2) / 3.0;
    l.log(
        Topic::GnssFix,
        t,
        &json!({"timestamp": ts,
            "frame_id": "gnss", "latitude": lat.to_degrees(), "longitude": lon.to_degrees(), "altitude": h,
            "position_covariance": [var, 0.0, 0.0, 0.0, var, 0.0, 0.0, 0.0, var], "position_covariance_type": 1,
            "satellites": fix.sats.len(), "raim": format!("{:?}", fix.raim)}),
    );
}
