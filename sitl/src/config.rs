//! The simulator's settings: what truth and noise to make.
//!
//! The camera and IMU descriptions it draws with are the shared ones of
//! `cmsckf_models::sensors`, the same the estimator models its sensors with,
//! so the two cannot drift apart. Every field carries its unit in its name or
//! doc, and [`Validate`] rejects non-finite or out-of-range values with a
//! message that names the field and the fix.
//!
//! [`SimConfig::new`] is deliberately as unkind as a real drone, because a
//! filter tuned on punctual, co-located, airborne-from-the-start sensors
//! fails on the first real flight:
//! - a camera's frames reach the host 30–60 ms after exposure
//!   (`camera_latency_s`), and its clock is off the IMU's by an unknown
//!   offset (`camera_time_offset_s`, OpenVINS's `t_imu = t_cam + t_d`);
//! - a GNSS receiver reports an epoch 0.2–0.6 s after it
//!   (`gnss.latency_s`), and measures at its antenna, not at the IMU
//!   (`gnss.p_A_in_B_m`);
//! - a multirotor sits on the ground before it takes off (`standstill_s`);
//! - in the air it never flies its smooth commanded path: gusts push it
//!   about by decimetres and tilt it by degrees (`[wind]`).
//!
//! Setting the latencies, the offset, the lever arm, the standstill and the
//! gusts to 0 gives back ideal sensors and the historical airborne scenarios.

use serde::{Deserialize, Serialize};

use cmsckf_models::check::{Check, FieldError, Validate};
use cmsckf_models::sensors::{CameraConfig, ImuConfig};

use crate::imu::VibrationConfig;
use crate::trajectory::WindConfig;

/// Simulated feature tracks (a KLT-like front end over a landmark field).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct FeatureSimConfig {
    /// Tracks kept per frame; new landmarks are spawned in view when fewer
    /// are visible (count).
    pub per_frame: usize,
    /// Nearest depth at which new landmarks are spawned (m).
    pub depth_min_m: f64,
    /// Farthest depth at which new landmarks are spawned (m).
    pub depth_max_m: f64,
    /// Landmarks farther than this are not detected (m).
    pub max_range_m: f64,
    /// Probability per frame that a live track is lost (0..1).
    pub track_loss_prob: f64,
    /// Probability that a landmark that comes back into view is re-identified
    /// with its old id, which is what produces loop closures (0..1).
    pub reid_prob: f64,
    /// Probability per observation of an outlier (0..1): half are wrong ids,
    /// half gross pixel errors.
    pub outlier_prob: f64,
}

impl Default for FeatureSimConfig {
    fn default() -> Self {
        Self {
            per_frame: 100,
            depth_min_m: 5.0,
            depth_max_m: 30.0,
            max_range_m: 60.0,
            track_loss_prob: 0.03,
            reid_prob: 0.9,
            outlier_prob: 0.01,
        }
    }
}

impl Validate for FeatureSimConfig {
    fn validate(&self, prefix: &str) -> Result<(), FieldError> {
        let c = Check::new(prefix);
        c.within("per_frame", self.per_frame as u64, 1, 2000, "set 1..2000")?;
        c.positive("depth_min_m", self.depth_min_m, 1e4)?;
        c.positive("depth_max_m", self.depth_max_m, 1e4)?;
        if self.depth_max_m < self.depth_min_m {
            return Err(c.fail("depth_max_m", "is below depth_min_m", "set depth_max_m ≥ depth_min_m"));
        }
        c.positive("max_range_m", self.max_range_m, 1e5)?;
        c.range("track_loss_prob", self.track_loss_prob, 0.0, 1.0)?;
        c.range("reid_prob", self.reid_prob, 0.0, 1.0)?;
        c.range("outlier_prob", self.outlier_prob, 0.0, 1.0)
    }
}

/// Simulated GNSS receiver and constellation.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct GnssSimConfig {
    /// Whether pseudoranges are generated.
    pub enabled: bool,
    /// Epoch rate (Hz).
    pub rate_hz: f64,
    /// Geodetic origin of the NED world frame: `[lat_deg, lon_deg, height_m]`
    /// (WGS-84 ellipsoidal height).
    pub origin_llh: [f64; 3],
    /// GPS week of the start of the flight (full week number).
    pub start_week: u32,
    /// GPS time of week at the start of the flight (s).
    pub start_tow_s: f64,
    /// Pseudorange noise at zenith, one sigma (m); it grows as 1/sin(elevation).
    pub pseudorange_noise_m: f64,
    /// Pseudorange-rate noise at zenith, one sigma (m/s).
    pub pseudorange_rate_noise_mps: f64,
    /// Satellites below this elevation are not tracked (deg).
    pub elevation_mask_deg: f64,
    /// Receiver clock drift random walk, `c·δṫ` (m/s/√s).
    pub clock_drift_rw_mps_per_sqrt_s: f64,
    /// Receiver clock bias white frequency noise, `c·δt` (m/√s).
    pub clock_bias_rw_m_per_sqrt_s: f64,
    /// Initial receiver clock bias `c·δt` (m).
    pub clock_bias0_m: f64,
    /// Initial receiver clock drift `c·δṫ` (m/s).
    pub clock_drift0_mps: f64,
    /// Probability per satellite and epoch of a multipath outlier (0..1).
    pub multipath_prob: f64,
    /// Size of a multipath outlier (m).
    pub multipath_m: f64,
    /// Whether an ionospheric delay is added (Klobuchar-like, 5 m at zenith
    /// by day).
    pub ionosphere: bool,
    /// Whether Galileo (E1) is tracked beside GPS.
    pub galileo: bool,
    /// The receiver's Galileo − GPS inter-system bias (m).
    pub isb_galileo_m: f64,
    /// Delivery delay of an epoch after its instant, drawn uniformly per
    /// epoch from `[min, max]` (s): a receiver solves and serialises an epoch
    /// before it sends it, and the link adds its own delay.
    pub latency_s: [f64; 2],
    /// The antenna's position in the body frame (FRD, m): pseudoranges and
    /// rates are measured at the antenna, which sits away from the IMU.
    /// The default, `[0.10, 0.05, −0.10]`, is 10 cm forward, 5 cm right and
    /// 10 cm up, 0.15 m from the IMU, a mast on a small multirotor.
    pub p_A_in_B_m: [f64; 3],
    /// Broadcast orbit and clock error projected on the line of sight, one
    /// sigma per satellite (m): the "signal-in-space range error" every
    /// receiver sees alike (GPS's is about 0.6 m). Constant over a flight;
    /// a base station nearby sees the same, so differential GNSS removes it.
    pub broadcast_error_m: f64,
    /// The troposphere the receiver's model misses, as a fraction of the
    /// Saastamoinen slant delay (the wet part's misfit), alike for every
    /// receiver nearby.
    pub troposphere_error_frac: f64,
    /// A base station near the flight, sending its observations and antenna
    /// position (MT1005) as a ground station injects them into
    /// `GPS_RTCM_DATA`.
    pub base: BaseSimConfig,
    /// Elevation below which the rover sees no satellite (deg) from
    /// `canyon_s[0]` to `canyon_s[1]` of flight time, except the
    /// `canyon_keep` highest (an urban canyon); empty: none.
    pub canyon_s: Vec<f64>,
    pub canyon_keep: usize,
}

/// A simulated base station: a receiver of the same kind at a surveyed
/// point, with its own clock and noise.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct BaseSimConfig {
    pub enabled: bool,
    /// The antenna's position in the world frame (NED from the origin, m).
    pub p_base_in_W_m: [f64; 3],
    /// RTCM reference-station id.
    pub station_id: u16,
    /// Delay from an epoch to its arrival at the vehicle (s), drawn per epoch:
    /// a radio link and the ground station's relay.
    pub latency_s: [f64; 2],
    /// Whether the base tracks Galileo (many older bases and CORS sites
    /// send GPS only, while the rover tracks both).
    pub galileo: bool,
    /// The base sends legacy MT1004 (GPS L1 with its ambiguity) instead of
    /// MSM7, as many CORS networks and NTRIP casters do: GPS only.
    pub legacy: bool,
    /// How far the antenna position the base announces (MT1005) is from
    /// where it stands (NED, m): a badly surveyed base.
    pub announced_error_m: [f64; 3],
    /// A second ground station (system 254) relays the same base under
    /// this other station id, announcing a position 40 m away (0: none).
    pub second_station_id: u16,
}

impl Default for BaseSimConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            p_base_in_W_m: [2000.0, -1500.0, 0.0],
            station_id: 100,
            latency_s: [0.3, 0.8],
            galileo: true,
            legacy: false,
            announced_error_m: [0.0; 3],
            second_station_id: 0,
        }
    }
}

impl Default for GnssSimConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate_hz: 1.0,
            // Sydney, near the paper's authors.
            origin_llh: [-33.8840, 151.1990, 40.0],
            start_week: 2443,
            start_tow_s: 345_600.0,
            pseudorange_noise_m: 0.5,
            pseudorange_rate_noise_mps: 0.05,
            elevation_mask_deg: 10.0,
            clock_drift_rw_mps_per_sqrt_s: 0.01,
            clock_bias_rw_m_per_sqrt_s: 0.02,
            clock_bias0_m: 12_000.0,
            clock_drift0_mps: 15.0,
            multipath_prob: 0.005,
            multipath_m: 30.0,
            ionosphere: false,
            galileo: true,
            isb_galileo_m: 6.0,
            latency_s: [0.2, 0.6],
            p_A_in_B_m: [0.10, 0.05, -0.10],
            broadcast_error_m: 0.6,
            troposphere_error_frac: 0.05,
            base: BaseSimConfig::default(),
            canyon_s: Vec::new(),
            canyon_keep: 3,
        }
    }
}

impl Validate for GnssSimConfig {
    fn validate(&self, prefix: &str) -> Result<(), FieldError> {
        let c = Check::new(prefix);
        c.positive("rate_hz", self.rate_hz, 20.0)?;
        c.range("origin_llh[0]", self.origin_llh[0], -90.0, 90.0)?;
        c.range("origin_llh[1]", self.origin_llh[1], -180.0, 180.0)?;
        c.range("origin_llh[2]", self.origin_llh[2], -500.0, 10_000.0)?;
        c.within(
            "start_week",
            self.start_week as u64,
            1024,
            10_000,
            "give the full GPS week, e.g. 2443",
        )?;
        c.range("start_tow_s", self.start_tow_s, 0.0, 604_799.0)?;
        c.positive("pseudorange_noise_m", self.pseudorange_noise_m, 1e3)?;
        c.positive("pseudorange_rate_noise_mps", self.pseudorange_rate_noise_mps, 1e2)?;
        c.range("elevation_mask_deg", self.elevation_mask_deg, 0.0, 60.0)?;
        c.range(
            "clock_drift_rw_mps_per_sqrt_s",
            self.clock_drift_rw_mps_per_sqrt_s,
            0.0,
            100.0,
        )?;
        c.range(
            "clock_bias_rw_m_per_sqrt_s",
            self.clock_bias_rw_m_per_sqrt_s,
            0.0,
            100.0,
        )?;
        c.range("clock_bias0_m", self.clock_bias0_m, -3e5, 3e5)?;
        c.range("clock_drift0_mps", self.clock_drift0_mps, -1e3, 1e3)?;
        c.range("multipath_prob", self.multipath_prob, 0.0, 1.0)?;
        c.range("multipath_m", self.multipath_m, 0.0, 1e4)?;
        c.range("isb_galileo_m", self.isb_galileo_m, -1e3, 1e3)?;
        latency_range(&c, "latency_s", &self.latency_s, 5.0)?;
        c.range("broadcast_error_m", self.broadcast_error_m, 0.0, 100.0)?;
        c.range("troposphere_error_frac", self.troposphere_error_frac, -1.0, 1.0)?;
        if !self.canyon_s.is_empty() && (self.canyon_s.len() != 2 || self.canyon_s[1] < self.canyon_s[0]) {
            return Err(c.fail(
                "canyon_s",
                "is not [start, end]",
                "give [start_s, end_s] with end ≥ start, or []",
            ));
        }
        c.within("canyon_keep", self.canyon_keep as u64, 0, 64, "set 0..64")?;
        c.all_finite("base.p_base_in_W_m", &self.base.p_base_in_W_m, -1e5, 1e5)?;
        latency_range(&c, "base.latency_s", &self.base.latency_s, 10.0)?;
        c.all_finite("base.announced_error_m", &self.base.announced_error_m, -1e5, 1e5)?;
        c.all_finite("p_A_in_B_m", &self.p_A_in_B_m, -5.0, 5.0)
    }
}

/// The mock autopilot's own EKF, as it shows in its `LOCAL_POSITION_NED` and
/// `ATTITUDE`: never the truth, because a real autopilot only knows its own
/// estimate, and the daemon starts (and restarts) its filter from it.
///
/// The model (`serve::autopilot`), per axis:
/// - position error `e`: a first-order Gauss–Markov process (stationary
///   sigma `position_drift_sigma_m`, correlation time
///   `position_drift_time_s`), the slow wander of a GNSS-aided EKF; while
///   the GNSS is out it is a random walk at the same rate (no absolute aid
///   pulls it back);
/// - with `follow_vpe`, each `VISION_POSITION_ESTIMATE` that passes EK3's
///   5σ-style innovation gate pulls `e` toward the daemon's own error with
///   time constant `follow_time_s`, as ArduPilot's EK3 does with external
///   navigation as its position source; a change of the estimate's
///   `reset_counter`, or `vpe_retry_s` of rejected estimates, resets `e` to
///   the daemon's error, as EK3 resets to external navigation;
/// - on top, white noise `position_noise_m` on each message, and
///   `velocity_noise_mps` on its velocity;
/// - attitude: Gauss–Markov tilt (roll/pitch) and yaw biases plus white
///   noise; the yaw is a compass's, a few degrees off, and does not follow
///   the daemon.
///
/// Nothing ever sets `e` to zero: after a link drop or a reboot the
/// autopilot reports where it last believed it was, drifting on. All
/// magnitudes 0 and `follow_vpe = false` give back the truth.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct AutopilotSimConfig {
    /// Stationary one-sigma of the position error's slow drift, per axis (m).
    pub position_drift_sigma_m: f64,
    /// Correlation time of that drift (s): minutes, as a GNSS-aided EKF
    /// wanders.
    pub position_drift_time_s: f64,
    /// White noise on each reported position, one sigma per axis (m).
    pub position_noise_m: f64,
    /// White noise on each reported velocity, one sigma per axis (m/s).
    pub velocity_noise_mps: f64,
    /// Stationary one-sigma of the roll and pitch biases (deg).
    pub tilt_bias_sigma_deg: f64,
    /// Correlation time of the roll and pitch biases (s).
    pub tilt_bias_time_s: f64,
    /// White noise on the reported roll and pitch, one sigma (deg).
    pub tilt_noise_deg: f64,
    /// Stationary one-sigma of the yaw bias (deg): a compass beside motors
    /// and wiring is degrees off.
    pub yaw_bias_sigma_deg: f64,
    /// Correlation time of the yaw bias (s).
    pub yaw_bias_time_s: f64,
    /// White noise on the reported yaw, one sigma (deg).
    pub yaw_noise_deg: f64,
    /// Whether the position follows the daemon's estimates (EK3 with
    /// external navigation as its position source).
    pub follow_vpe: bool,
    /// Time constant with which the position error follows the daemon's (s).
    pub follow_time_s: f64,
    /// Innovation gate on the daemon's estimates, in sigmas of the
    /// innovation (EK3_POS_I_GATE's 5σ).
    pub vpe_gate_sigma: f64,
    /// After this long with every estimate rejected, the autopilot resets
    /// to the daemon's (s; EK3's position retry time without velocity aid).
    pub vpe_retry_s: f64,
    /// How long before the vehicle leaves the ground its land detector
    /// says "in the air" (s): the motors spin up on the ground first. PX4's
    /// beside its SIH said so 1.1 s before the truth rose
    /// (docs/setup-px4.md); ArduPilot clears its landed flag as the
    /// take-off's throttle rises, before the vehicle does. 0 says it as
    /// the truth leaves.
    pub land_detector_lead_s: f64,
}

impl Default for AutopilotSimConfig {
    fn default() -> Self {
        Self {
            position_drift_sigma_m: 0.5,
            position_drift_time_s: 120.0,
            position_noise_m: 0.05,
            velocity_noise_mps: 0.05,
            tilt_bias_sigma_deg: 0.3,
            tilt_bias_time_s: 60.0,
            tilt_noise_deg: 0.1,
            yaw_bias_sigma_deg: 2.0,
            yaw_bias_time_s: 600.0,
            yaw_noise_deg: 0.2,
            follow_vpe: true,
            follow_time_s: 1.0,
            vpe_gate_sigma: 5.0,
            vpe_retry_s: 7.0,
            land_detector_lead_s: 1.1,
        }
    }
}

impl AutopilotSimConfig {
    /// An autopilot that reports the truth (the historical mock).
    pub fn truth() -> Self {
        Self {
            position_drift_sigma_m: 0.0,
            position_noise_m: 0.0,
            velocity_noise_mps: 0.0,
            tilt_bias_sigma_deg: 0.0,
            tilt_noise_deg: 0.0,
            yaw_bias_sigma_deg: 0.0,
            yaw_noise_deg: 0.0,
            follow_vpe: false,
            land_detector_lead_s: 0.0,
            ..Self::default()
        }
    }
}

impl Validate for AutopilotSimConfig {
    fn validate(&self, prefix: &str) -> Result<(), FieldError> {
        let c = Check::new(prefix);
        c.range("position_drift_sigma_m", self.position_drift_sigma_m, 0.0, 1e3)?;
        c.positive("position_drift_time_s", self.position_drift_time_s, 1e6)?;
        c.range("position_noise_m", self.position_noise_m, 0.0, 1e3)?;
        c.range("velocity_noise_mps", self.velocity_noise_mps, 0.0, 1e2)?;
        c.range("tilt_bias_sigma_deg", self.tilt_bias_sigma_deg, 0.0, 30.0)?;
        c.positive("tilt_bias_time_s", self.tilt_bias_time_s, 1e6)?;
        c.range("tilt_noise_deg", self.tilt_noise_deg, 0.0, 30.0)?;
        c.range("yaw_bias_sigma_deg", self.yaw_bias_sigma_deg, 0.0, 180.0)?;
        c.positive("yaw_bias_time_s", self.yaw_bias_time_s, 1e6)?;
        c.range("yaw_noise_deg", self.yaw_noise_deg, 0.0, 180.0)?;
        c.positive("follow_time_s", self.follow_time_s, 1e3)?;
        c.positive("vpe_gate_sigma", self.vpe_gate_sigma, 1e3)?;
        c.positive("vpe_retry_s", self.vpe_retry_s, 1e3)?;
        c.range("land_detector_lead_s", self.land_detector_lead_s, 0.0, 10.0)
    }
}

/// A delivery-latency range `[min, max]` (s): both in `[0, hi]`, min ≤ max.
fn latency_range(c: &Check, field: &str, v: &[f64; 2], hi: f64) -> Result<(), FieldError> {
    c.all_finite(field, v, 0.0, hi)?;
    if v[1] < v[0] {
        return Err(c.fail(
            field,
            format!("max {} is below min {}", v[1], v[0]),
            "give [min, max] with min ≤ max",
        ));
    }
    Ok(())
}

/// Everything the simulator needs besides the scenario, seed and duration.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    pub imu: ImuConfig,
    /// IMU sample rate (Hz).
    pub imu_rate_hz: f64,
    /// One-sigma spread of the true initial accelerometer bias (m/s²).
    pub accel_bias0_sigma: f64,
    /// One-sigma spread of the true initial gyroscope bias (rad/s).
    pub gyro_bias0_sigma: f64,
    pub camera: CameraConfig,
    /// Delivery delay of a frame after its exposure, drawn uniformly per
    /// frame from `[min, max]` (s, IMU clock): a real camera reads out,
    /// transfers and the front end tracks before the features arrive.
    pub camera_latency_s: [f64; 2],
    /// True camera–IMU clock offset `t_d` (s), unknown to the filter, with
    /// OpenVINS's convention `t_imu = t_cam + t_d`: a frame exposed at IMU
    /// time `t` is stamped `t − t_d` by the camera's clock.
    pub camera_time_offset_s: f64,
    pub features: FeatureSimConfig,
    pub gnss: GnssSimConfig,
    /// Time at rest on the ground, level at the origin, before an analytic
    /// scenario (racetrack, figure8, hover) takes off smoothly (s): a real
    /// flight starts on the ground, where the filter initialises. 0 gives the
    /// historical scenarios exactly (racetrack and figure8 airborne from
    /// t = 0, hover with its 4 s wait). TUM trajectories ignore it.
    pub standstill_s: f64,
    /// The mock autopilot's own estimate (`serve`): its errors.
    pub autopilot: AutopilotSimConfig,
    /// Gusts in the air (`crate::trajectory::wind`).
    pub wind: WindConfig,
    /// Motor vibration on the IMU (`crate::imu`): by default an armed
    /// multirotor's (`VibrationConfig::armed_multirotor()`); `[vibration]`
    /// with empty line lists gives none.
    pub vibration: VibrationConfig,
    /// The rendered camera (`crate::render`, `demo --frontend`).
    pub render: crate::render::RenderConfig,
    /// How the camera's true lens differs from `camera`, its calibration
    /// (`crate::lens`): drawn per flight, rendered and projected through;
    /// the daemon is given `camera`.
    pub lens: crate::lens::LensErrorConfig,
}

impl SimConfig {
    pub fn new() -> Self {
        Self {
            imu_rate_hz: 200.0,
            accel_bias0_sigma: 0.02,
            gyro_bias0_sigma: 0.08,
            camera_latency_s: [0.03, 0.06],
            camera_time_offset_s: 0.012,
            standstill_s: 5.0,
            vibration: crate::imu::VibrationConfig::armed_multirotor(),
            ..Default::default()
        }
    }

    /// Parses TOML over [`Self::new`]'s defaults, rejecting unknown keys,
    /// and validates every value.
    pub fn from_toml(text: &str) -> Result<Self, String> {
        Self::from_toml_onto(&Self::new(), text)
    }

    /// Parses TOML over `base`: what the text names replaces base's, the
    /// rest stays base's (a table's keys one by one). Rejects unknown keys
    /// and validates every value.
    pub fn from_toml_onto(base: &Self, text: &str) -> Result<Self, String> {
        let mut base: toml::Value = toml::Value::try_from(base).map_err(|e| e.to_string())?;
        let over: toml::Value = toml::from_str(text).map_err(|e| e.to_string())?;
        merge(&mut base, over);
        let cfg: Self = base.try_into().map_err(|e: toml::de::Error| e.to_string())?;
        cfg.validate("").map_err(|e| e.to_string())?;
        Ok(cfg)
    }
}

fn merge(base: &mut toml::Value, over: toml::Value) {
    match (base, over) {
        (toml::Value::Table(b), toml::Value::Table(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(bv) => merge(bv, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (b, o) => *b = o,
    }
}

impl Validate for SimConfig {
    fn validate(&self, prefix: &str) -> Result<(), FieldError> {
        let p = |s: &str| {
            if prefix.is_empty() {
                s.to_string()
            } else {
                format!("{prefix}.{s}")
            }
        };
        let c = Check::new(prefix);
        self.imu.validate(&p("imu"))?;
        c.positive("imu_rate_hz", self.imu_rate_hz, 4000.0)?;
        c.range("accel_bias0_sigma", self.accel_bias0_sigma, 0.0, 10.0)?;
        c.range("gyro_bias0_sigma", self.gyro_bias0_sigma, 0.0, 1.0)?;
        self.camera.validate(&p("camera"))?;
        latency_range(&c, "camera_latency_s", &self.camera_latency_s, 1.0)?;
        c.range("camera_time_offset_s", self.camera_time_offset_s, -0.1, 0.1)?;
        c.range("standstill_s", self.standstill_s, 0.0, 600.0)?;
        self.features.validate(&p("features"))?;
        self.gnss.validate(&p("gnss"))?;
        self.autopilot.validate(&p("autopilot"))?;
        self.wind.validate(&p("wind"))?;
        self.vibration.validate(&p("vibration"))?;
        self.render.validate(&p("render"))?;
        self.lens.validate(&p("lens"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What a TOML leaves out stays the base's: an evaluation's camera and
    /// IMU are its `--config`'s unless its `--sim-config` names them.
    #[test]
    fn toml_onto_a_base_keeps_what_it_does_not_name() {
        let mut base = SimConfig::new();
        base.camera.q_B_C_xyzw = [
            0.3535533905932738,
            0.3535533905932738,
            0.6123724356957945,
            0.6123724356957945,
        ];
        base.imu.accel_noise_density = 0.12;
        let c = SimConfig::from_toml_onto(
            &base,
            "[features]\noutlier_prob = 0.0\n[imu]\ngyro_noise_density = 0.008\n",
        )
        .unwrap();
        assert_eq!(c.camera, base.camera);
        assert_eq!(c.imu.accel_noise_density, 0.12);
        assert_eq!(c.imu.gyro_noise_density, 0.008);
        assert_eq!(c.features.outlier_prob, 0.0);
        let e = SimConfig::from_toml_onto(&base, "[camera]\nrate_hz = -1.0\n").unwrap_err();
        assert!(e.contains("camera.rate_hz"), "{e}");
    }
    use nalgebra::Vector3;

    #[test]
    fn defaults_are_valid() {
        SimConfig::new().validate("").unwrap();
    }

    #[test]
    fn errors_name_the_field() {
        let e = SimConfig::from_toml("[imu]\naccel_noise_density = nan\n").unwrap_err();
        assert!(e.contains("imu.accel_noise_density") && e.contains("finite"), "{e}");
        let e = SimConfig::from_toml("[camera]\npixel_noise_px = -1.0\n").unwrap_err();
        assert!(e.contains("camera.pixel_noise_px"), "{e}");
        let e = SimConfig::from_toml("[features]\nbogus = 1\n").unwrap_err();
        assert!(e.contains("bogus"), "{e}");
        let e = SimConfig::from_toml("imu_rate_hz = inf\n").unwrap_err();
        assert!(e.contains("imu_rate_hz"), "{e}");
        let e = SimConfig::from_toml("[autopilot]\nposition_drift_time_s = 0.0\n").unwrap_err();
        assert!(e.contains("autopilot.position_drift_time_s"), "{e}");
        let e = SimConfig::from_toml("[autopilot]\nyaw_bias_sigma_deg = -1.0\n").unwrap_err();
        assert!(e.contains("autopilot.yaw_bias_sigma_deg"), "{e}");
    }

    #[test]
    fn the_autopilot_is_honest_by_default_and_truthful_on_request() {
        let d = SimConfig::new().autopilot;
        assert!(d.position_drift_sigma_m > 0.0 && d.yaw_bias_sigma_deg > 0.0 && d.follow_vpe);
        AutopilotSimConfig::truth().validate("autopilot").unwrap();
        let c = SimConfig::from_toml("[autopilot]\nyaw_bias_sigma_deg = 0.0\nfollow_vpe = false\n").unwrap();
        assert_eq!(c.autopilot.yaw_bias_sigma_deg, 0.0);
        assert!(!c.autopilot.follow_vpe);
        assert_eq!(c.autopilot.position_drift_sigma_m, d.position_drift_sigma_m);
    }

    #[test]
    fn timing_lever_arm_and_standstill_knobs() {
        let d = SimConfig::new();
        assert_eq!(d.camera_latency_s, [0.03, 0.06]);
        assert_eq!(d.camera_time_offset_s, 0.012);
        assert_eq!(d.gnss.latency_s, [0.2, 0.6]);
        assert!((Vector3::from(d.gnss.p_A_in_B_m).norm() - 0.15).abs() < 1e-12);
        assert_eq!(d.standstill_s, 5.0);
        let c = SimConfig::from_toml(
            "camera_latency_s = [0.0, 0.1]\ncamera_time_offset_s = -0.05\nstandstill_s = 0.0\n\
             [gnss]\nlatency_s = [0.5, 0.5]\np_A_in_B_m = [0.0, 0.0, -0.3]\n",
        )
        .unwrap();
        assert_eq!(c.camera_latency_s, [0.0, 0.1]);
        assert_eq!(c.camera_time_offset_s, -0.05);
        assert_eq!(c.standstill_s, 0.0);
        assert_eq!(c.gnss.latency_s, [0.5, 0.5]);
        assert_eq!(c.gnss.p_A_in_B_m, [0.0, 0.0, -0.3]);
        for (toml, field) in [
            ("camera_latency_s = [0.06, 0.03]\n", "camera_latency_s"),
            ("camera_latency_s = [0.0, 1.5]\n", "camera_latency_s[1]"),
            ("camera_latency_s = [-0.01, 0.03]\n", "camera_latency_s[0]"),
            ("camera_latency_s = [0.03]\n", "camera_latency_s"),
            ("camera_time_offset_s = 0.2\n", "camera_time_offset_s"),
            ("camera_time_offset_s = nan\n", "camera_time_offset_s"),
            ("standstill_s = -1.0\n", "standstill_s"),
            ("[gnss]\nlatency_s = [0.6, 0.2]\n", "gnss.latency_s"),
            ("[gnss]\nlatency_s = [0.2, inf]\n", "gnss.latency_s[1]"),
            ("[gnss]\np_A_in_B_m = [0.0, nan, 0.0]\n", "gnss.p_A_in_B_m[1]"),
        ] {
            let e = SimConfig::from_toml(toml).unwrap_err();
            assert!(e.contains(field), "{toml}: {e}");
        }
    }
}
