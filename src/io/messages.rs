//! What crosses the MAVLink boundary, as the rest of the daemon sees it:
//! plain values in SI units (who sent a message, each inbound message we
//! read, each outbound message we write). `io::mavlink` converts them to and
//! from MAVLink's own types; nothing here names the `mavlink` crate.

use nalgebra::Vector3;

/// Who sent a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct Source {
    pub system: u32,
    pub component: u8,
}

/// A simulator's truth (`SIM_STATE`, as ArduPilot's SITL and ours send
/// it): position (deg, deg, m above mean sea level), attitude (w, x, y, z)
/// and velocity (NED, m/s). Only logged, for review against the truth; never
/// fused.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimTruth {
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub alt_m: f64,
    pub q_wxyz: [f64; 4],
    pub v_ned_mps: Vector3<f64>,
}

/// A message from the autopilot, in SI units.
#[derive(Clone, Debug, PartialEq)]
pub enum Inbound {
    /// IMU sample: boot time (µs), specific force (m/s², FRD), rate (rad/s).
    Imu {
        t_us: u64,
        accel_mps2: Vector3<f64>,
        gyro_radps: Vector3<f64>,
        /// The message it came in.
        kind: ImuMessage,
        /// The magnetic field in the body frame, when the message carries
        /// one: its direction only (units differ: ArduPilot's
        /// `HIGHRES_IMU` sends µG where MAVLink says G; `RAW_IMU` mG).
        mag_B: Option<Vector3<f64>>,
    },
    /// Attitude (rad) at boot time (ms).
    Attitude {
        t_boot_ms: u32,
        roll_rad: f64,
        pitch_rad: f64,
        yaw_rad: f64,
    },
    /// The autopilot's local position and velocity (NED, m and m/s).
    LocalPosition {
        t_boot_ms: u32,
        p_ned_m: Vector3<f64>,
        v_ned_mps: Vector3<f64>,
    },
    /// `SCALED_PRESSURE`: the autopilot's barometer (Pa, °C) at boot time
    /// (ms). Only logged: the review sets its height changes beside ours;
    /// the filter does not fuse it.
    Pressure {
        t_boot_ms: u32,
        p_abs_pa: f64,
        temperature_c: f64,
    },
    /// The autopilot's GNSS accuracy (`GPS_RAW_INT`'s `h_acc`, `v_acc`; m,
    /// one sigma), when it reports one: the uncertainty of its local
    /// position, which an in-flight start takes as its own.
    GpsAccuracy {
        h_acc_m: f64,
        v_acc_m: f64,
    },
    SystemTime {
        unix_us: u64,
        boot_ms: u32,
    },
    Timesync {
        tc1_ns: i64,
        ts1_ns: i64,
    },
    /// One `GPS_RTCM_DATA` fragment.
    RtcmFragment {
        flags: u8,
        data: Vec<u8>,
    },
    /// A `HEARTBEAT`: whether its sender is armed, and which autopilot.
    Heartbeat {
        armed: bool,
        kind: AutopilotKind,
        /// Its flight mode (`custom_mode`, the autopilot's own numbering).
        mode: u32,
    },
    /// A `STATUSTEXT` from the autopilot: only logged (the review's
    /// timeline shows what the autopilot said).
    AutopilotText {
        severity: u8,
        text: String,
    },
    /// `EXTENDED_SYS_STATE`'s landed state: on the ground, in the air
    /// (taking off, flying, landing), or not known (`None`).
    LandedState {
        on_ground: Option<bool>,
    },
    /// The autopilot's EKF origin (deg, deg, m above the ellipsoid... as
    /// MAVLink gives it: AMSL).
    GpsGlobalOrigin {
        lat_deg: f64,
        lon_deg: f64,
        alt_m: f64,
    },
    /// A simulator's truth (`SIM_STATE`): only logged, never fused.
    SimState(SimTruth),
    /// How the autopilot's own EKF takes our estimates: ArduPilot's
    /// `EKF_STATUS_REPORT` or PX4's `ESTIMATOR_STATUS`. Only logged.
    EstimatorStatus(EstimatorStatus),
    /// `PARAM_VALUE`: one of the autopilot's parameters as the wire carries
    /// it. An integer's `raw` is its value cast to `f32` (ArduPilot) or its
    /// bytes copied into one (PX4): [`ParamValue::decoded`] knows which.
    ParamValue(ParamValue),
    /// `VISION_POSITION_ESTIMATE` (when the peer is another estimator, or
    /// for the SITL scorer's own tests).
    Other(&'static str),
}

/// The autopilot EKF's innovation test ratios, as it reports them: over 1
/// means the EKF rejected that measurement. ArduPilot's
/// `EKF_STATUS_REPORT` names them variances, but fills them with the square
/// roots of EK3's test ratios; PX4's `ESTIMATOR_STATUS` names them ratios.
/// With external navigation as the position source, the position ratios
/// are those of our estimates.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EstimatorStatus {
    /// `ekf_status_report` (ArduPilot) or `estimator_status` (PX4).
    pub source: EstimatorSource,
    /// `None` when not finite: a field we do not use must not cost the
    /// position ratios.
    pub vel_ratio: Option<f64>,
    pub pos_horiz_ratio: f64,
    pub pos_vert_ratio: f64,
    pub mag_ratio: Option<f64>,
    /// The message's flags, as sent (`EKF_STATUS_FLAGS` or
    /// `ESTIMATOR_STATUS_FLAGS`).
    pub flags: u16,
}

/// Which message an [`EstimatorStatus`] came in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EstimatorSource {
    EkfStatusReport,
    EstimatorStatus,
}

/// A message to the autopilot.
#[derive(Clone, Debug, PartialEq)]
pub enum Outbound {
    /// `MAV_STATE_STANDBY` until initialised, then `ACTIVE`, or `CRITICAL`
    /// while degraded (an input stale or being rejected, or just restarted).
    Heartbeat {
        initialised: bool,
        degraded: bool,
    },
    /// A `STATUSTEXT` (RFC-5424 severity: 2 critical, 4 warning, 6 info).
    /// A text over MAVLink's 50 bytes goes out as MAVLink 2 chunks (at most
    /// four; longer texts are cut with "…"): see `io::mavlink`.
    StatusText {
        severity: u8,
        text: String,
    },
    SetMessageInterval {
        message_id: u32,
        interval_us: f32,
    },
    /// `PARAM_REQUEST_READ`: send the parameter `name` (at most 16 bytes).
    ParamRequestRead {
        name: &'static str,
    },
    /// `MAV_CMD_REQUEST_MESSAGE`: send `message_id` once.
    RequestMessage {
        message_id: u32,
    },
    TimesyncRequest {
        ts1_ns: i64,
    },
    /// TIMESYNC reply to the autopilot's request `ts1_ns`, with our time
    /// `tc1_ns`: the autopilot's boot clock as we estimate it, the clock our
    /// outputs are stamped in (ns).
    TimesyncReply {
        tc1_ns: i64,
        ts1_ns: i64,
    },
    VisionPositionEstimate {
        t_us: u64,
        p_ned_m: Vector3<f64>,
        rpy_rad: Vector3<f64>,
        /// Upper triangle of the 6×6 covariance of `[x y z roll pitch yaw]`.
        covariance: [f32; 21],
        reset_counter: u8,
    },
    /// `VISION_SPEED_ESTIMATE`, sent with each `VisionPositionEstimate`:
    /// velocity (NED, m/s) and its 3×3 covariance, row-major.
    VisionSpeedEstimate {
        t_us: u64,
        v_ned_mps: Vector3<f64>,
        covariance: [f32; 9],
        reset_counter: u8,
    },
    /// `ODOMETRY` of a VIO estimator: position (NED, m) and attitude
    /// (`q_wxyz`, body FRD to NED), velocity (m/s) and rate (rad/s) in the
    /// body FRD frame.
    Odometry {
        t_us: u64,
        p_ned_m: Vector3<f64>,
        q_wxyz: [f32; 4],
        v_body_mps: Vector3<f64>,
        w_body_radps: Vector3<f64>,
        /// Upper triangle of the 6×6 covariance of `[x y z roll pitch yaw]`.
        pose_covariance: [f32; 21],
        /// Upper triangle of the 6×6 covariance of `[vx vy vz p q r]`
        /// (body velocity and rate).
        velocity_covariance: [f32; 21],
        reset_counter: u8,
        /// −1 failed, 1 worst … 100 best (MAVLink's `ODOMETRY.quality`).
        quality: i8,
        /// `frame_id` `MAV_FRAME_LOCAL_NED` (PX4: our world frame is
        /// north-referenced, so its yaw is a heading) instead of
        /// `MAV_FRAME_LOCAL_FRD` (the only one ArduPilot accepts).
        frame_ned: bool,
    },
    SetGpsGlobalOrigin {
        lat_deg: f64,
        lon_deg: f64,
        alt_m: f64,
    },
}

impl Outbound {
    /// An estimate of the pose: `ODOMETRY` or `VISION_POSITION_ESTIMATE`,
    /// one per output instant whichever `output.message` chooses (a
    /// `VISION_SPEED_ESTIMATE` goes with the latter and is not counted).
    pub fn is_estimate(&self) -> bool {
        matches!(
            self,
            Outbound::Odometry { .. } | Outbound::VisionPositionEstimate { .. }
        )
    }
}

/// Where RTCM reached the daemon, and so what its observations may be.
/// `GPS_RTCM_DATA` normally carries a base station's corrections to the
/// autopilot; a receiver wired to the companion is the rover itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RtcmStream {
    /// The receiver on the companion (`gnss.source = "stream"`): the
    /// rover's own, whatever its station id.
    Receiver,
    /// `GPS_RTCM_DATA` from the vehicle's system id: the rover's only when
    /// its station id is `gnss.rover_station_id` (and it announces no
    /// antenna position, as a base does); else a base station's.
    LinkVehicle,
    /// `GPS_RTCM_DATA` from another system (a ground station injecting a
    /// base's corrections): never the rover's.
    LinkOther,
}

impl RtcmStream {
    /// The name logged for replay.
    pub fn name(self) -> &'static str {
        match self {
            RtcmStream::Receiver => "receiver",
            RtcmStream::LinkVehicle => "link_vehicle",
            RtcmStream::LinkOther => "link_other",
        }
    }
}

/// Which autopilot a `HEARTBEAT` says it is (`MAV_AUTOPILOT_*`): the
/// output's frame and covariance follow what each one reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AutopilotKind {
    ArduPilot,
    Px4,
    Other,
}

/// The MAVLink message an IMU sample came in. Each autopilot fills them
/// differently, so the daemon takes one and ignores the others
/// (`mavlink.imu_message`): PX4's `HIGHRES_IMU` has EKF2's bias estimates
/// taken out, and EKF2 learns those from our own estimates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ImuMessage {
    /// `HIGHRES_IMU` (105): floats, stamped in µs.
    Highres,
    /// `SCALED_IMU` (26): mG and mrad/s, stamped in ms.
    Scaled,
    /// `RAW_IMU` (27): ArduPilot's, in mG and mrad/s, stamped in µs.
    Raw,
}

impl ImuMessage {
    /// Its MAVLink message id, for the stream request.
    pub const fn message_id(self) -> u32 {
        match self {
            ImuMessage::Highres => MSG_ID_HIGHRES_IMU,
            ImuMessage::Scaled => MSG_ID_SCALED_IMU,
            ImuMessage::Raw => MSG_ID_RAW_IMU,
        }
    }

    /// The one the daemon takes beside `kind`, when the config leaves it
    /// to the autopilot (`imu_message = "auto"`). PX4's `HIGHRES_IMU` is
    /// `vehicle_imu` less EKF2's accelerometer and gyro bias estimates
    /// (`HIGHRES_IMU.hpp`), and EKF2 learns those from our estimates: a
    /// loop through which our own error comes back as our input, measured
    /// at 0.2-0.4 m/s² on PX4's SITL, whose IMU has no bias.
    /// `SCALED_IMU` is `vehicle_imu` itself. ArduPilot's `HIGHRES_IMU` is
    /// its IMU as calibrated.
    pub const fn auto_for(kind: Option<AutopilotKind>) -> Self {
        match kind {
            Some(AutopilotKind::Px4) => ImuMessage::Scaled,
            _ => ImuMessage::Highres,
        }
    }

    /// The counter of the samples that came in it (taken or not).
    pub const fn counter(self) -> crate::counters::Counter {
        use crate::counters::Counter;
        match self {
            ImuMessage::Highres => Counter::ImuHighres,
            ImuMessage::Scaled => Counter::ImuScaled,
            ImuMessage::Raw => Counter::ImuRaw,
        }
    }

    /// As stored in an atomic (the receive task sets it, the stream
    /// requests read it).
    pub const fn to_u8(self) -> u8 {
        self as u8
    }

    pub const fn from_u8(v: u8) -> Self {
        match v {
            1 => ImuMessage::Scaled,
            2 => ImuMessage::Raw,
            _ => ImuMessage::Highres,
        }
    }
}

/// Message ids the daemon asks streams for.
pub const MSG_ID_HIGHRES_IMU: u32 = 105;
pub const MSG_ID_SCALED_IMU: u32 = 26;
pub const MSG_ID_RAW_IMU: u32 = 27;
pub const MSG_ID_ATTITUDE: u32 = 30;
pub const MSG_ID_SYSTEM_TIME: u32 = 2;
pub const MSG_ID_LOCAL_POSITION_NED: u32 = 32;
/// `EXTENDED_SYS_STATE` (the landed state).
pub const MSG_ID_EXTENDED_SYS_STATE: u32 = 245;
/// `EKF_STATUS_REPORT` (ArduPilot's EKF test ratios).
pub const MSG_ID_EKF_STATUS_REPORT: u32 = 193;
/// `ESTIMATOR_STATUS` (PX4's EKF test ratios).
pub const MSG_ID_ESTIMATOR_STATUS: u32 = 230;
/// `TIMESYNC` (PX4 streams its requests).
pub const MSG_ID_TIMESYNC: u32 = 111;
/// `SCALED_PRESSURE` (the autopilot's barometer).
pub const MSG_ID_SCALED_PRESSURE: u32 = 29;

/// One parameter as `PARAM_VALUE` carries it (`MAV_PARAM_TYPE` in
/// `param_type`: 1–8 integers, 9 `f32`, 10 `f64`).
#[derive(Clone, Debug, PartialEq)]
pub struct ParamValue {
    /// Its name, without the trailing NULs (at most 16 bytes).
    pub name: String,
    pub raw: f32,
    pub param_type: u8,
}

impl ParamValue {
    /// Its value, as the autopilot meant it: a `REAL32` as it is; an
    /// integer of up to 32 bits cast (ArduPilot, MAVLink's "C cast"
    /// encoding) or bit-copied into the `f32` (PX4, "bytewise"); `None` for
    /// a 64-bit type (it does not fit) or a value that is not finite.
    pub fn decoded(&self, kind: AutopilotKind) -> Option<f64> {
        let bytewise = kind == AutopilotKind::Px4;
        let bits = self.raw.to_bits();
        let v = match self.param_type {
            9 => f64::from(self.raw),
            1..=6 if !bytewise => f64::from(self.raw).round(),
            1 => f64::from(bits as u8),
            2 => f64::from(bits as u8 as i8),
            3 => f64::from(bits as u16),
            4 => f64::from(bits as u16 as i16),
            5 => f64::from(bits),
            6 => f64::from(bits as i32),
            _ => return None,
        };
        v.is_finite().then_some(v)
    }
}
