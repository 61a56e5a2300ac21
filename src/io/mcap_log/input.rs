//! The log's input records: one type, [`InputRecord`], for everything the
//! fusion loop consumes, written by the daemon and read back by `replay`
//! and `review`. Writer and readers share these types, so a misspelt field
//! does not compile, and a record that does not parse is an error with its
//! topic, never a silent `None`.
//!
//! Each variant is one `/input/*` channel (its [`Topic`]); the JSON of each
//! is the channel's schema (`schemas.rs`). The hot records (IMU, frames,
//! RTCM) borrow their data when written, so logging them allocates
//! nothing per field; read back, they own it.
//!
//! [`LOG_FORMAT`] is written in the log's `cmsckf` metadata. Format 1 (logs
//! without the field) has the same records, read with the defaults noted
//! below; a log of a newer format is refused by name.

use std::borrow::Cow;
use std::collections::BTreeMap;

use cmsckf_models::feature_wire::PixelFeature;
use serde::{Deserialize, Deserializer, Serialize};

use super::Topic;
use crate::io::messages::{AutopilotKind, RtcmStream};

/// The format of the log's records that this build writes and reads.
/// Format 4: a feature in `/input/features` may carry a fourth number, its
/// σ (px), which a reader of format 3 would take for a malformed record.
/// Format 3 writes records in log-time order, with MCAP `sequence` one
/// counter for every channel in the order they came (replay restores it);
/// formats 1 and 2 wrote records in the order they came, each channel
/// counting its own.
pub const LOG_FORMAT: u32 = 4;

/// The first format written in log-time order ([`LOG_FORMAT`]).
pub const FORMAT_TIME_ORDERED: u32 = 3;

/// Errors reading an input record back.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("{topic} is not an input channel")]
    NotAnInput { topic: &'static str },
    #[error("a {topic} record does not parse: {source}")]
    Malformed {
        topic: &'static str,
        source: serde_json::Error,
    },
    #[error(
        "the log's records are of format {found}; this cmsckf reads formats 1 to {LOG_FORMAT}: \
         read it with a newer cmsckf"
    )]
    NewerFormat { found: u32 },
    #[error(
        "the log's format is named '{value}', not a format number 1 to {LOG_FORMAT}: \
         not a cmsckf log, or a damaged one"
    )]
    BadFormat { value: String },
}

/// One input as the fusion loop consumed it: the payload of one `/input/*`
/// channel.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(untagged)]
pub enum InputRecord<'a> {
    Imu(ImuRecord),
    Features(FeaturesRecord<'a>),
    Rtcm(RtcmRecord<'a>),
    SystemTime(SystemTimeRecord),
    Autopilot(AutopilotRecord),
    RebaseInstalled(RebaseRecord),
}

/// `/input/imu`: one sample, stamped by the autopilot's boot clock.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImuRecord {
    pub t_us: u64,
    pub accel_mps2: [f64; 3],
    pub gyro_radps: [f64; 3],
}

/// `/input/features`: a camera frame as received, with its stamp mapped to
/// the autopilot's clock (`t_ap_us`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FeaturesRecord<'a> {
    /// The stamp the front-end gave (its clock, `features.clock`).
    pub t_us: u64,
    /// The same instant on the autopilot's clock (what replay uses).
    pub t_ap_us: i64,
    pub cam: u32,
    /// `[landmark_id, u_px, v_px]` each, distorted pixels, with a fourth
    /// number, the front-end's σ (px), where it sent one.
    pub features: Cow<'a, [PixelFeature]>,
}

/// `/input/rtcm`: RTCM3 message bytes and the stream they came by.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RtcmRecord<'a> {
    pub bytes: Cow<'a, [u8]>,
    /// Format 1 logs from before the stream was recorded: the vehicle's link.
    #[serde(default = "link_vehicle")]
    pub stream: RtcmStream,
}

fn link_vehicle() -> RtcmStream {
    RtcmStream::LinkVehicle
}

/// `/input/mavlink/system_time`: the autopilot's Unix time and boot time.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SystemTimeRecord {
    pub unix_us: u64,
    pub boot_ms: u64,
}

/// `/input/rebase_installed`: where the fusion loop installed a global
/// update computed on its worker thread (replay installs it there too).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RebaseRecord {
    pub seq: u64,
    /// The worker's wall time for the job (ms); absent in replay's logs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compute_ms: Option<f64>,
    /// The global keyframes after the install; absent in replay's logs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub global_keyframes: Option<usize>,
}

/// `/input/mavlink/autopilot`: what the autopilot said of itself, one
/// thing a record (`{"attitude_rad": [..]}`, `{"armed": true}`, …).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AutopilotRecord {
    /// `ATTITUDE`: roll, pitch, yaw (rad).
    #[serde(rename = "attitude_rad")]
    Attitude([f64; 3]),
    /// `LOCAL_POSITION_NED`.
    LocalPosition(LocalPositionRecord),
    /// `SCALED_PRESSURE`: the autopilot's barometer, for the review (never
    /// fused).
    Pressure(PressureRecord),
    /// The magnetometer in the body frame (its direction is what is used).
    #[serde(rename = "mag_B")]
    Magnetometer([f64; 3]),
    /// Which autopilot its `HEARTBEAT` says it is (logged on change).
    Autopilot(AutopilotKind),
    /// Its `HEARTBEAT`'s armed flag (logged on change).
    Armed(bool),
    /// `EXTENDED_SYS_STATE`'s landed state (logged on change).
    OnGround(bool),
    /// Today in Unix days, by the companion's clock at start.
    UnixDays(i64),
    /// The autopilot's GNSS accuracy `[horizontal, vertical]` (m, 1σ;
    /// `null` when it reports none).
    #[serde(rename = "gps_accuracy_m")]
    GpsAccuracy([Option<f64>; 2]),
    /// `GPS_GLOBAL_ORIGIN`: latitude, longitude (deg), altitude above mean
    /// sea level (m).
    Origin([f64; 3]),
    /// A simulator's truth (`SIM_STATE`): for the review, never fused.
    SimState(SimStateRecord),
    /// The autopilot EKF's test ratios of our estimates
    /// (`EKF_STATUS_REPORT`, `ESTIMATOR_STATUS`): for the review, never
    /// fused.
    EstimatorStatus(crate::io::messages::EstimatorStatus),
    /// Its flight mode (`HEARTBEAT.custom_mode`), logged on change.
    Mode(u32),
    /// A `STATUSTEXT` it sent.
    #[serde(rename = "statustext")]
    StatusText(StatusTextRecord),
    /// One of its navigation parameters (`PARAM_VALUE`), as the wire
    /// carried it (`daemon/nav_params.rs` decodes it by the autopilot's
    /// kind, logged before it).
    Param(ParamRecord),
}

/// A `PARAM_VALUE` from the autopilot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ParamRecord {
    pub name: String,
    /// The bits of the wire's `f32` (an integer's own bits with PX4), so
    /// that replay decodes exactly what came.
    pub raw_bits: u32,
    /// `MAV_PARAM_TYPE`.
    pub param_type: u8,
    /// Its value as decoded for the autopilot's kind (`null`: not a
    /// number, or the kind not yet known).
    pub value: Option<f64>,
}

/// A `STATUSTEXT` from the autopilot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StatusTextRecord {
    /// MAVLink severity: 0 emergency … 7 debug.
    pub severity: u8,
    pub text: String,
}

/// The autopilot's local position and velocity (NED) at its own time.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LocalPositionRecord {
    /// Autopilot boot time of the sample (s); NaN in format 1 logs from
    /// before it was recorded (then no carrying forward).
    #[serde(default = "nan", deserialize_with = "f64_or_nan")]
    pub t_s: f64,
    pub p_ned_m: [f64; 3],
    pub v_ned_mps: [f64; 3],
}

/// The autopilot's barometer at its own time.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PressureRecord {
    /// Autopilot boot time of the reading (s).
    pub t_s: f64,
    /// Absolute pressure (Pa).
    pub p_abs_pa: f64,
    /// The barometer's temperature (°C).
    pub temperature_c: f64,
}

/// `SIM_STATE`, and its position in our world frame once the origin is
/// known.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimStateRecord {
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Above mean sea level (m).
    pub alt_m: f64,
    pub q_wxyz: [f64; 4],
    pub v_ned_mps: [f64; 3],
    /// In our world frame (m), `None` before the origin is known.
    pub p_ned_m: Option<[f64; 3]>,
}

fn nan() -> f64 {
    f64::NAN
}

/// A number, or NaN for `null` (JSON has no NaN: serde_json writes it as
/// `null`).
fn f64_or_nan<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

impl InputRecord<'_> {
    /// The channel the record is written to.
    pub fn topic(&self) -> Topic {
        match self {
            InputRecord::Imu(_) => Topic::InputImu,
            InputRecord::Features(_) => Topic::InputFeatures,
            InputRecord::Rtcm(_) => Topic::InputRtcm,
            InputRecord::SystemTime(_) => Topic::InputSystemTime,
            InputRecord::Autopilot(_) => Topic::InputAutopilot,
            InputRecord::RebaseInstalled(_) => Topic::InputRebase,
        }
    }
}

impl InputRecord<'static> {
    /// Reads one record of the input channel `topic` back.
    pub fn parse(topic: Topic, data: &[u8]) -> Result<Self, RecordError> {
        let name = topic.name();
        let bad = |source| RecordError::Malformed { topic: name, source };
        Ok(match topic {
            Topic::InputImu => InputRecord::Imu(serde_json::from_slice(data).map_err(bad)?),
            Topic::InputFeatures => InputRecord::Features(serde_json::from_slice(data).map_err(bad)?),
            Topic::InputRtcm => InputRecord::Rtcm(serde_json::from_slice(data).map_err(bad)?),
            Topic::InputSystemTime => InputRecord::SystemTime(serde_json::from_slice(data).map_err(bad)?),
            Topic::InputAutopilot => InputRecord::Autopilot(serde_json::from_slice(data).map_err(bad)?),
            Topic::InputRebase => InputRecord::RebaseInstalled(serde_json::from_slice(data).map_err(bad)?),
            _ => return Err(RecordError::NotAnInput { topic: name }),
        })
    }
}

/// The log's `cmsckf` metadata record (its version, mode, config and log
/// format), read once for all who need it: `Ok(None)` for a log without one
/// (or cut before it), `Err` for bytes that do not start as an MCAP file.
pub fn cmsckf_metadata(bytes: &[u8]) -> Result<Option<BTreeMap<String, String>>, mcap::McapError> {
    for rec in mcap::read::LinearReader::new_with_options(bytes, mcap::read::Options::IgnoreEndMagic.into())? {
        let Ok(rec) = rec else { break };
        if let mcap::records::Record::Metadata(m) = rec {
            if m.name == "cmsckf" {
                return Ok(Some(m.metadata));
            }
        }
    }
    Ok(None)
}

/// The format of a log from its `cmsckf` metadata (a log without it is
/// taken as format 1: its reader then says what else is wrong); a newer
/// format is refused.
pub fn log_format_of(metadata: Option<&BTreeMap<String, String>>) -> Result<u32, RecordError> {
    check_format(metadata.and_then(|m| m.get("log_format")).map(String::as_str))
}

/// Checks the log format named in a log's `cmsckf` metadata (`None`: a
/// format 1 log, which did not name it).
pub fn check_format(log_format: Option<&str>) -> Result<u32, RecordError> {
    let found = match log_format {
        None => 1,
        Some(s) => match s.trim().parse::<u32>() {
            Ok(n) if n >= 1 => n,
            _ => {
                return Err(RecordError::BadFormat {
                    value: s.chars().take(40).collect(),
                })
            }
        },
    };
    if found > LOG_FORMAT {
        return Err(RecordError::NewerFormat { found });
    }
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each record as the format 1 daemon wrote it (`json!` by hand) reads
    /// back, and writes back to the same JSON.
    #[test]
    fn format_1_records_read_and_write_the_same() {
        let cases: [(Topic, &str); 14] = [
            (
                Topic::InputImu,
                r#"{"t_us":1000,"accel_mps2":[0.1,0.2,-9.8],"gyro_radps":[0.0,0.01,0.02]}"#,
            ),
            (
                Topic::InputFeatures,
                r#"{"t_us":5,"t_ap_us":7,"cam":0,"features":[[3,10.5,20.25]]}"#,
            ),
            (
                Topic::InputFeatures,
                r#"{"t_us":5,"t_ap_us":7,"cam":0,"features":[[3,10.5,20.25,0.06],[4,1.0,2.0]]}"#,
            ),
            (Topic::InputRtcm, r#"{"bytes":[211,0,1],"stream":"link_other"}"#),
            (Topic::InputSystemTime, r#"{"unix_us":1700000000000000,"boot_ms":1234}"#),
            (Topic::InputAutopilot, r#"{"attitude_rad":[0.1,-0.2,1.5]}"#),
            (
                Topic::InputAutopilot,
                r#"{"local_position":{"t_s":2.5,"p_ned_m":[1.0,2.0,3.0],"v_ned_mps":[0.0,0.5,0.0]}}"#,
            ),
            (Topic::InputAutopilot, r#"{"mag_B":[0.2,0.0,0.4]}"#),
            (Topic::InputAutopilot, r#"{"autopilot":"px4"}"#),
            (Topic::InputAutopilot, r#"{"armed":true}"#),
            (Topic::InputAutopilot, r#"{"gps_accuracy_m":[1.5,null]}"#),
            (Topic::InputAutopilot, r#"{"origin":[47.1,8.5,400.0]}"#),
            (
                Topic::InputAutopilot,
                r#"{"sim_state":{"lat_deg":47.0,"lon_deg":8.0,"alt_m":5.0,"q_wxyz":[1.0,0.0,0.0,0.0],"v_ned_mps":[1.0,0.0,0.0],"p_ned_m":null}}"#,
            ),
            (
                Topic::InputRebase,
                r#"{"seq":4,"compute_ms":1.5,"global_keyframes":12}"#,
            ),
        ];
        for (topic, json) in cases {
            let rec = InputRecord::parse(topic, json.as_bytes()).unwrap_or_else(|e| panic!("{json}: {e}"));
            assert_eq!(rec.topic(), topic);
            assert_eq!(serde_json::to_string(&rec).unwrap(), json);
        }
    }

    #[test]
    fn format_1_defaults_and_bad_records() {
        let r = InputRecord::parse(Topic::InputRtcm, br#"{"bytes":[1,2]}"#).unwrap();
        assert!(matches!(
            r,
            InputRecord::Rtcm(RtcmRecord {
                stream: RtcmStream::LinkVehicle,
                ..
            })
        ));
        let r = InputRecord::parse(
            Topic::InputAutopilot,
            br#"{"local_position":{"p_ned_m":[1,2,3],"v_ned_mps":[0,0,0]}}"#,
        )
        .unwrap();
        let InputRecord::Autopilot(AutopilotRecord::LocalPosition(l)) = r else {
            panic!("{r:?}")
        };
        assert!(l.t_s.is_nan());
        let e = InputRecord::parse(
            Topic::InputImu,
            br#"{"t_us":1,"accel_mps2":[1,2],"gyro_radps":[0,0,0]}"#,
        );
        assert!(e.unwrap_err().to_string().contains("/input/imu"));
        let e = InputRecord::parse(Topic::InputAutopilot, br#"{"attitude":[0,0,0]}"#);
        assert!(matches!(e, Err(RecordError::Malformed { .. })));
        assert!(matches!(
            InputRecord::parse(Topic::Pose, b"{}"),
            Err(RecordError::NotAnInput { .. })
        ));
    }

    #[test]
    fn newer_formats_are_refused_by_name() {
        assert_eq!(check_format(None).unwrap(), 1);
        assert_eq!(check_format(Some("2")).unwrap(), 2);
        assert_eq!(check_format(Some("3")).unwrap(), 3);
        assert_eq!(check_format(Some("4")).unwrap(), 4);
        let e = check_format(Some("5")).unwrap_err().to_string();
        assert!(e.contains("format 5"), "{e}");
        // Red-team 7: not a number (or 0) is named as such, not as a
        // format 4294967295 to read with a newer cmsckf.
        for bad in ["3.0", "three", "-1", "", "0"] {
            let e = check_format(Some(bad)).unwrap_err();
            assert!(matches!(e, RecordError::BadFormat { .. }), "{bad}: {e}");
        }
    }

    #[test]
    fn hot_records_borrow_when_written() {
        let features = vec![PixelFeature::new(1, 2.0, 3.0)];
        let rec = InputRecord::Features(FeaturesRecord {
            t_us: 1,
            t_ap_us: 1,
            cam: 0,
            features: Cow::Borrowed(&features),
        });
        assert_eq!(
            serde_json::to_string(&rec).unwrap(),
            r#"{"t_us":1,"t_ap_us":1,"cam":0,"features":[[1,2.0,3.0]]}"#
        );
    }
}
