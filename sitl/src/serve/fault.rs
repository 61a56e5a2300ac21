//! Fault injection: the faults the mock autopilot can be told to inject
//! (`NAME@START+DURATION`), which of them are in force at a flight time, and
//! how each one alters what goes out, so that the senders only ask.

use crate::gnss::GnssEpoch;

/// A fault the mock autopilot injects.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    /// Nothing goes over MAVLink.
    LinkDrop,
    /// No RTCM.
    GnssOutage,
    /// No camera frames.
    CameraOutage,
    /// No IMU samples.
    ImuGap,
    /// IMU samples with NaN or absurd (1e5 m/s²) accelerations, alternately.
    NanImu,
    /// A plausible but wrong 50 m/s² added to the x accelerometer (a
    /// saturating vibration): the filter is fooled, diverges and must reset.
    ImuSpike,
    /// The front end disconnects and reconnects at the end.
    FrontendRestart,
    /// RTCM frames corrupted (bad CRC).
    RtcmBadCrc,
    /// 100 m added to two satellites' pseudoranges.
    PrOutlier,
    /// The autopilot reboots at the start: silent for the duration, then
    /// its boot clock restarts from 1 s.
    ClockJump,
    /// IMU samples sent in swapped pairs and twice each; camera lines and
    /// RTCM messages sent twice.
    DupReorder,
    /// The base station falls silent (its radio or the ground station's
    /// relay stops).
    BaseSilent,
    /// The base station's messages arrive twice, injected by two ground
    /// stations (systems 255 and 254).
    BaseDoubled,
    /// The base station announces an antenna position 28 m from where it
    /// stands (a badly surveyed or mistyped position).
    BaseMoved,
    /// A ground station announces an antenna position (MT1005) under the
    /// rover's own station id.
    BaseClaimsRoverId,
    /// The base loses its lowest-numbered GPS satellite (it sets, or is
    /// blocked, at the base): its satellite set changes twice.
    BaseDropsSatellite,
    /// The autopilot's visual odometry is off: `VISO_TYPE` read as 0 (an
    /// ArduPilot that would ignore every estimate).
    VisoOff,
    /// The barometer reads 3 m high (the autopilot switched to another
    /// barometer, or the rotor wash near the ground).
    BaroStep,
}

impl FaultKind {
    pub fn name(self) -> &'static str {
        match self {
            FaultKind::LinkDrop => "link_drop",
            FaultKind::GnssOutage => "gnss_outage",
            FaultKind::CameraOutage => "camera_outage",
            FaultKind::ImuGap => "imu_gap",
            FaultKind::NanImu => "nan_imu",
            FaultKind::FrontendRestart => "frontend_restart",
            FaultKind::RtcmBadCrc => "rtcm_bad_crc",
            FaultKind::PrOutlier => "pr_outlier",
            FaultKind::ClockJump => "clock_jump",
            FaultKind::DupReorder => "dup_reorder",
            FaultKind::ImuSpike => "imu_spike",
            FaultKind::BaseSilent => "base_silent",
            FaultKind::BaseDoubled => "base_doubled",
            FaultKind::BaseMoved => "base_moved",
            FaultKind::BaseClaimsRoverId => "base_claims_rover_id",
            FaultKind::BaseDropsSatellite => "base_drops_satellite",
            FaultKind::VisoOff => "viso_off",
            FaultKind::BaroStep => "baro_step",
        }
    }

    pub const ALL: [FaultKind; 18] = [
        FaultKind::LinkDrop,
        FaultKind::GnssOutage,
        FaultKind::CameraOutage,
        FaultKind::ImuGap,
        FaultKind::NanImu,
        FaultKind::FrontendRestart,
        FaultKind::RtcmBadCrc,
        FaultKind::PrOutlier,
        FaultKind::ClockJump,
        FaultKind::DupReorder,
        FaultKind::ImuSpike,
        FaultKind::BaseSilent,
        FaultKind::BaseDoubled,
        FaultKind::BaseMoved,
        FaultKind::BaseClaimsRoverId,
        FaultKind::BaseDropsSatellite,
        FaultKind::VisoOff,
        FaultKind::BaroStep,
    ];
}

/// How far the `baro_step` barometer reads high (m).
pub(super) const BARO_STEP_M: f64 = 3.0;

/// `NAME@START+DURATION` (seconds of flight).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fault {
    pub kind: FaultKind,
    pub start_s: f64,
    pub duration_s: f64,
}

impl Fault {
    pub(super) fn active(&self, t: f64) -> bool {
        t >= self.start_s && t < self.start_s + self.duration_s
    }
}

impl std::str::FromStr for Fault {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let kinds = FaultKind::ALL;
        let (name, rest) = s
            .split_once('@')
            .ok_or_else(|| format!("fault '{s}': expected NAME@START+DURATION"))?;
        let kind = kinds
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| format!("unknown fault '{name}': use {}", kinds.map(|k| k.name()).join(", ")))?;
        let (a, b) = rest
            .split_once('+')
            .ok_or_else(|| format!("fault '{s}': expected NAME@START+DURATION"))?;
        let start_s: f64 = a
            .parse()
            .map_err(|_| format!("fault '{s}': start '{a}' is not a number"))?;
        let duration_s: f64 = b
            .parse()
            .map_err(|_| format!("fault '{s}': duration '{b}' is not a number"))?;
        if !(start_s.is_finite() && start_s >= 0.0 && duration_s.is_finite() && duration_s > 0.0) {
            return Err(format!("fault '{s}': start ≥ 0 and duration > 0 are needed"));
        }
        Ok(Fault {
            kind,
            start_s,
            duration_s,
        })
    }
}

/// Flight time of the autopilot's reboot (the first `clock_jump`), if any.
pub(super) fn reboot_time(faults: &[Fault]) -> Option<f64> {
    faults
        .iter()
        .find(|f| f.kind == FaultKind::ClockJump)
        .map(|f| f.start_s)
}

/// The faults in force at one flight time.
pub(super) struct Active<'a> {
    faults: &'a [Fault],
    t: f64,
}

impl<'a> Active<'a> {
    pub(super) fn at(faults: &'a [Fault], t: f64) -> Self {
        Self { faults, t }
    }

    /// A fault of kind `k` is in force.
    pub(super) fn has(&self, k: FaultKind) -> bool {
        self.faults.iter().any(|f| f.kind == k && f.active(self.t))
    }

    /// Nothing from the autopilot gets through: a rebooting autopilot is as
    /// silent as a dropped link.
    pub(super) fn link_down(&self) -> bool {
        self.has(FaultKind::LinkDrop) || self.has(FaultKind::ClockJump)
    }

    /// How many times each camera line, RTCM message and IMU sample goes out.
    pub(super) fn copies(&self) -> usize {
        if self.has(FaultKind::DupReorder) {
            2
        } else {
            1
        }
    }
}

/// `base_moved`: how far the announced antenna position is from the
/// base's true one (m, east in the world frame's NED).
pub const BASE_MOVED_M: f64 = 28.0;

/// `base_drops_satellite`: the epoch without its lowest-numbered GPS
/// satellite.
pub(super) fn drop_first_gps(ep: &mut GnssEpoch) {
    let first = ep
        .sats
        .iter()
        .enumerate()
        .filter(|(_, s)| s.system == cmsckf_models::gnss::System::Gps)
        .min_by_key(|(_, s)| s.prn)
        .map(|(i, _)| i);
    if let Some(i) = first {
        ep.sats.remove(i);
    }
}

/// `pr_outlier`: 100 m added to the first two satellites' pseudoranges.
pub(super) fn add_pr_outliers(ep: &mut GnssEpoch) {
    for s in ep.sats.iter_mut().take(2) {
        s.pseudorange_m += 100.0;
    }
}

/// `rtcm_bad_crc`: one byte of the message flipped, so its CRC fails.
pub(super) fn break_crc(bytes: &mut [u8]) {
    if bytes.len() > 10 {
        bytes[8] ^= 0xFF;
    }
}

/// Offsets from the current IMU sample, in sending order: with duplicates
/// (`copies` > 1) and a next sample (`has_next`), duplicated and out of
/// order: the next sample first, then this one twice.
pub(super) fn imu_order(copies: usize, has_next: bool) -> &'static [usize] {
    if copies > 1 && has_next {
        &[1, 0, 0]
    } else {
        &[0]
    }
}
