//! The estimator: an MSCKF with keyframes, in four modes (`msckf`, `full`,
//! `schmidt`, `compressed`).
//!
//! It is pure: no I/O, no tokio, no wall clock. Every timestamp is passed in,
//! and every equation is derived in `src/estimator/README.md` (cited as §n).
//!
//! This file is the public face and the state. The rest, by concern:
//! - `covariance.rs`: the one place that changes `P` (layout, propagation
//!   step, cloning, marginalisation, the EKF update, injection);
//! - `propagate.rs`: IMU kinematics and the filter's propagation;
//! - `msckf.rs`: the track update of each camera frame;
//! - `keyframes.rs`: the keyframe life cycle;
//! - `compressed/`: the local/global split, rebases and promotions;
//! - `gnss_model.rs`, `gnss_update.rs`: what a satellite measures (with the
//!   antenna's lever arm), and the GNSS update that fuses an epoch, late ones
//!   through their clones; `range_bias.rs`: the single-point codes' errors
//!   that hold for the flight, as states;
//! - `health.rs`: divergence detection and state checks;
//! - `feature.rs`, `math/`, `frontend.rs`, `settings.rs`: triangulation and
//!   the track Jacobians, dense kernels, pixel normalisation, settings.
//!
//! Error-state layout of the covariance `P` (the *local* part in compressed
//! mode): `[IMU (15), clock (5), t_d | local keyframes (6 each) | clones (6
//! each) | GNSS clones (17 each) | range-bias block]`. Each
//! pose block is `[δθ, δp]`. In `compressed` mode the global keyframes live in
//! [`Global`]: `P_LG(0)`, `P_GG(0)` frozen at the last global update plus the
//! accumulated `Φ`, `Ψ` and `q` (§5).

pub mod barometer;
pub mod compressed;
mod covariance;
pub mod feature;
pub mod frontend;
pub mod gnss_model;
pub mod gnss_update;
mod heading;
pub mod health;
pub mod imu_covariance;
mod inspect;
mod keyframes;
pub mod landed;
mod landmarks;
pub mod math;
mod msckf;
pub mod propagate;
mod range_bias;
pub mod settings;
mod snapshot;
mod vibration;
mod zupt;

use crate::counters::Counter;
use std::collections::{BTreeMap, BTreeSet, VecDeque};

pub use barometer::BaroOutcome;
use compressed::Global;
pub use compressed::{InstallError, RebaseJob, RebaseResult};

use cmsckf_models::geodesy::NedFrame;
use cmsckf_models::gnss::{SatMeas, System};
use nalgebra::{DMatrix, Matrix6, UnitQuaternion, Vector3};

use covariance::position_sigma_m;
pub use feature::Reject;
pub use frontend::NormObs;
pub use gnss_update::{GnssReport, GNSS_CLONE_DIM};
pub use heading::YawConditionError;
pub use inspect::SchmidtDowndate;
use math::exp_so3;
pub use propagate::{ImuMeas, ImuState, Mat15, IMU_DIM};
pub use range_bias::RangeBiasEstimate;
pub use settings::{BaroSettings, Mode, Settings, ZuptSettings};
pub use snapshot::Snapshot;

/// The constellations with an inter-system bias state, in state order:
/// each one's own clock bias is GPS's plus its ISB (QZSS runs on GPS's
/// clock and has none).
pub const ISB_SYSTEMS: [System; 3] = [System::Galileo, System::Glonass, System::BeiDou];
/// The receiver clock `[c·δt_G (m), c·δṫ (m/s), isb_E, isb_R, isb_C (m)]`:
/// GPS's bias, the common drift, and the inter-system biases
/// `c·(δt_X − δt_G)` of [`ISB_SYSTEMS`] (§8, eq. K1).
pub const CLOCK_DIM: usize = 2 + ISB_SYSTEMS.len();
/// A receiver clock state (see [`CLOCK_DIM`]).
pub type ClockVec = nalgebra::SVector<f64, CLOCK_DIM>;
/// Active (always-local) states: the IMU, then the GNSS receiver clock
/// ([`CLOCK_DIM`]), then the camera–IMU time offset `t_d` (s,
/// `t_imu = t_cam + t_d`, §3b), then the barometer's offset `b_h` (m,
/// §3g).
pub const ACTIVE_DIM: usize = IMU_DIM + CLOCK_DIM + 2;
/// Offsets of the clock bias, drift and the first inter-system bias
/// (Galileo's; the others follow in [`ISB_SYSTEMS`] order).
pub const CLK_B: usize = IMU_DIM;
pub const CLK_D: usize = IMU_DIM + 1;
pub const CLK_E: usize = IMU_DIM + 2;
/// Offset of the camera–IMU time offset.
pub const TD: usize = IMU_DIM + CLOCK_DIM;
/// Offset of the barometer's offset `b_h` (§3g).
pub const BARO: usize = TD + 1;

/// The inter-system-bias slot of a constellation (its index in
/// [`ISB_SYSTEMS`]); `None` for GPS and QZSS, which use GPS's bias.
pub fn isb_slot(system: System) -> Option<usize> {
    ISB_SYSTEMS.iter().position(|&s| s == system)
}
/// The active block's transition.
pub type MatActive = nalgebra::SMatrix<f64, ACTIVE_DIM, ACTIVE_DIM>;
use propagate::{P as P_OFF, TH};

/// The body pose `[δθ, δp]` within the IMU error state (what a clone or a
/// keyframe copies).
const POSE_IDX: [usize; 6] = [TH, TH + 1, TH + 2, P_OFF, P_OFF + 1, P_OFF + 2];

/// State sanity bounds of [`Estimator::check_health`]: speed (m/s) and IMU
/// biases (m/s², rad/s), far outside any multirotor's envelope or any
/// working MEMS IMU.
const MAX_SPEED_MPS: f64 = 100.0;
const MAX_ACCEL_BIAS_MPS2: f64 = 2.0;
const MAX_GYRO_BIAS_RADPS: f64 = 0.5;

/// A code residual this many sigmas from its constellation's median is an
/// outlier (§8 K5).
const OUTLIER_SIGMAS: f64 = 5.0;

/// Most global keyframes promoted in one frame while a rebase is out (§5
/// R5); the observations of the others wait for a later track, and
/// compressed then departs from full. With one, a frame of the armed IMU's
/// racetrack that needed two deferred one observation, and the asynchronous
/// filter ended 0.17 σ from full; four leave none waiting there.
const PENDING_PROMOTIONS_PER_FRAME: usize = 4;

/// Most keyframe observations one track uses (§4).
const MAX_KEYFRAMES_PER_TRACK: usize = 8;

/// Bound on buffered, not yet integrated IMU samples.
const IMU_BUFFER_CAP: usize = 4096;

/// Gyro samples kept for the time offset's column (§3b, T3): 0.5 s at
/// 1 kHz, more than the smoothing window at any IMU rate.
const RATE_HISTORY_CAP: usize = 512;

/// Half-width of the triangular window that smooths the body rate for the
/// time offset's column (s, §3b, T3): its response `sinc²(f W)` keeps 97 %
/// of a 2 Hz gust's rate and passes 0.6 % of a 37 Hz motor line.
const RATE_SMOOTHING_HALF_WIDTH_S: f64 = 0.05;

/// Rejected inputs.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InputError {
    #[error("non-finite IMU sample at t = {0} s")]
    NonFiniteImu(f64),
    #[error("IMU time {t_s} s is not after the previous {prev_s} s")]
    ImuTimeBackwards { t_s: f64, prev_s: f64 },
    #[error("frame time {t_s} s is before the filter time {filter_s} s")]
    FrameTimeBackwards { t_s: f64, filter_s: f64 },
    #[error("IMU buffer full ({0} samples); oldest dropped")]
    ImuOverflow(usize),
    #[error("non-finite barometer height {h_m} m at t = {t_s} s")]
    NonFiniteBaro { t_s: f64, h_m: f64 },
    #[error("barometer reading at {t_s} s is {late_s:.3} s behind the filter (at most {max_s} s)")]
    BaroLate { t_s: f64, late_s: f64, max_s: f64 },
    #[error("GNSS epoch at {t_s} s is {late_s:.3} s behind the filter: past the {max_s} s it may be late, or no clone was taken at its instant")]
    GnssLate { t_s: f64, late_s: f64, max_s: f64 },
}

/// A sliding-window clone of the body pose.
#[derive(Clone, Copy, Debug)]
struct CloneState {
    seq: u64,
    q_W_B: UnitQuaternion<f64>,
    p_B_in_W: Vector3<f64>,
    /// First estimate of the position (§3d): its value when cloned, before
    /// any update; the camera Jacobians are taken there.
    p_fej_in_W: Vector3<f64>,
}

/// A stochastic clone for a GNSS epoch (§8b): the states its measurements
/// involve, taken at the instant the receiver's next epoch is expected and
/// kept until the epoch arrives (or `gnss_max_delay_s` has passed), so a
/// late epoch is fused at its own time, exactly.
#[derive(Clone, Copy, Debug)]
struct GnssClone {
    t_s: f64,
    nom: gnss_model::GnssNominal,
    /// The IMU measurement at the instant (to shift to the epoch's own time).
    meas: ImuMeas,
}

/// Where GNSS epochs are expected: every `period_s` after the last one.
#[derive(Clone, Copy, Debug)]
struct GnssGrid {
    last_epoch_s: f64,
    period_s: f64,
    /// Whether `period_s` was measured from two epochs (else the setting).
    measured: bool,
    /// Spacings in a row longer than half again `period_s`, and the
    /// shortest of them: enough of them and the period is theirs (a stray
    /// early epoch, or a receiver that slowed down).
    longer: u32,
    longer_min_s: f64,
    /// The next instant to clone at.
    next_s: f64,
}

/// IMU stillness since the last frame (§3c): the sums that give the mean
/// and the scatter of the body rate and of the specific force's departure
/// from gravity's, both with the current bias estimates removed. A still
/// vehicle's means are small whatever its motors make the samples do
/// (vibration is zero-mean); its scatter says how far the means may be off
/// from noise and vibration alone.
#[derive(Clone, Copy, Debug, Default)]
struct Stillness {
    samples: u32,
    /// `Σ (ω_m − b̂_g)` (rad/s) and `Σ |ω_m − b̂_g|²` (rad²/s²).
    gyro_sum_radps: Vector3<f64>,
    gyro_sq_sum: f64,
    /// `Σ (a_m − b̂_a + R̂_W_Bᵀ g_W)` (m/s²) and the sum of its squares.
    accel_dev_sum_mps2: Vector3<f64>,
    accel_dev_sq_sum: f64,
    /// `∫ ω_m dt` and the time it spans (s): the mean rate, which at rest
    /// is the gyro bias.
    gyro_integral_rad: Vector3<f64>,
    span_s: f64,
}

/// A keyframe observation of a landmark.
#[derive(Clone, Copy, Debug)]
struct KfObs {
    obs: NormObs,
    /// Set once the landmark has left view after the keyframe: only then can
    /// a later track use it (a revisit), and it is used at most once (§4).
    eligible: bool,
}

/// A keyframe: the body pose at its creation, held in a chart
/// `R = Exp(δ) R₀` so that its corrections add (§4).
#[derive(Clone, Debug)]
pub struct Keyframe {
    pub id: u64,
    pub t_s: f64,
    q0_W_B: UnitQuaternion<f64>,
    delta: Vector3<f64>,
    pub p_B_in_W: Vector3<f64>,
    /// First estimate of the position (§3d), as for clones.
    p_fej_in_W: Vector3<f64>,
    obs: BTreeMap<u64, KfObs>,
    /// When a measurement last involved it (its creation at first): the
    /// least recently used leave the local part first.
    last_used_s: f64,
}

impl Keyframe {
    pub fn q_W_B(&self) -> UnitQuaternion<f64> {
        exp_so3(&self.delta) * self.q0_W_B
    }
}

/// Counters since start.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Stats {
    pub imu_samples: u64,
    pub frames: u64,
    pub tracks_used: u64,
    pub rejected: BTreeMap<Counter, u64>,
    pub updates: u64,
    pub loop_closure_updates: u64,
    pub global_updates: u64,
    /// Rebase results installed (equal to `global_updates` once none is
    /// pending).
    pub rebases_installed: u64,
    /// Of those, installs whose base space shrank to the global part's
    /// columns (§5 R6), and the base coordinates that removed in all.
    pub base_space_reductions: u64,
    pub base_space_dims_removed: u64,
    /// Global keyframes brought into the local part for a measurement.
    pub promotions: u64,
    /// Of those, promoted while a rebase job was out (§5 R5).
    pub promotions_while_pending: u64,
    /// Keyframe observations left for later because their keyframe was in a
    /// global part still being computed.
    pub loop_closure_deferred: u64,
    pub keyframes_created: u64,
    pub keyframes_marginalised: u64,
    /// Barometer readings fused (§3g).
    pub baro_updates: u64,
    /// GNSS epochs fused (on time or through their clone).
    pub gnss_epochs_fused: u64,
    /// Of those, fused at their own time through a clone (late arrivals).
    pub gnss_epochs_fused_late: u64,
    /// GNSS epochs refused as later than `gnss_max_delay_s` (or with no
    /// clone at their instant).
    pub gnss_epochs_late: u64,
    /// Range-bias states created for satellites, and dropped after their
    /// satellite went unused for `range_bias_timeout_s` (§8c, DG5′).
    #[serde(default)]
    pub range_bias_states_created: u64,
    #[serde(default)]
    pub range_bias_states_dropped: u64,
    /// Frames taken as zero-velocity updates instead of clones (§3c).
    pub zupt_updates: u64,
    /// Frames, while zero-velocity updates were allowed, whose features had
    /// moved in the image past `zupt.max_disparity_px` since the last clone:
    /// the camera saw motion, whatever the IMU said (§3c).
    pub zupt_camera_moved: u64,
    /// Tracks used at their landmark's remembered depth for want of
    /// parallax (§3e).
    pub low_parallax_tracks: u64,
    /// The vibration's attitude jitter at the last view (rad, RMS per axis,
    /// §3f eq. V1); 0 before one is measured.
    #[serde(default)]
    pub vibration_jitter_rad: f64,
}

/// Why a global update happened.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GlobalReason {
    /// The vehicle left the local region.
    LeftLocalRegion,
    /// The local part holds more than `max_local_keyframes`.
    LocalPartFull,
    /// Asked for (shutdown, log).
    Forced,
}

/// Filter events of one frame, in the order they happened.
#[derive(Clone, Debug, PartialEq)]
pub enum FilterEvent {
    GlobalUpdate {
        reason: GlobalReason,
        /// Keyframes in the global part before the update.
        global_before: Vec<u64>,
        /// Keyframes local after the re-partition.
        local_after: Vec<u64>,
    },
    KeyframeCreated {
        id: u64,
    },
    /// Global keyframes a measurement needs became local (§5 P1–P3).
    Promoted {
        keyframes: Vec<u64>,
    },
    Update {
        tracks: usize,
        /// Keyframes whose poses the update involved.
        keyframes: Vec<u64>,
    },
}

/// What one camera frame did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameReport {
    pub events: Vec<FilterEvent>,
    pub tracks_used: usize,
    pub rejected: BTreeMap<Reject, u64>,
    /// NIS of each accepted track with its degrees of freedom.
    pub nis: Vec<(f64, usize)>,
    pub residual_rms: f64,
    pub keyframe_created: bool,
    pub global_updates: usize,
    pub loop_closure_tracks: usize,
    /// Of the tracks used, those with too little parallax to triangulate,
    /// used at their landmark's remembered depth (§3e).
    pub low_parallax_tracks: usize,
    /// Keyframe observations left for a later track: their keyframe is in
    /// a global part that a rebase is still computing (§5 R5).
    pub deferred: usize,
    /// Global keyframes made local for this frame's measurements.
    pub promoted: usize,
    /// The triangulated position of each accepted track's landmark (m,
    /// world NED), for the log's 3D view.
    pub landmarks_W: Vec<Vector3<f64>>,
    /// The frame was taken as a zero-velocity update (§3c), not a clone.
    pub zupt: bool,
    /// The camera saw the vehicle move: the frame's features moved past
    /// `zupt.max_disparity_px` since their last clone (as §3c's Z0
    /// measures it: a small turn mostly taken out), judged while
    /// zero-velocity updates are enabled and allowed (§3c; `Stats::zupt_camera_moved`
    /// counts these). A take-off's zero-velocity grace ends on it
    /// (`daemon::autopilot`).
    pub camera_moved: bool,
}

/// A landmark's observations in the window.
#[derive(Clone, Debug, Default)]
struct Track {
    obs: Vec<(u64, NormObs)>,
}

/// The filter.
#[derive(Clone, Debug)]
pub struct Estimator {
    s: Settings,
    /// Whether the vehicle may be still (see [`Estimator::set_zupt_allowed`]).
    zupt_allowed: bool,
    /// The frame's feature displacements, as seen and derotated, for their
    /// medians (zero-velocity updates, §3c Z0), kept so that a frame
    /// allocates nothing for them.
    disparity_buf: (Vec<f64>, Vec<f64>),
    /// The buffers a track's gate works in, kept for the same reason.
    gate_scratch: math::Scratch<msckf::GateScratch>,
    /// The frame's landmark ids, its ready tracks and the track lists
    /// that ended, kept for the same reason (`msckf::FrameScratch`).
    frame_scratch: math::Scratch<msckf::FrameScratch>,
    g_W: Vector3<f64>,
    t_s: f64,
    imu: ImuState,
    last_meas: Option<ImuMeas>,
    imu_buf: VecDeque<ImuMeas>,
    /// Transition accumulated since the cross-covariances were last synced.
    f_acc: MatActive,
    P: DMatrix<f64>,
    /// Receiver clock (see [`CLOCK_DIM`]); set from the first GNSS epoch,
    /// each inter-system bias from the first epoch of its constellation (§8).
    clock: ClockVec,
    clock_initialised: bool,
    isb_initialised: [bool; ISB_SYSTEMS.len()],
    /// Whether the last fused epoch's codes were differential (§8c).
    gnss_differential: bool,
    /// The base station and epoch (time of week, s) of the last
    /// differential epoch's corrections: a new epoch moves their common part
    /// (§8c, DG8), a new station sets it anew (DG4).
    gnss_base: Option<(u16, f64)>,
    clones: VecDeque<CloneState>,
    next_seq: u64,
    keyframes: BTreeMap<u64, Keyframe>,
    /// Keyframes in `P`, in order.
    local_kfs: Vec<u64>,
    global: Option<Global>,
    /// The rebase being computed.
    pending: Option<compressed::PendingRebase>,
    rebase_seq: u64,
    /// Runs the rebase jobs of a synchronous filter ([`RebaseJob::run`];
    /// the evaluation wraps it to time them).
    rebase_runner: fn(&RebaseJob) -> RebaseResult,
    /// The Schmidt update's downdate `P += α AᵀA` outside the keyframe
    /// block ([`math::add_gram_outside_block`]; see
    /// [`Estimator::set_schmidt_downdate`]).
    schmidt_downdate: SchmidtDowndate,
    centre_W: Vector3<f64>,
    tracks: BTreeMap<u64, Track>,
    /// Each landmark's last triangulated position (m, world) and when (s):
    /// where a track of it with too little parallax is linearised (§3e).
    landmark_memory: landmarks::LandmarkMemory,
    /// When the memory last forgot its old landmarks (s).
    landmarks_forgotten_s: f64,
    /// This frame's low-parallax tracks' NIS and dof, kept apart from the
    /// monitor's (§3e); a buffer kept between frames.
    low_parallax_nis: Vec<(f64, usize)>,
    /// Landmark → keyframes holding an observation of it.
    kf_by_landmark: BTreeMap<u64, BTreeSet<u64>>,
    /// Landmarks seen at a recent keyframe that have not yet left view.
    pending_eligible: BTreeSet<u64>,
    next_kf_id: u64,
    last_kf_t_s: f64,
    /// Camera–IMU time offset `t_d` (s), the nominal of state [`TD`].
    t_d_s: f64,
    /// The barometer's offset, the nominal of state [`BARO`], and what
    /// its gate has said (§3g).
    baro: barometer::BaroOffset,
    /// Corrections to the velocity and position since the last IMU step:
    /// the next step's transition is taken from the first estimates, the
    /// values before them (§3d, eq. F5).
    fej_dv: Vector3<f64>,
    fej_dp: Vector3<f64>,
    /// GNSS clones waiting for their epochs, oldest first; their blocks
    /// sit after the camera clones, `GNSS_CLONE_DIM` each.
    gnss_clones: VecDeque<GnssClone>,
    /// The single-point codes' persistent errors as states, after the GNSS
    /// clones (§8c, DG5′).
    range_bias: range_bias::RangeBiasBlock,
    gnss_grid: Option<GnssGrid>,
    still: Stillness,
    /// The body rate at the last frame, smoothed (T3), its bias removed
    /// (rad/s).
    frame_rate_B: Option<Vector3<f64>>,
    /// The latest gyro samples `(t_s, ω_m)`, queued or propagated, at most
    /// [`RATE_HISTORY_CAP`].
    rate_history: VecDeque<(f64, Vector3<f64>)>,
    /// Time the filter started (the monitor's grace period runs from it).
    t_start_s: f64,
    /// The end of the last IMU gap of [`propagate::GAP_GRACE_MIN_S`] or
    /// more: the monitor's vision checks wait their grace from it (§2, N3).
    vision_grace_from_s: f64,
    /// Time of the last IMU sample stepped through (not an interpolated
    /// one): the spacing of the samples tells an IMU gap (§2, eq. N3).
    last_sample_t_s: f64,
    pub stats: Stats,
    /// Divergence detection from the innovations (§9).
    pub monitor: health::NisMonitor,
}

impl Estimator {
    /// Starts the filter at `t_s` from a state and its 15×15 covariance.
    pub fn new(s: Settings, t_s: f64, imu: ImuState, P_imu: &Mat15) -> Self {
        let mut P = DMatrix::zeros(ACTIVE_DIM, ACTIVE_DIM);
        P.view_mut((0, 0), (IMU_DIM, IMU_DIM)).copy_from(P_imu);
        // The clock is unknown until the first GNSS epoch sets it.
        P[(CLK_B, CLK_B)] = 1.0;
        P[(CLK_D, CLK_D)] = 1.0;
        for k in 0..ISB_SYSTEMS.len() {
            P[(CLK_E + k, CLK_E + k)] = 1.0;
        }
        P[(TD, TD)] = s.time_offset_sigma_s.powi(2).max(1e-12);
        // Unknown until the first reading sets it (§3g, eq. B2).
        P[(BARO, BARO)] = 1.0;
        Self {
            t_d_s: s.time_offset_s,
            baro: barometer::BaroOffset::default(),
            fej_dv: Vector3::zeros(),
            fej_dp: Vector3::zeros(),
            gnss_clones: VecDeque::new(),
            range_bias: range_bias::RangeBiasBlock::default(),
            gnss_grid: None,
            still: Stillness::default(),
            frame_rate_B: None,
            rate_history: VecDeque::with_capacity(RATE_HISTORY_CAP),
            t_start_s: t_s,
            vision_grace_from_s: f64::NEG_INFINITY,
            last_sample_t_s: t_s,
            clock: ClockVec::zeros(),
            clock_initialised: false,
            gnss_differential: false,
            gnss_base: None,
            isb_initialised: [false; ISB_SYSTEMS.len()],
            g_W: Vector3::new(0.0, 0.0, s.imu.gravity_mps2),
            t_s,
            centre_W: imu.p_B_in_W,
            imu,
            last_meas: None,
            imu_buf: VecDeque::with_capacity(IMU_BUFFER_CAP),
            f_acc: MatActive::identity(),
            P,
            clones: VecDeque::with_capacity(s.max_clones + 2),
            next_seq: 0,
            keyframes: BTreeMap::new(),
            local_kfs: Vec::new(),
            global: None,
            pending: None,
            rebase_seq: 0,
            rebase_runner: RebaseJob::run,
            schmidt_downdate: math::add_gram_outside_block,
            tracks: BTreeMap::new(),
            landmark_memory: landmarks::LandmarkMemory::default(),
            landmarks_forgotten_s: t_s,
            low_parallax_nis: Vec::new(),
            kf_by_landmark: BTreeMap::new(),
            pending_eligible: BTreeSet::new(),
            next_kf_id: 0,
            last_kf_t_s: f64::NEG_INFINITY,
            stats: Stats::default(),
            zupt_allowed: true,
            disparity_buf: (Vec::new(), Vec::new()),
            gate_scratch: math::Scratch::default(),
            frame_scratch: math::Scratch::default(),
            monitor: health::NisMonitor::new(health::MonitorSettings::default()),
            s,
        }
    }

    pub fn mode(&self) -> Mode {
        self.s.mode
    }
    pub fn time_s(&self) -> f64 {
        self.t_s
    }
    // The filter's interface, in one place: each entry point below is done
    // by the file of its concern (named beside it), whose doc gives the
    // details and the equations.

    /// Queues an IMU sample (rejecting a non-finite or non-increasing one);
    /// it is integrated when a measurement or a prediction needs it
    /// (`propagate.rs`, §2).
    pub fn add_imu(&mut self, m: ImuMeas) -> Result<(), InputError> {
        self.queue_imu(m)
    }

    /// Brings the filter to `t_s` through the queued IMU samples, cloning
    /// the states GNSS epochs will need (`propagate.rs`, §2, §8b).
    pub fn propagate_to(&mut self, t_s: f64) {
        self.propagate_filter_to(t_s)
    }

    /// The body state predicted to `t_s` through the queued IMU samples,
    /// without changing the filter: the low-latency output
    /// (`propagate.rs`).
    pub fn predict(&self, t_s: f64) -> ImuState {
        self.predict_imu_state(t_s)
    }

    /// One camera frame stamped `t_cam_s` by the camera's clock: the
    /// tracks it ends, the keyframes and loop closures (`msckf.rs`, §3–§5).
    pub fn process_frame(&mut self, t_cam_s: f64, obs: &[NormObs]) -> Result<FrameReport, InputError> {
        self.update_with_frame(t_cam_s, obs)
    }

    /// One GNSS epoch at `t_s` in the world frame `frame` (`gnss_update.rs`,
    /// §8).
    pub fn process_gnss(&mut self, t_s: f64, frame: &NedFrame, sats: &[SatMeas]) -> Result<GnssReport, InputError> {
        self.update_with_gnss(t_s, frame, sats)
    }

    /// One barometer reading: the height `h_m` (m, up, the standard
    /// atmosphere's) at `t_s` (`barometer.rs`, §3g).
    pub fn process_baro(&mut self, t_s: f64, h_m: f64) -> Result<BaroOutcome, InputError> {
        self.update_with_baro(t_s, h_m)
    }

    /// Whether zero-velocity updates may be taken now: on the ground only
    /// (`zupt.rs`, §3c).
    pub fn set_zupt_allowed(&mut self, allowed: bool) {
        self.allow_zupt(allowed)
    }

    /// What the caller last said of zero-velocity updates
    /// ([`Self::set_zupt_allowed`]; allowed until it says).
    pub fn zupt_allowed(&self) -> bool {
        self.zupt_allowed
    }

    /// The filter's judgement of itself: covariance, state bounds and the
    /// innovations' monitor (`health.rs`, §9); `Err` says why it failed.
    pub fn check_health(&self) -> Result<(), String> {
        self.judge_health()
    }

    pub fn imu_state(&self) -> &ImuState {
        &self.imu
    }
    pub fn keyframes(&self) -> impl Iterator<Item = &Keyframe> {
        self.keyframes.values()
    }
    pub fn n_clones(&self) -> usize {
        self.clones.len()
    }
    /// The camera–IMU time offset estimate `t_d` (s, `t_imu = t_cam + t_d`)
    /// and its variance (s²).
    pub fn time_offset(&self) -> (f64, f64) {
        (self.t_d_s, self.P[(TD, TD)])
    }
    /// GNSS clones waiting for their epochs.
    pub fn n_gnss_clones(&self) -> usize {
        self.gnss_clones.len()
    }
    pub fn n_global_keyframes(&self) -> usize {
        self.global.as_ref().map_or(0, |g| g.live.len())
    }
    pub fn local_dim(&self) -> usize {
        self.P.nrows()
    }

    /// Covariance of the body pose `[δθ, δp]` (6×6).
    pub fn pose_covariance(&self) -> Matrix6<f64> {
        Matrix6::from_fn(|i, j| self.P[(POSE_IDX[i], POSE_IDX[j])])
    }

    /// The IMU block of the covariance (15×15).
    pub fn imu_covariance(&self) -> Mat15 {
        self.P.fixed_view::<15, 15>(0, 0).into_owned()
    }

    /// Position σ (m, `√trace`) of each keyframe as the filter holds it:
    /// the live value for local keyframes, and for global ones the value
    /// frozen at the last global update (what the compressed filter stores;
    /// the paper's Figure 1). `(id, σ, is_global)`.
    pub fn keyframe_sigmas(&self) -> Vec<(u64, f64, bool)> {
        let mut v: Vec<(u64, f64, bool)> = self
            .local_kfs
            .iter()
            .enumerate()
            .map(|(j, id)| (*id, position_sigma_m(&self.P, self.kf_offset(j)), false))
            .collect();
        if let Some(g) = &self.global {
            v.extend(g.sigma_m.iter().map(|(id, s)| (*id, *s, true)));
        }
        v.sort_by_key(|x| x.0);
        v
    }

    /// Covariance of a keyframe's pose `[δθ, δp]` (in its chart), if known
    /// without a global update (local keyframes; global ones at the last
    /// global update minus what is accumulated since).
    pub fn keyframe_covariance(&self, id: u64) -> Option<Matrix6<f64>> {
        if let Some(j) = self.local_kfs.iter().position(|&k| k == id) {
            let o = ACTIVE_DIM + 6 * j;
            return Some(self.P.fixed_view::<6, 6>(o, o).into_owned());
        }
        let pgg = self.global_keyframe_covariance(id)?;
        Some(Matrix6::from_fn(|r, c| pgg[(r, c)]))
    }
}

/// Roll and pitch from the mean specific force of a static segment, with a
/// given yaw (§7): at rest `f_B = −R_W_Bᵀ g_W`, so the body's down axis in
/// the world is `R_W_B (−f̂_B)`… solved as the rotation taking `−f̂_B` to
/// the world's down axis, composed with the yaw.
pub fn attitude_from_static(mean_accel_B: &Vector3<f64>, yaw_rad: f64) -> Option<UnitQuaternion<f64>> {
    let n = mean_accel_B.norm();
    if !(n.is_finite() && n > 5.0 && n < 15.0) {
        return None;
    }
    let f = mean_accel_B / n;
    // f_B = R_W_Bᵀ (−g ẑ) / g → in the body, world-down is −f.
    let roll = (-f.y).atan2(-f.z);
    let pitch = f.x.atan2((f.y * f.y + f.z * f.z).sqrt());
    Some(UnitQuaternion::from_euler_angles(roll, pitch, yaw_rad))
}
