//! The daemon's configuration: serde structs matching `config/default.toml`.
//!
//! Every field is documented with its unit. Unknown keys are rejected
//! (`deny_unknown_fields`), missing keys take the defaults below, and
//! [`Config::validate`] (in `validate.rs`) rejects non-finite and out-of-range values with a
//! message that names the field and says how to fix it. `settings.rs` turns
//! it into what the estimator needs.

use std::path::Path;

use serde::{Deserialize, Serialize};

use cmsckf_models::check::FieldError;
use cmsckf_models::sensors::{CameraConfig, ImuConfig};

use crate::estimator::Mode;
use crate::gnss::IonoMode;
use crate::io::mcap_log::LogHeader;
use crate::io::messages::ImuMessage;

pub mod kalibr;
mod settings;
mod validate;

pub use validate::load_signing_key;

/// Errors from loading a config file.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config '{path}': {source}")]
    Io { path: String, source: std::io::Error },
    #[error("config '{path}': {message}")]
    Parse { path: String, message: String },
    #[error("config '{path}': {source}")]
    Field { path: String, source: FieldError },
}

/// The whole configuration.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    pub mavlink: MavlinkConfig,
    pub features: FeaturesConfig,
    /// Defaults (`CameraConfig::default`): EuRoC MAV cam0's resolution,
    /// intrinsics and radtan distortion; the mounting, `rate_hz` and
    /// `pixel_noise_px` are not EuRoC's (config/default.toml says what they
    /// are). From Kalibr: [`kalibr`].
    pub camera: CameraConfig,
    /// Defaults (`ImuConfig::default`): EuRoC MAV imu0's noise densities (its
    /// ADIS16448; also OpenVINS's defaults), not Kalibr's example imu.yaml.
    /// From Kalibr: [`kalibr`].
    pub imu: ImuConfig,
    pub estimator: EstimatorConfig,
    pub init: InitConfig,
    pub keyframe: KeyframeConfig,
    pub compressed: CompressedConfig,
    pub gnss: GnssConfig,
    pub zupt: ZuptConfig,
    pub barometer: BarometerConfig,
    pub output: OutputConfig,
    pub log: LogConfig,
    pub live_view: LiveViewConfig,
}

/// The optional live view: a Foxglove WebSocket server streaming the
/// flight log's channels as they are written, for a ground station.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct LiveViewConfig {
    /// Off by default.
    pub enabled: bool,
    /// `HOST:PORT` to listen on; loopback unless configured otherwise
    /// (`0.0.0.0:8765` for a ground station on the vehicle's network).
    pub address: String,
}

impl Default for LiveViewConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            address: "127.0.0.1:8765".into(),
        }
    }
}

/// The MAVLink link to the autopilot.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct MavlinkConfig {
    /// Address in the `mavlink` crate's syntax: `udpin:`, `udpout:`,
    /// `tcpout:`, `serial:<dev>:<baud>`. Loopback by default: on an open
    /// network, set `signing_key_file` (anyone there could otherwise speak
    /// as the autopilot before it does).
    pub address: String,
    /// The vehicle's MAVLink system id (1..=255).
    pub system_id: u8,
    /// Our component id (197 = MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY).
    pub component_id: u8,
    /// The autopilot's component id (1 = MAV_COMP_ID_AUTOPILOT1).
    pub autopilot_component_id: u8,
    /// IMU rate requested with MAV_CMD_SET_MESSAGE_INTERVAL (Hz).
    pub imu_rate_hz: f64,
    /// The IMU message taken (the others are ignored and counted):
    /// `auto` takes `SCALED_IMU` from PX4, whose `HIGHRES_IMU` has EKF2's
    /// bias estimates (learnt from our estimates) taken out, and
    /// `HIGHRES_IMU` from any other autopilot.
    pub imu_message: ImuMessageChoice,
    /// MAVLink 2 message signing: a file holding the 32-byte secret key as 64
    /// hex digits (mode 0600 or stricter); empty = no signing. When set,
    /// unsigned and badly signed messages are rejected and counted, and ours
    /// are signed.
    pub signing_key_file: String,
    /// The signing link id we stamp on our messages (0..=255).
    pub signing_link_id: u8,
    /// Silence from the autopilot after which the link counts as down (s):
    /// HEARTBEAT shows `link_down`, the log records the outage, and a UDP
    /// link forgets the autopilot's address to learn it again.
    pub link_down_after_s: f64,
    /// Silence after which the daemon exits non-zero so that its service
    /// manager restarts it (s; 0 = never).
    pub link_exit_after_s: f64,
    /// A jump of the autopilot's IMU clock (a reboot, or a link that was
    /// down) is believed once its samples have run on this long (s) with
    /// none on the old clock among them: a burst of forged samples is not.
    pub clock_jump_confirm_s: f64,
}

impl Default for MavlinkConfig {
    fn default() -> Self {
        Self {
            address: "udpin:127.0.0.1:14550".into(),
            system_id: 1,
            component_id: 197,
            autopilot_component_id: 1,
            imu_rate_hz: 100.0,
            imu_message: ImuMessageChoice::Auto,
            signing_key_file: String::new(),
            signing_link_id: 0,
            link_down_after_s: 2.0,
            link_exit_after_s: 60.0,
            clock_jump_confirm_s: 0.25,
        }
    }
}

/// `mavlink.imu_message`: the IMU message the daemon takes.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum ImuMessageChoice {
    /// By the autopilot's kind ([`ImuMessage::auto_for`]).
    Auto,
    Highres,
    Scaled,
    Raw,
}

impl ImuMessageChoice {
    /// The message taken beside an autopilot of `kind` (not yet heard:
    /// `None`).
    pub fn resolve(self, kind: Option<crate::io::messages::AutopilotKind>) -> ImuMessage {
        match self {
            ImuMessageChoice::Auto => ImuMessage::auto_for(kind),
            ImuMessageChoice::Highres => ImuMessage::Highres,
            ImuMessageChoice::Scaled => ImuMessage::Scaled,
            ImuMessageChoice::Raw => ImuMessage::Raw,
        }
    }
}

/// Which clock the front end stamps its frames with.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum FeatureClock {
    /// The autopilot's boot clock (`HIGHRES_IMU.time_usec`).
    Autopilot,
    /// The companion computer's `CLOCK_MONOTONIC`, mapped through TIMESYNC.
    Monotonic,
}

/// The feature socket from the camera front end.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct FeaturesConfig {
    /// Path of the Unix-domain stream socket (created with mode 0600).
    pub socket: String,
    /// `autopilot` or `monotonic`.
    pub clock: FeatureClock,
    /// Longest accepted line (bytes).
    pub max_line_bytes: usize,
    /// Most features accepted in one frame (count).
    pub max_features: usize,
    /// A connected front end silent this long is dropped, so that another
    /// can connect (s; one writer is served at a time).
    pub idle_timeout_s: f64,
}

impl Default for FeaturesConfig {
    fn default() -> Self {
        Self {
            socket: "/run/cmsckf/features.sock".into(),
            clock: FeatureClock::Autopilot,
            max_line_bytes: 131_072,
            max_features: 1000,
            idle_timeout_s: 5.0,
        }
    }
}

/// The filter.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct EstimatorConfig {
    /// `msckf`, `full`, `schmidt` or `compressed`.
    pub mode: Mode,
    /// Clones in the sliding window (count).
    pub max_clones: usize,
    /// Fewest observations for a track to be used (count).
    pub min_track_len: usize,
    /// Probability of the per-track χ² gate (0..1).
    pub chi2_gate_prob: f64,
    /// Nearest accepted triangulated depth (m).
    pub min_depth_m: f64,
    /// Farthest accepted triangulated depth (m).
    pub max_depth_m: f64,
    /// Largest accepted condition number of the triangulation's normal
    /// matrix (unitless).
    pub max_triangulation_cond: f64,
    /// Tracks whose bearings span less than this are skipped, not counted
    /// against health (deg): a hover or a far landmark gives no parallax.
    pub min_parallax_deg: f64,
    /// Use those tracks at the depth their landmark was last triangulated
    /// at, so a hover is held by its image (bool); off, they are skipped.
    pub low_parallax_updates: bool,
    /// Each new view's attitude carries the jitter that the armed
    /// vehicle's vibration leaves in the integrated gyro, measured from the
    /// gyro samples (bool; README.md §3f of the estimator); off, a view is as
    /// certain as the propagation says.
    pub vibration_jitter: bool,
    /// Prior of the camera–IMU time offset `t_d` (s): the IMU clock's time
    /// of a frame is its camera stamp plus `t_d`. Estimated online.
    pub time_offset_s: f64,
    /// Sigma of that prior (s); real cameras are 5–30 ms off.
    pub time_offset_sigma_s: f64,
    /// Time after (re)initialisation during which the divergence monitor
    /// does not judge (s).
    pub health_grace_s: f64,
    /// The motion an IMU gap hides (a step beyond 50 ms): the body rate and
    /// the specific force in the gap differ from their interpolation by
    /// this much, the vehicle's own manoeuvring (rad/s, m/s²).
    pub imu_gap_sigma_rate_radps: f64,
    pub imu_gap_sigma_accel_mps2: f64,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            mode: Mode::Compressed,
            max_clones: 11,
            min_track_len: 3,
            chi2_gate_prob: 0.95,
            min_depth_m: 0.3,
            max_depth_m: 300.0,
            max_triangulation_cond: 1e6,
            min_parallax_deg: 0.3,
            low_parallax_updates: true,
            vibration_jitter: true,
            time_offset_s: 0.0,
            time_offset_sigma_s: 0.02,
            health_grace_s: 2.0,
            imu_gap_sigma_rate_radps: 0.3,
            imu_gap_sigma_accel_mps2: 3.0,
        }
    }
}

/// Initial uncertainty of the filter.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct InitConfig {
    /// Length of the static IMU segment used for roll, pitch and gyro bias (s).
    pub static_window_s: f64,
    /// The gyro's largest bias by its specification, uncompensated (rad/s):
    /// a mean rate within it may be the bias of a vehicle standing still
    /// (it is then taken as the bias), beyond it is a turn. Autopilots
    /// remove the offset before `HIGHRES_IMU`; a raw IMU (EuRoC's, a
    /// MEMS part at turn-on) may be off by 0.1 rad/s.
    pub gyro_bias_max_radps: f64,
    /// Where the first yaw comes from (after a restart it is always our own
    /// last estimate, never the autopilot's echo of it).
    pub yaw_source: YawSource,
    /// Initial yaw for `yaw_source = "config"` (deg, from north).
    pub yaw_deg: f64,
    /// Initial attitude sigma, roll and pitch (deg).
    pub sigma_tilt_deg: f64,
    /// Initial yaw sigma when the yaw is given here (`yaw_deg`) or by a
    /// simulation's truth (deg).
    pub sigma_yaw_deg: f64,
    /// Initial yaw sigma when the yaw comes from the autopilot: its compass
    /// (deg). Magnetometers beside motors and wiring are off by degrees.
    pub sigma_yaw_autopilot_deg: f64,
    /// Initial yaw sigma when the yaw is the compass's, from the autopilot's
    /// magnetometer and the WMM declination (deg): the compass's bias, which
    /// no averaging removes. The mean's own noise is added from the
    /// readings' scatter (estimator README §7, eq. H1).
    pub sigma_yaw_compass_deg: f64,
    /// A restart keeps our own last estimate and adds this position sigma
    /// (m): the filter was inconsistent, so its error is not known to be as
    /// small as its covariance said.
    pub restart_sigma_position_m: f64,
    /// ... and this velocity sigma (m/s); the position sigma also grows by
    /// it for the time the filter was out.
    pub restart_sigma_velocity_mps: f64,
    /// Initial position sigma when the filter starts the world frame where
    /// it stands (m): the frame is defined there, so this is small.
    pub sigma_position_m: f64,
    /// Initial position sigma when the start position is the autopilot's
    /// local position and it reports no GNSS accuracy (m); with
    /// `GPS_RAW_INT`'s `h_acc`/`v_acc` those are used.
    pub sigma_position_autopilot_m: f64,
    /// Initial velocity sigma (m/s).
    pub sigma_velocity_mps: f64,
    /// Initial accelerometer bias sigma (m/s²).
    pub sigma_accel_bias_mps2: f64,
    /// Initial gyroscope bias sigma (rad/s) of a static start, whose bias is
    /// the still window's mean.
    pub sigma_gyro_bias_radps: f64,
    /// Initial gyroscope bias sigma of an in-flight start (rad/s): no still
    /// window measured the bias, so the sensor's specification (a MEMS
    /// gyro's uncompensated turn-on bias; an autopilot that removes its
    /// offset first may set less). A restart keeps the last estimate's.
    pub sigma_gyro_bias_in_flight_radps: f64,
}

impl Default for InitConfig {
    fn default() -> Self {
        Self {
            static_window_s: 1.0,
            gyro_bias_max_radps: 0.15,
            yaw_source: YawSource::Auto,
            yaw_deg: 0.0,
            sigma_tilt_deg: 0.5,
            sigma_yaw_deg: 1.0,
            sigma_yaw_autopilot_deg: 5.0,
            sigma_yaw_compass_deg: 3.0,
            restart_sigma_position_m: 0.5,
            restart_sigma_velocity_mps: 0.3,
            sigma_position_m: 0.05,
            sigma_position_autopilot_m: 3.0,
            sigma_velocity_mps: 0.05,
            sigma_accel_bias_mps2: 0.05,
            sigma_gyro_bias_radps: 0.005,
            sigma_gyro_bias_in_flight_radps: 0.05,
        }
    }
}

/// Keyframes (the map kept for loop closure).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct KeyframeConfig {
    /// Time between keyframes (s).
    pub interval_s: f64,
    /// Most keyframes kept; the oldest is marginalised (count).
    pub max: usize,
}

impl Default for KeyframeConfig {
    fn default() -> Self {
        Self {
            interval_s: 5.0,
            max: 1000,
        }
    }
}

/// Compressed mode.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct CompressedConfig {
    /// Radius of the local region around its centre (m).
    pub local_radius_m: f64,
    /// Most keyframes the local part holds; beyond it a rebase demotes the
    /// least recently used (count).
    pub max_local_keyframes: usize,
    /// Compute rebases on a worker thread in the daemon, so they never stall
    /// the IMU and camera path (§5 R4).
    pub rebase_thread: bool,
}

impl Default for CompressedConfig {
    fn default() -> Self {
        Self {
            local_radius_m: 25.0,
            max_local_keyframes: 20,
            rebase_thread: true,
        }
    }
}

/// Where raw GNSS observations come from.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum GnssSource {
    Mavlink,
    Stream,
    Off,
}

/// Raw GNSS.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct GnssConfig {
    /// `mavlink` (RTCM3 in GPS_RTCM_DATA), `stream` or `off`.
    pub source: GnssSource,
    /// For `stream`: `serial:/dev/ttyUSB0:115200`, `tcp:host:port` or `file:path`.
    pub stream: String,
    /// RTCM reference-station id of the drone's own receiver, when its RTCM
    /// comes through `GPS_RTCM_DATA` (`source = "mavlink"`). That message
    /// normally carries a base station's corrections to the autopilot: any
    /// other station's observations there are a base's, kept apart and
    /// never fused as the rover's; 0 = none of them are the rover's. A
    /// station that sends its antenna position (MT1005/1006) is a base
    /// whatever this says. With `source = "stream"` the stream is the
    /// rover's own receiver.
    pub rover_station_id: u16,
    /// Constellations to use, comma separated: G, E, R, C, J.
    pub systems: String,
    /// `off`, `klobuchar`, `iono-free` or `auto`.
    pub iono: IonoMode,
    /// Satellites below this elevation are not used (deg).
    pub elevation_mask_deg: f64,
    /// Full GPS week near the data, to resolve MT1019's 10-bit week; 0 =
    /// the companion's clock until better is known. The autopilot's
    /// SYSTEM_TIME (its GNSS time) and a Galileo ephemeris's 12-bit week
    /// overrule either, with a warning when they disagree.
    pub week_hint: u32,
    /// Pseudorange noise at zenith, one sigma (m); it grows as 1/sin(el).
    pub pseudorange_sigma_m: f64,
    /// Range-rate (Doppler) noise at zenith, one sigma (m/s).
    pub range_rate_sigma_mps: f64,
    /// Broadcast orbit and clock error on each satellite's range, one sigma
    /// (m), as one epoch sees it: the default, 2.4 m, is the user range
    /// accuracy a healthy GPS satellite broadcasts (URA index 0), as RTKLIB
    /// weights it. It screens outliers (a code far from its constellation's
    /// median), is the prior of a range-bias state started again after a
    /// step (at least `range_bias_sigma_m`), and weighs the codes of
    /// satellites without a state (see `range_bias_states`). Differential
    /// codes have it removed.
    pub broadcast_sigma_m: f64,
    /// Error of the troposphere model at zenith, one sigma (m): the prior of
    /// its state (or, without range-bias states, a weight growing as
    /// 1/sin(el)). A base nearby removes it.
    pub troposphere_sigma_m: f64,
    /// Each satellite's broadcast error, and the troposphere model's error
    /// at zenith, as states of the filter (§8c, eq. DG5′): believed once,
    /// whatever the rate and the length of the flight. `false`: weighted
    /// by `broadcast_sigma_m` and `correlation_window_s` instead (eq. DG6),
    /// which a keyframe map holding an hour of fixes believes about ten
    /// times over (position NEES 34.4 against 3 after an hour).
    pub range_bias_states: bool,
    /// Prior of a satellite's range-bias state, one sigma (m): the signal in
    /// space range error of a modern GPS or Galileo satellite; GLONASS's is
    /// taken twice as wide.
    pub range_bias_sigma_m: f64,
    /// How fast a range bias wanders, random walk (m/√s).
    pub range_bias_rw_m_per_sqrt_s: f64,
    /// A satellite's state leaves after this long without a fused code (s).
    pub range_bias_timeout_s: f64,
    /// How fast the zenith troposphere error wanders, random walk (m/√s);
    /// its prior is `troposphere_sigma_m`.
    pub troposphere_rw_m_per_sqrt_s: f64,
    /// Errors that hold for the whole flight and have no state (a range
    /// rate's persistent part, a base correction that corrects several
    /// rover epochs, the base's announced position; and the broadcast and
    /// troposphere errors without range-bias states): fused epoch after
    /// epoch as white noise, they would be believed once per epoch. So
    /// their variance is scaled by the epochs in this window (s), at least
    /// 1: whatever the receiver's rate, they count as one measurement per
    /// window (§8c, eq. DG6).
    pub correlation_window_s: f64,
    /// The persistent part of a range rate at zenith, one sigma (m/s): the
    /// troposphere's rate and the signal's flight time, which the model
    /// leaves out; grows as 1/sin(el), scaled as above.
    pub range_rate_correlated_sigma_mps: f64,
    /// A single-frequency code's ionosphere (unmodelled: 5 m of variance
    /// inflation; or Klobuchar's residual) holds for tens of minutes along
    /// each line of sight and is metres: its variance is scaled by the
    /// epochs in this window (s), at least 1 (§8c, eq. DG6′). Fused as
    /// white noise it made single point overconfident (position NEES 23.6
    /// on the simulated ionosphere).
    pub ionosphere_window_s: f64,
    /// Receiver clock bias white-frequency noise (m/√s).
    pub clock_bias_rw_m_per_sqrt_s: f64,
    /// Receiver clock drift random walk (m/s/√s).
    pub clock_drift_rw_mps_per_sqrt_s: f64,
    /// Random walk of the Galileo − GPS inter-system bias (m/√s).
    pub isb_rw_m_per_sqrt_s: f64,
    /// Geodetic origin of the NED world frame `[lat_deg, lon_deg, h_m]`,
    /// `h_m` above the WGS84 ellipsoid; empty = the autopilot's
    /// GPS_GLOBAL_ORIGIN (its altitude above mean sea level, converted
    /// through EGM96), else the first single-point fix.
    pub origin_llh: Vec<f64>,
    /// Klobuchar ionosphere α0..α3 (s, s/semicircle, …); empty = unknown.
    pub klobuchar_alpha: Vec<f64>,
    /// Klobuchar ionosphere β0..β3 (s, s/semicircle, …); empty = unknown.
    pub klobuchar_beta: Vec<f64>,
    /// GNSS antenna phase centre in the body frame, `[fwd, right, down]` (m).
    #[serde(rename = "p_A_in_B_m")]
    pub p_A_in_B_m: [f64; 3],
    /// The receiver's epoch rate (Hz), assumed until two epochs show theirs.
    pub epoch_rate_hz: f64,
    /// Latest an epoch may arrive after its own time and still be fused at
    /// that time (s); later ones are counted as `gnss_late`.
    pub max_delay_s: f64,
    /// Differential GNSS: when a base station is on the link (RTCM in
    /// `GPS_RTCM_DATA` with its MT1005/1006 antenna position), fuse the
    /// rover's codes less the base's corrections instead of the raw codes.
    pub dgnss: bool,
    /// Oldest base epoch a differential code may use (s); older, the epoch
    /// falls back to single-point codes. A base epoch's correction is held,
    /// never extrapolated, until a newer one comes.
    pub dgnss_max_age_s: f64,
    /// How fast a held correction drifts from the truth, one sigma (m/s):
    /// the satellites' clock and orbit errors and the atmosphere change
    /// while the base is late or silent; its variance grows as
    /// `(σ·age)²` (§8c, eq. DG2′).
    pub dgnss_correction_rate_sigma_mps: f64,
    /// Farthest the base's announced antenna position (MT1005/1006) may be
    /// from its own single-point fixes horizontally (m, median of the last
    /// five; twice this vertically, where a single-frequency fix is
    /// biased by the ionosphere): beyond it the base is refused (a badly
    /// surveyed or mistyped position moves the rover by as much) and single
    /// point is used.
    pub base_max_position_error_m: f64,
    /// How well the base's announced position is known, one sigma per axis
    /// (m): every differential code, and so the rover, is off by its error
    /// for the whole flight, and no check can see an error of a few metres.
    /// A surveyed mark: 0.05; a receiver's survey-in: its accuracy limit
    /// (1–2 m). MT1005 does not say (§8c, eq. DG9′).
    pub base_position_sigma_m: f64,
    /// When most of a base's corrected codes keep failing the filter's gate,
    /// the base is set aside for this long (s) and single point used, with
    /// a STATUSTEXT; it never causes a filter reset.
    pub base_holdoff_s: f64,
}

impl Default for GnssConfig {
    fn default() -> Self {
        Self {
            source: GnssSource::Mavlink,
            stream: String::new(),
            rover_station_id: 0,
            dgnss: true,
            dgnss_max_age_s: 10.0,
            dgnss_correction_rate_sigma_mps: 0.01,
            base_max_position_error_m: 10.0,
            base_position_sigma_m: 0.5,
            base_holdoff_s: 30.0,
            systems: "G,E,R,C,J".into(),
            iono: IonoMode::Auto,
            elevation_mask_deg: 10.0,
            week_hint: 0,
            pseudorange_sigma_m: 0.5,
            range_rate_sigma_mps: 0.05,
            broadcast_sigma_m: 2.4,
            troposphere_sigma_m: 0.1,
            range_bias_states: true,
            range_bias_sigma_m: 0.6,
            range_bias_rw_m_per_sqrt_s: 0.002,
            range_bias_timeout_s: 300.0,
            troposphere_rw_m_per_sqrt_s: 0.0002,
            correlation_window_s: 4.0,
            range_rate_correlated_sigma_mps: 0.005,
            ionosphere_window_s: 60.0,
            clock_bias_rw_m_per_sqrt_s: 0.02,
            clock_drift_rw_mps_per_sqrt_s: 0.01,
            isb_rw_m_per_sqrt_s: 0.001,
            origin_llh: Vec::new(),
            klobuchar_alpha: Vec::new(),
            klobuchar_beta: Vec::new(),
            p_A_in_B_m: [0.0; 3],
            epoch_rate_hz: 1.0,
            max_delay_s: 1.0,
        }
    }
}

/// Zero-velocity updates at standstill (on the ground, in a hover): a frame
/// is one when all of these hold.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ZuptConfig {
    pub enabled: bool,
    /// Largest mean body rate since the last frame, the gyro bias removed,
    /// beyond two standard errors of the samples' own scatter and three
    /// sigmas of the bias (rad/s).
    pub max_gyro_radps: f64,
    /// Largest mean of `a_m − b_a + R_W_Bᵀ g` since the last frame: the
    /// specific force's departure from gravity's, in any direction, beyond
    /// two standard errors of the scatter and three sigmas of the tilt (m/s²).
    pub max_accel_deviation_mps2: f64,
    /// Largest RMS scatter of the body rate about its mean (rad/s): motor
    /// vibration on a vehicle standing armed is about 0.1; more is not a
    /// vehicle standing.
    pub max_vibration_gyro_radps: f64,
    /// Largest RMS scatter of the specific force about its mean (m/s²):
    /// about 0.8 on an armed multirotor standing.
    pub max_vibration_accel_mps2: f64,
    /// Largest median feature displacement since the last clone (px). Pixel
    /// noise alone moves a still feature by a median of 1.7 σ_px between two
    /// frames: keep this about 3 σ_px.
    pub max_disparity_px: f64,
    /// Largest estimated speed (m/s).
    pub max_speed_mps: f64,
    /// Sigma of the zero-velocity measurement (m/s).
    pub sigma_mps: f64,
}

impl Default for ZuptConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            max_gyro_radps: 0.02,
            max_accel_deviation_mps2: 0.1,
            max_vibration_gyro_radps: 0.5,
            max_vibration_accel_mps2: 5.0,
            max_disparity_px: 3.0,
            max_speed_mps: 0.5,
            sigma_mps: 0.01,
        }
    }
}

/// The autopilot's barometer (`SCALED_PRESSURE`) as a height with an
/// offset the filter estimates (estimator README §3g). It is logged
/// whether or not it is fused.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct BarometerConfig {
    /// Fuse it: the height's changes then follow the barometer's, and a
    /// climb flown at the wrong scale is pulled back.
    pub fuse: bool,
    /// One reading's white noise (m, 1σ): about 0.1 for a MEMS barometer
    /// at 10 Hz; more beside propellers' wash.
    pub noise_m: f64,
    /// How fast its zero wanders with temperature and weather (m/√s).
    pub offset_rw_m_per_sqrt_s: f64,
}

impl Default for BarometerConfig {
    fn default() -> Self {
        let b = crate::estimator::BaroSettings::default();
        Self {
            fuse: true,
            noise_m: b.noise_m,
            offset_rw_m_per_sqrt_s: b.offset_rw_m_per_sqrt_s,
        }
    }
}

/// How the pose covariance of the estimates is written.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum PoseCovariance {
    /// `ardupilot_cbrt` towards an autopilot whose HEARTBEAT says ArduPilot,
    /// `variances` towards any other.
    #[default]
    Auto,
    /// The covariance as MAVLink defines it, in variances (PX4 reads it
    /// axis by axis; ArduPilot with PR #32084 takes √trace).
    Variances,
    /// Written so that ArduPilot's reduction, `cbrt(c₀² + c₆² + c₁₁²)` for
    /// position and the same over the angles (`GCS_Common.cpp`, releases up
    /// to 4.6 and master before PR #32084), gives back our 1σ: each
    /// position variance entry σ_p^(3/2)/√3 with σ_p the largest axis's σ,
    /// each angle entry σ_ψ^(3/2)/√3 with σ_ψ the yaw's σ (the only angle
    /// EKF3 uses), every other entry 0. Then cbrt(3·c²) = σ.
    ArdupilotCbrt,
}

/// Which position uncertainty the estimates carry (estimator README eq. O2).
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum PositionCovariance {
    /// `GivenYaw` towards PX4 once its parameters say that its heading is
    /// ours alone (`EKF2_EV_CTRL` bit 3 on, `EKF2_GPS_CTRL` bits 0, 2 and 3 off,
    /// `EKF2_MAG_TYPE` 5, read over MAVLink: `daemon/nav_params.rs`);
    /// `Absolute` until they are read, when they say otherwise, and towards
    /// any other autopilot (conditioning was measured beside PX4 only).
    #[default]
    Auto,
    /// The position's whole uncertainty, our yaw's share included (the
    /// compass's bias, 3° by default: 0.6 m at 12 m from the start). Right
    /// whatever the autopilot takes its heading from.
    Absolute,
    /// The position's uncertainty given our yaw: the share that a turn of
    /// our whole frame by our yaw's error explains is taken out, and the
    /// attitude's covariance is sent as it is. Right only when the autopilot
    /// takes its heading from us alone and has no position of its own
    /// (PX4: `EKF2_EV_CTRL` bit 3 on, `EKF2_MAG_TYPE` 5, `EKF2_GPS_CTRL` 0; ArduPilot:
    /// `EK3_SRC1_YAW = 6` and no GPS): its frame then turns with ours, and
    /// a drift across that frame is its position's error. Sent whole,
    /// EKF2 weighs each of our positions at an σ that no single sample
    /// errs by, and strays from them (docs/setup-px4.md). With a heading of
    /// its own (compass, GNSS) it is overconfident by the turn's share.
    GivenYaw,
}

/// Where the filter's first yaw comes from.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum YawSource {
    /// The compass when the autopilot's `HIGHRES_IMU` carries a magnetic
    /// field and the origin is known (for the declination), else the
    /// autopilot's `ATTITUDE` yaw. With external navigation as the
    /// autopilot's yaw source (ArduPilot `EK3_SRC1_YAW = 6`), its yaw is a
    /// placeholder 0 until our first estimate, so it must not be taken.
    #[default]
    Auto,
    /// The compass only: the filter waits for a magnetic field.
    Compass,
    /// The autopilot's `ATTITUDE` yaw (its own EKF with compass or GNSS).
    Autopilot,
    /// `init.yaw_deg`.
    Config,
}

/// Which message carries the estimate to the autopilot: one of them, never
/// both (the same pose fused twice would count as two measurements).
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum OutputMessage {
    /// `ODOMETRY` (331): pose, body velocity and rates, both covariances,
    /// `reset_counter` and a `quality`. The default: ArduPilot 4.1+
    /// (`VISO_TYPE = 1`) reads velocity and `quality` (`VISO_QUAL_MIN`) from
    /// this message only, and PX4 maps it to `vehicle_visual_odometry`
    /// (`EKF2_EV_CTRL`); both prefer it.
    #[default]
    Odometry,
    /// `VISION_POSITION_ESTIMATE` (102) with `VISION_SPEED_ESTIMATE` (103)
    /// at the same instant, for autopilots older than ArduPilot 4.1.
    VisionPositionEstimate,
}

/// Messages sent to the autopilot.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Estimate rate (Hz, autopilot time); ArduPilot needs at least 4.
    pub rate_hz: f64,
    /// `odometry` (default) or `vision_position_estimate` (with
    /// `VISION_SPEED_ESTIMATE`): see [`OutputMessage`].
    pub message: OutputMessage,
    /// Send SET_GPS_GLOBAL_ORIGIN once the origin is known: `gnss.origin_llh`
    /// (so a VIO-only vehicle gets an EKF origin), else the first fix; its
    /// altitude above mean sea level, as MAVLink defines it (EGM96).
    pub set_gps_origin: bool,
    /// How the pose covariance is written: see [`PoseCovariance`].
    pub covariance: PoseCovariance,
    /// Which position uncertainty is sent: see [`PositionCovariance`].
    pub position_covariance: PositionCovariance,
    /// The removed `odometry = true|false`, read only so that an old config
    /// is refused with what replaces it (never written).
    #[serde(skip_serializing)]
    pub odometry: Option<bool>,
}

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            rate_hz: 30.0,
            message: OutputMessage::Odometry,
            set_gps_origin: false,
            covariance: PoseCovariance::Auto,
            position_covariance: PositionCovariance::Auto,
            odometry: None,
        }
    }
}

/// The MCAP flight log.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct LogConfig {
    /// Output path, with strftime-style `%Y%m%d-%H%M%S`; empty = no log.
    /// A name that exists is never written over: a suffix is added.
    pub path: String,
    /// A log is closed and the next begun past this size (MiB; 0: no limit).
    pub max_file_mb: u64,
    /// The logs in the log's directory whose names start as `path`'s does
    /// are kept under this total, deleting the oldest finished ones first
    /// (MiB; 0: no limit). Unfinished (crash) logs are never deleted.
    pub max_total_mb: u64,
    /// Begin a new log when the vehicle disarms, so that each log holds one
    /// flight, from the ground before arming to its disarm.
    pub new_log_on_disarm: bool,
}

impl Default for LogConfig {
    fn default() -> Self {
        Self {
            path: "cmsckf-%Y%m%d-%H%M%S.mcap".into(),
            max_file_mb: 1024,
            max_total_mb: 8192,
            new_log_on_disarm: true,
        }
    }
}

impl Config {
    /// The header of a flight log written under this config (the daemon's
    /// and replay's): this build's version, the mode and the config itself.
    pub fn log_header(&self) -> LogHeader {
        LogHeader {
            version: env!("CMSCKF_BUILD").to_string(),
            mode: self.estimator.mode.name().to_string(),
            config_toml: toml::to_string(self).unwrap_or_default(),
        }
    }

    /// Parses TOML text (unknown keys are errors) and validates it.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let cfg: Config = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: origin.to_string(),
            message: e.to_string(),
        })?;
        cfg.validate().map_err(|source| ConfigError::Field {
            path: origin.to_string(),
            source,
        })?;
        Ok(cfg)
    }

    /// Reads and validates a config file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_toml(&text, &path.display().to_string())
    }
}

#[cfg(test)]
mod tests;
