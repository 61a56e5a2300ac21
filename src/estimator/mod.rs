//! The estimator: an MSCKF with keyframes, in four modes (`msckf`, `full`,
//! `schmidt`, `compressed`).
//!
//! It is pure: no I/O, no tokio, no wall clock. Every timestamp is passed in,
//! and every equation is derived in `src/estimator/README.md` (cited as §n).
//!
//! Error-state layout of the covariance `P` (the *local* part in compressed
//! mode): `[IMU (15) | local keyframes (6 each) | clones (6 each)]`. Each
//! pose block is `[δθ, δp]`. In `compressed` mode the global keyframes live in
//! [`Global`]: `P_LG(0)`, `P_GG(0)` frozen at the last global update plus the
//! accumulated `Φ`, `Ψ` and `q` (§5).

pub mod compressed;
pub mod feature;
pub mod frontend;
pub mod gnss_update;
pub mod health;
pub mod math;
pub mod propagate;

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use compressed::Global;
pub use compressed::{InstallError, RebaseJob, RebaseResult};

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, UnitQuaternion, Vector3};

use crate::config::{Config, ImuConfig, Mode};
use feature::{Extrinsic, Obs, Reject, TriangulationLimits, View};
pub use frontend::NormObs;
use math::{exp_so3, left_jacobian};
pub use propagate::{ImuMeas, ImuState, Mat15, IMU_DIM};

/// Active (always-local) states: the IMU, then the GNSS receiver clock
/// `[c·δt_G (m), c·δṫ (m/s), c·(δt_E − δt_G) (m)]`: GPS's bias, the common
/// drift, and Galileo's inter-system bias (so Galileo's own bias is
/// `c·δt_E = c·δt_G + isb`: a bias per constellation and one drift).
pub const ACTIVE_DIM: usize = IMU_DIM + 3;
/// Offsets of the clock bias, drift and Galileo inter-system bias.
pub const CLK_B: usize = IMU_DIM;
pub const CLK_D: usize = IMU_DIM + 1;
pub const CLK_E: usize = IMU_DIM + 2;
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
/// R5); the observations of the others wait for a later track.
const PENDING_PROMOTIONS_PER_FRAME: usize = 1;

/// Most keyframe observations one track uses (§4).
const MAX_KEYFRAMES_PER_TRACK: usize = 8;

/// Bound on buffered, not yet integrated IMU samples.
const IMU_BUFFER_CAP: usize = 4096;

/// Estimator settings taken from the config.
#[derive(Clone, Debug)]
pub struct Settings {
    pub mode: Mode,
    pub max_clones: usize,
    pub min_track_len: usize,
    pub chi2_gate_prob: f64,
    pub tri: TriangulationLimits,
    pub keyframe_interval_s: f64,
    pub keyframe_max: usize,
    pub local_radius_m: f64,
    pub max_local_keyframes: usize,
    pub imu: ImuConfig,
    pub ext: Extrinsic,
    /// Receiver clock bias white-frequency noise (m/√s) and drift random
    /// walk (m/s/√s).
    pub clock_bias_rw: f64,
    pub clock_drift_rw: f64,
    /// Galileo − GPS inter-system bias random walk (m/√s).
    pub isb_rw: f64,
    /// Pseudorange and range-rate sigmas at zenith (m, m/s).
    pub pseudorange_sigma_m: f64,
    pub range_rate_sigma_mps: f64,
    pub elevation_mask_deg: f64,
    /// Compressed mode: rebases are computed by whoever takes the job
    /// ([`Estimator::take_rebase_job`]) instead of at once (§5 R4).
    pub async_rebase: bool,
}

impl Settings {
    pub fn from_config(c: &Config) -> Self {
        let cam = cmsckf_sitl::camera::Camera::from_config(&c.camera);
        Self {
            mode: c.estimator.mode,
            max_clones: c.estimator.max_clones,
            min_track_len: c.estimator.min_track_len,
            chi2_gate_prob: c.estimator.chi2_gate_prob,
            tri: TriangulationLimits {
                min_depth_m: c.estimator.min_depth_m,
                max_depth_m: c.estimator.max_depth_m,
                max_cond: c.estimator.max_triangulation_cond,
            },
            keyframe_interval_s: c.keyframe.interval_s,
            keyframe_max: c.keyframe.max,
            local_radius_m: c.compressed.local_radius_m,
            max_local_keyframes: c.compressed.max_local_keyframes,
            imu: c.imu.clone(),
            clock_bias_rw: c.gnss.clock_bias_rw_m_per_sqrt_s,
            clock_drift_rw: c.gnss.clock_drift_rw_mps_per_sqrt_s,
            isb_rw: c.gnss.isb_rw_m_per_sqrt_s,
            pseudorange_sigma_m: c.gnss.pseudorange_sigma_m,
            range_rate_sigma_mps: c.gnss.range_rate_sigma_mps,
            elevation_mask_deg: c.gnss.elevation_mask_deg,
            async_rebase: false,
            ext: Extrinsic {
                R_B_C: cam.T_B_C.rotation.to_rotation_matrix().into_inner(),
                p_C_in_B: cam.T_B_C.translation.vector,
            },
        }
    }
}

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
}

/// A sliding-window clone of the body pose.
#[derive(Clone, Copy, Debug)]
struct CloneState {
    seq: u64,
    q_W_B: UnitQuaternion<f64>,
    p_B_in_W: Vector3<f64>,
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
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Stats {
    pub imu_samples: u64,
    pub frames: u64,
    pub tracks_used: u64,
    pub rejected: BTreeMap<&'static str, u64>,
    pub updates: u64,
    pub loop_closure_updates: u64,
    pub global_updates: u64,
    /// Rebase results installed (equal to `global_updates` once none is
    /// pending).
    pub rebases_installed: u64,
    /// Global keyframes brought into the local part for a measurement.
    pub promotions: u64,
    /// Of those, promoted while a rebase job was out (§5 R5).
    pub promotions_while_pending: u64,
    /// Keyframe observations left for later because their keyframe was in a
    /// global part still being computed.
    pub loop_closure_deferred: u64,
    pub keyframes_created: u64,
    pub keyframes_marginalised: u64,
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
    pub rejected: BTreeMap<&'static str, u64>,
    /// NIS of each accepted track with its degrees of freedom.
    pub nis: Vec<(f64, usize)>,
    pub residual_rms: f64,
    pub keyframe_created: bool,
    pub global_updates: usize,
    pub loop_closure_tracks: usize,
    /// Keyframe observations left for a later track: their keyframe is in
    /// a global part that a rebase is still computing (§5 R5).
    pub deferred: usize,
    /// Global keyframes made local for this frame's measurements.
    pub promoted: usize,
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
    g_W: Vector3<f64>,
    t_s: f64,
    imu: ImuState,
    last_meas: Option<ImuMeas>,
    imu_buf: VecDeque<ImuMeas>,
    /// Transition accumulated since the cross-covariances were last synced.
    f_acc: MatActive,
    P: DMatrix<f64>,
    /// Receiver clock `[c·δt_G (m), c·δṫ (m/s), isb_E (m)]`; set from the
    /// first GNSS epoch, the inter-system bias from the first Galileo one (§8).
    clock: nalgebra::Vector3<f64>,
    clock_initialised: bool,
    isb_initialised: bool,
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
    centre_W: Vector3<f64>,
    tracks: BTreeMap<u64, Track>,
    /// Landmark → keyframes holding an observation of it.
    kf_by_landmark: BTreeMap<u64, BTreeSet<u64>>,
    /// Landmarks seen at a recent keyframe that have not yet left view.
    pending_eligible: BTreeSet<u64>,
    next_kf_id: u64,
    last_kf_t_s: f64,
    pub stats: Stats,
    /// Divergence detection from the innovations (§9).
    pub monitor: health::NisMonitor,
}

/// The full state in a fixed order (IMU, clones, keyframes by id), for
/// comparing modes: the nominal values and the covariance.
#[derive(Clone, Debug)]
pub struct Snapshot {
    pub x: DVector<f64>,
    pub P: DMatrix<f64>,
}

impl Snapshot {
    /// Largest element-wise difference relative to the largest magnitude,
    /// over state and covariance separately; returns the worse.
    pub fn max_rel_diff(&self, other: &Snapshot) -> f64 {
        if self.x.len() != other.x.len() || self.P.shape() != other.P.shape() {
            return f64::INFINITY;
        }
        let rel = |a: &[f64], b: &[f64]| {
            let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
            a.iter().zip(b).fold(0.0f64, |m, (x, y)| m.max((x - y).abs())) / scale
        };
        // Covariance relative to its largest entry; state per element,
        // relative to max(|x|, 1).
        let xs = self
            .x
            .iter()
            .zip(other.x.iter())
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs() / b.abs().max(1.0)));
        xs.max(rel(self.P.as_slice(), other.P.as_slice()))
    }
}

impl Estimator {
    /// Starts the filter at `t_s` from a state and its 15×15 covariance.
    pub fn new(s: Settings, t_s: f64, imu: ImuState, P_imu: &Mat15) -> Self {
        let mut P = DMatrix::zeros(ACTIVE_DIM, ACTIVE_DIM);
        P.view_mut((0, 0), (IMU_DIM, IMU_DIM)).copy_from(P_imu);
        // The clock is unknown until the first GNSS epoch sets it.
        P[(CLK_B, CLK_B)] = 1.0;
        P[(CLK_D, CLK_D)] = 1.0;
        P[(CLK_E, CLK_E)] = 1.0;
        Self {
            clock: nalgebra::Vector3::zeros(),
            clock_initialised: false,
            isb_initialised: false,
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
            tracks: BTreeMap::new(),
            kf_by_landmark: BTreeMap::new(),
            pending_eligible: BTreeSet::new(),
            next_kf_id: 0,
            last_kf_t_s: f64::NEG_INFINITY,
            stats: Stats::default(),
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
    pub fn imu_state(&self) -> &ImuState {
        &self.imu
    }
    pub fn keyframes(&self) -> impl Iterator<Item = &Keyframe> {
        self.keyframes.values()
    }
    pub fn n_clones(&self) -> usize {
        self.clones.len()
    }
    pub fn n_global_keyframes(&self) -> usize {
        self.global.as_ref().map_or(0, |g| g.live.len())
    }
    pub fn local_dim(&self) -> usize {
        self.P.nrows()
    }

    /// Covariance of the body pose `[δθ, δp]` (6×6).
    pub fn pose_covariance(&self) -> Matrix6<f64> {
        let idx = [0, 1, 2, 6, 7, 8];
        Matrix6::from_fn(|i, j| self.P[(idx[i], idx[j])])
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

    // ----------------------------------------------------------------- IMU

    /// Queues an IMU sample; it is integrated when a frame or a query needs
    /// it. Non-finite or non-increasing samples are rejected.
    pub fn add_imu(&mut self, m: ImuMeas) -> Result<(), InputError> {
        if !(m.t_s.is_finite()
            && m.accel_mps2.iter().all(|v| v.is_finite())
            && m.gyro_radps.iter().all(|v| v.is_finite()))
        {
            *self.stats.rejected.entry("imu_non_finite").or_default() += 1;
            return Err(InputError::NonFiniteImu(m.t_s));
        }
        let prev = self
            .imu_buf
            .back()
            .map(|b| b.t_s)
            .or(self.last_meas.map(|l| l.t_s))
            .unwrap_or(f64::NEG_INFINITY);
        if m.t_s <= prev {
            *self.stats.rejected.entry("imu_time_backwards").or_default() += 1;
            return Err(InputError::ImuTimeBackwards {
                t_s: m.t_s,
                prev_s: prev,
            });
        }
        self.stats.imu_samples += 1;
        if self.last_meas.is_none() {
            // The first sample defines the measurement at the filter time.
            self.last_meas = Some(ImuMeas {
                t_s: self.t_s.min(m.t_s),
                ..m
            });
            if m.t_s <= self.t_s {
                return Ok(());
            }
        }
        let mut res = Ok(());
        if self.imu_buf.len() == IMU_BUFFER_CAP {
            self.imu_buf.pop_front();
            *self.stats.rejected.entry("imu_overflow").or_default() += 1;
            res = Err(InputError::ImuOverflow(IMU_BUFFER_CAP));
        }
        self.imu_buf.push_back(m);
        res
    }

    /// Integrates one step from the last measurement to `m` (§2): the
    /// nominal state, the IMU covariance block and the accumulated
    /// transition. No allocation.
    fn step(&mut self, m: ImuMeas) {
        let Some(m0) = self.last_meas else {
            self.last_meas = Some(m);
            return;
        };
        if m.t_s <= m0.t_s {
            return;
        }
        let (f15, q15) = propagate::transition(&self.imu, &m0, &m, &self.s.imu);
        // The clock: bias integrates drift, both random walks (§8, eq. K1).
        let dt = m.t_s - m0.t_s;
        let mut f = MatActive::identity();
        f.fixed_view_mut::<15, 15>(0, 0).copy_from(&f15);
        f[(CLK_B, CLK_D)] = dt;
        let mut q = MatActive::zeros();
        q.fixed_view_mut::<15, 15>(0, 0).copy_from(&q15);
        let (qb, qd) = (self.s.clock_bias_rw.powi(2), self.s.clock_drift_rw.powi(2));
        q[(CLK_B, CLK_B)] = qb * dt + qd * dt * dt * dt / 3.0;
        q[(CLK_B, CLK_D)] = qd * dt * dt / 2.0;
        q[(CLK_D, CLK_B)] = qd * dt * dt / 2.0;
        q[(CLK_D, CLK_D)] = qd * dt;
        q[(CLK_E, CLK_E)] = self.s.isb_rw.powi(2) * dt;
        self.imu = propagate::integrate(&self.imu, &m0, &m, &self.g_W);
        self.clock.x += self.clock.y * dt;
        let paa = self.P.fixed_view::<ACTIVE_DIM, ACTIVE_DIM>(0, 0).into_owned();
        let mut new = f * paa * f.transpose() + q;
        new = (new + new.transpose()) * 0.5;
        self.P.fixed_view_mut::<ACTIVE_DIM, ACTIVE_DIM>(0, 0).copy_from(&new);
        self.f_acc = f * self.f_acc;
        self.t_s = m.t_s;
        self.last_meas = Some(m);
    }

    /// Propagates the filter to `t_s` through the buffered samples,
    /// interpolating the last one (or holding it if none is later).
    pub fn propagate_to(&mut self, t_s: f64) {
        while let Some(&m) = self.imu_buf.front() {
            if m.t_s > t_s {
                break;
            }
            self.imu_buf.pop_front();
            self.step(m);
        }
        if t_s > self.t_s {
            if let Some(last) = self.last_meas {
                let m = match self.imu_buf.front() {
                    Some(next) => ImuMeas::lerp(&last, next, t_s),
                    None => ImuMeas { t_s, ..last },
                };
                self.step(m);
            } else {
                self.t_s = t_s;
            }
        }
    }

    /// The body state predicted to `t_s` through the buffered IMU samples,
    /// without changing the filter (for low-latency output).
    pub fn predict(&self, t_s: f64) -> ImuState {
        let mut x = self.imu;
        let Some(mut last) = self.last_meas else {
            return x;
        };
        for m in self.imu_buf.iter() {
            let target = if m.t_s > t_s { ImuMeas::lerp(&last, m, t_s) } else { *m };
            if target.t_s > last.t_s {
                x = propagate::integrate(&x, &last, &target, &self.g_W);
            }
            last = target;
            if m.t_s >= t_s {
                return x;
            }
        }
        if t_s > last.t_s {
            x = propagate::integrate(&x, &last, &ImuMeas { t_s, ..last }, &self.g_W);
        }
        x
    }

    /// Applies the accumulated IMU transition to the cross-covariances and
    /// to `Φ` (§2, eq. F4): `P_IX ← F P_IX`, `Φ_I ← F Φ_I`.
    fn sync(&mut self) {
        if self.f_acc == MatActive::identity() {
            return;
        }
        let n = self.P.nrows();
        if n > ACTIVE_DIM {
            let cross = self.f_acc * self.P.view((0, ACTIVE_DIM), (ACTIVE_DIM, n - ACTIVE_DIM));
            self.P
                .view_mut((0, ACTIVE_DIM), (ACTIVE_DIM, n - ACTIVE_DIM))
                .copy_from(&cross);
            self.P
                .view_mut((ACTIVE_DIM, 0), (n - ACTIVE_DIM, ACTIVE_DIM))
                .copy_from(&cross.transpose());
        }
        if let Some(g) = self.global.as_mut() {
            let c = g.Phi.ncols();
            let top = self.f_acc * g.Phi.view((0, 0), (ACTIVE_DIM, c));
            g.Phi.view_mut((0, 0), (ACTIVE_DIM, c)).copy_from(&top);
        }
        self.f_acc = MatActive::identity();
    }

    // ------------------------------------------------------- state layout

    fn kf_offset(&self, local_index: usize) -> usize {
        ACTIVE_DIM + 6 * local_index
    }
    fn clones_offset(&self) -> usize {
        ACTIVE_DIM + 6 * self.local_kfs.len()
    }
    fn clone_offset_by_seq(&self, seq: u64) -> Option<usize> {
        let first = self.clones.front()?.seq;
        let i = seq.checked_sub(first)? as usize;
        (i < self.clones.len()).then(|| self.clones_offset() + 6 * i)
    }

    /// Inserts 6 new error states `J δx` at `at`, a copy of the body pose
    /// (§2, eq. A1): `P' = [P, PJᵀ; JP, JPJᵀ]` (rows and columns placed at
    /// `at`), and `Φ' = [Φ; JΦ]` in compressed mode.
    fn augment(&mut self, at: usize) {
        // J selects the body pose, so J P = P[pose, :] and J P Jᵀ = P[pose, pose]
        // exactly: copies, no products.
        let cross = self.P.select_columns(&POSE_IDX);
        let block = cross.select_rows(&POSE_IDX);
        self.insert_local(at, &cross, &block);
        if let Some(g) = self.global.as_mut() {
            let jphi = g.Phi.select_rows(&POSE_IDX);
            let phi = std::mem::replace(&mut g.Phi, DMatrix::zeros(0, 0)).insert_rows(at, 6, 0.0);
            g.Phi = phi;
            g.Phi.view_mut((at, 0), (6, jphi.ncols())).copy_from(&jphi);
        }
    }

    /// Marginalises 6 error states at `at` (§2, eq. A2).
    fn remove_block(&mut self, at: usize) {
        let p = std::mem::replace(&mut self.P, DMatrix::zeros(0, 0));
        self.P = p.remove_rows(at, 6).remove_columns(at, 6);
        if let Some(g) = self.global.as_mut() {
            let phi = std::mem::replace(&mut g.Phi, DMatrix::zeros(0, 0));
            g.Phi = phi.remove_rows(at, 6);
        }
    }

    // ------------------------------------------------------------ frames

    /// Brings the filter to a measurement at `t_s`, which must not be in
    /// its past (else it is counted under `counter` and refused).
    fn advance_to(&mut self, t_s: f64, counter: &'static str) -> Result<(), InputError> {
        if !t_s.is_finite() || t_s < self.t_s {
            *self.stats.rejected.entry(counter).or_default() += 1;
            return Err(InputError::FrameTimeBackwards {
                t_s,
                filter_s: self.t_s,
            });
        }
        self.propagate_to(t_s);
        self.sync();
        Ok(())
    }

    /// Processes one camera frame at `t_s` (§3–§5). The IMU samples up to
    /// (and preferably just past) `t_s` must have been added.
    pub fn process_frame(&mut self, t_s: f64, obs: &[NormObs]) -> Result<FrameReport, InputError> {
        self.advance_to(t_s, "frame_time_backwards")?;
        self.stats.frames += 1;
        let mut report = FrameReport::default();

        // Compressed: leaving the local region triggers a global update and
        // moves the centre to the vehicle (§5).
        // So does a local part over its keyframe bound. While a rebase is
        // still being computed the next one waits.
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

        let present: BTreeSet<u64> = obs.iter().map(|o| o.landmark_id).collect();

        let make_kf = self.s.mode != Mode::Msckf
            && self.s.keyframe_max > 0
            && t_s - self.last_kf_t_s >= self.s.keyframe_interval_s - 1e-9;
        if make_kf {
            let id = self.create_keyframe(t_s, obs);
            report.events.push(FilterEvent::KeyframeCreated { id });
            report.keyframe_created = true;
        } else {
            // New clone of the current pose, appended after the last clone.
            let at = self.P.nrows();
            self.augment(at);
            let seq = self.next_seq;
            self.next_seq += 1;
            self.clones.push_back(CloneState {
                seq,
                q_W_B: self.imu.q_W_B,
                p_B_in_W: self.imu.p_B_in_W,
            });
            for o in obs {
                self.tracks.entry(o.landmark_id).or_default().obs.push((seq, *o));
            }
        }

        // Tracks to use now: lost ones, and those that would lose their
        // oldest observation when the window slides.
        let oldest = if self.clones.len() > self.s.max_clones {
            self.clones.front().map(|c| c.seq)
        } else {
            None
        };
        let ready: Vec<u64> = self
            .tracks
            .iter()
            .filter(|(l, tr)| !present.contains(l) || oldest.is_some_and(|s| tr.obs.first().is_some_and(|o| o.0 == s)))
            .map(|(l, _)| *l)
            .collect();
        let ready_tracks: Vec<(u64, Track)> = ready
            .iter()
            .filter_map(|l| self.tracks.remove(l).map(|t| (*l, t)))
            .collect();
        self.update_tracks(ready_tracks, &mut report);

        // Keyframe observations become usable once their landmark has left view
        // (after this frame's update, so only a later re-detection uses them).
        let newly: Vec<u64> = self
            .pending_eligible
            .iter()
            .copied()
            .filter(|l| !present.contains(l))
            .collect();
        for l in newly {
            self.pending_eligible.remove(&l);
            if let Some(kfs) = self.kf_by_landmark.get(&l) {
                for k in kfs {
                    if let Some(o) = self.keyframes.get_mut(k).and_then(|kf| kf.obs.get_mut(&l)) {
                        o.eligible = true;
                    }
                }
            }
        }

        if let Some(seq) = oldest {
            // Marginalise the oldest clone; tracks still holding it drop it.
            if let Some(at) = self.clone_offset_by_seq(seq) {
                self.remove_block(at);
            }
            self.clones.pop_front();
            for tr in self.tracks.values_mut() {
                tr.obs.retain(|o| o.0 != seq);
            }
            self.tracks.retain(|_, t| !t.obs.is_empty());
        }
        // Tracks the poses cannot explain: failed the χ² gate, or failed to
        // triangulate to a depth or a fit (§9 D1).
        let inconsistent = [Reject::Chi2, Reject::BadDepth, Reject::NotConverged]
            .iter()
            .filter_map(|r| report.rejected.get(r.name()))
            .sum::<u64>();
        self.monitor.push_frame(t_s, &report.nis, inconsistent);
        Ok(report)
    }

    fn create_keyframe(&mut self, t_s: f64, obs: &[NormObs]) -> u64 {
        if self.keyframes.len() >= self.s.keyframe_max {
            if let Some(&oldest) = self.keyframes.keys().next() {
                self.remove_keyframe(oldest);
            }
        }
        let id = self.next_kf_id;
        self.next_kf_id += 1;
        let at = self.clones_offset();
        self.augment(at);
        self.local_kfs.push(id);
        let mut kobs = BTreeMap::new();
        for o in obs {
            kobs.insert(
                o.landmark_id,
                KfObs {
                    obs: *o,
                    eligible: false,
                },
            );
            self.kf_by_landmark.entry(o.landmark_id).or_default().insert(id);
            self.pending_eligible.insert(o.landmark_id);
        }
        self.keyframes.insert(
            id,
            Keyframe {
                id,
                t_s,
                q0_W_B: self.imu.q_W_B,
                delta: Vector3::zeros(),
                p_B_in_W: self.imu.p_B_in_W,
                obs: kobs,
                last_used_s: t_s,
            },
        );
        self.last_kf_t_s = t_s;
        self.stats.keyframes_created += 1;
        id
    }

    fn remove_keyframe(&mut self, id: u64) {
        if let Some(j) = self.local_kfs.iter().position(|&k| k == id) {
            let at = self.kf_offset(j);
            self.remove_block(at);
            self.local_kfs.remove(j);
        } else if let Some(g) = self.global.as_mut() {
            // Deleting a global state commutes with Ψ and q (§5, eq. G5): its
            // block goes dead and the next rebase drops it.
            g.live.remove(&id);
            g.sigma_m.remove(&id);
        }
        if let Some(kf) = self.keyframes.remove(&id) {
            for l in kf.obs.keys() {
                if let Some(s) = self.kf_by_landmark.get_mut(l) {
                    s.remove(&id);
                    if s.is_empty() {
                        self.kf_by_landmark.remove(l);
                    }
                }
            }
        }
        self.stats.keyframes_marginalised += 1;
    }

    /// Triangulates, projects and gates each track, then applies one stacked
    /// update (§3).
    fn update_tracks(&mut self, ready: Vec<(u64, Track)>, report: &mut FrameReport) {
        let now = self.t_s;
        // Keyframe observations each ready track may use.
        let mut kf_use: Vec<Vec<u64>> = Vec::with_capacity(ready.len());
        for (l, _) in &ready {
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
            // At most MAX_KEYFRAMES_PER_TRACK, spread from the oldest to the
            // newest: dense keyframes add little beyond that, and each one
            // costs a column block (and, if global, a promotion).
            if ks.len() > MAX_KEYFRAMES_PER_TRACK {
                let n = ks.len() - 1;
                ks = (0..MAX_KEYFRAMES_PER_TRACK)
                    .map(|i| ks[i * n / (MAX_KEYFRAMES_PER_TRACK - 1)])
                    .collect();
            }
            kf_use.push(ks);
        }
        // A measurement that touches a global keyframe first makes it local
        // (§5 P1–P3); while a rebase is out (R5), one keyframe per frame.
        if self.s.mode == Mode::Compressed {
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
            if !global_needed.is_empty() {
                // While a rebase is out (§5 R5) the local part cannot shed
                // keyframes, and each one promoted makes every update until
                // the rebase after next dearer: promote at most
                // PENDING_PROMOTIONS_PER_FRAME, those the most observations
                // need, within the local bound; the other observations wait
                // for a later track.
                let mut chosen = global_needed.clone();
                if self.pending.is_some() {
                    let room = (self.s.max_local_keyframes.saturating_sub(self.local_kfs.len()))
                        .min(PENDING_PROMOTIONS_PER_FRAME);
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
        }

        let mut rows: Vec<(DMatrix<f64>, DVector<f64>, Vec<usize>)> = Vec::new();
        let mut involved = BTreeSet::new();
        let gate_reject = |rep: &mut FrameReport, st: &mut Stats, r: Reject| {
            *rep.rejected.entry(r.name()).or_default() += 1;
            *st.rejected.entry(r.name()).or_default() += 1;
        };
        let (mut gate_idx, mut gate_p) = (Vec::new(), DMatrix::zeros(0, 0));
        for ((l, tr), ks) in ready.into_iter().zip(kf_use) {
            // Views: the clones of the track, then its keyframes.
            let mut views = Vec::new();
            let mut cols = Vec::new();
            let mut obs = Vec::new();
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
                    chart: Matrix3::identity(),
                });
                cols.push(off);
            }
            let clone_obs = obs.len();
            for k in &ks {
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
                    chart: left_jacobian(&kf.delta),
                });
                // A keyframe in the state (local), or a Schmidt/full keyframe.
                cols.push(off.unwrap_or(usize::MAX));
            }
            if clone_obs == 0 || obs.len() < self.s.min_track_len || cols.contains(&usize::MAX) {
                gate_reject(report, &mut self.stats, Reject::TooFewObservations);
                continue;
            }
            let p_f = match feature::triangulate(&views, &self.s.ext, &obs, &self.s.tri) {
                Ok(p) => p,
                Err(r) => {
                    gate_reject(report, &mut self.stats, r);
                    continue;
                }
            };
            let (hx_views, hf, r) = feature::track_system(&views, &self.s.ext, &obs, &p_f);
            let (hx, r) = feature::nullspace_project(&hx_views, &hf, &r);
            if !(math::all_finite(hx.as_slice()) && math::all_finite(r.as_slice())) {
                gate_reject(report, &mut self.stats, Reject::NonFinite);
                continue;
            }
            // χ² gate on S = H P_sub Hᵀ + I (§3, eq. G1), H P_sub Hᵀ formed
            // from the block-diagonal Jacobian before projection. Most tracks
            // span the whole window, so P_sub is gathered again only when
            // the columns change.
            let idx: Vec<usize> = cols.iter().flat_map(|&c| c..c + 6).collect();
            if idx != gate_idx {
                gate_p = DMatrix::zeros(idx.len(), idx.len());
                math::gather_block(&self.P, &idx, &mut gate_p);
                gate_idx.clone_from(&idx);
            }
            let mut s = feature::projected_hph(&hx_views, &hf, &obs, &gate_p);
            for i in 0..s.nrows() {
                s[(i, i)] += 1.0;
            }
            let Some(ch) = s.cholesky() else {
                gate_reject(report, &mut self.stats, Reject::NonFinite);
                continue;
            };
            let nis = r.dot(&ch.solve(&r));
            let dof = r.len();
            // A NaN NIS fails the gate too.
            if nis.is_nan() || nis > cmsckf_sitl::metrics::chi2_quantile(self.s.chi2_gate_prob, dof) {
                gate_reject(report, &mut self.stats, Reject::Chi2);
                continue;
            }
            report.nis.push((nis, dof));
            if !ks.is_empty() {
                report.loop_closure_tracks += 1;
                // Each keyframe observation is used at most once.
                for k in &ks {
                    if let Some(kf) = self.keyframes.get_mut(k) {
                        kf.obs.remove(&l);
                        kf.last_used_s = now;
                    }
                    if let Some(set) = self.kf_by_landmark.get_mut(&l) {
                        set.remove(k);
                    }
                }
            }
            involved.extend(ks.iter().copied());
            rows.push((hx, r, idx));
        }
        report.tracks_used = rows.len();
        self.stats.tracks_used += rows.len() as u64;
        self.stats.loop_closure_updates += report.loop_closure_tracks as u64;
        if rows.is_empty() {
            return;
        }
        // Stack over the union of the involved columns, in state order
        // (keyframes by id, then clones by age), so every mode builds the
        // same matrix whatever else its state holds.
        let mut union: Vec<usize> = rows.iter().flat_map(|r| r.2.iter().copied()).collect();
        union.sort_unstable();
        union.dedup();
        let m: usize = rows.iter().map(|r| r.1.len()).sum();
        let nc = union.len();
        // [H | r]: the residual rides along as the last column.
        let mut hr = DMatrix::zeros(m, nc + 1);
        let mut row = 0;
        for (hx, rr, idx) in &rows {
            for (c, col) in idx.iter().enumerate() {
                let uc = union.binary_search(col).expect("column in union");
                hr.view_mut((row, uc), (hx.nrows(), 1)).copy_from(&hx.column(c));
            }
            hr.view_mut((row, nc), (rr.len(), 1)).copy_from(rr);
            row += rr.len();
        }
        report.residual_rms = (hr.column(nc).norm_squared() / m as f64).sqrt();
        // QR compression when the stack is taller than the state (§3, eq. Q1):
        // Qᵀ [H | r] = [T r_T; 0 r_⊥], keep (T, r_T).
        let keep = if m > nc {
            math::householder_in_place(&mut hr, nc);
            nc
        } else {
            m
        };
        let h = math::block_owned(&hr, 0, 0, keep, nc);
        let r = DVector::from_column_slice(&hr.column(nc).as_slice()[..keep]);
        self.ekf_update(&h, &union, &r, m > nc);
        self.stats.updates += 1;
        report.events.push(FilterEvent::Update {
            tracks: rows.len(),
            keyframes: involved.into_iter().collect(),
        });
    }

    /// One EKF update with unit measurement noise, in the mode's form (§3
    /// eq. U1; Schmidt §6; compressed §5 eqs. C1–C3).
    /// `h` holds the columns `cols` of the full Jacobian; the rest are zero.
    /// `upper`: `h` is the square upper-triangular `T` of Q1, whose zero
    /// lower triangle the products skip.
    fn ekf_update(&mut self, h: &DMatrix<f64>, cols: &[usize], r: &DVector<f64>, upper: bool) {
        let (m, n) = (r.len(), self.P.nrows());
        let h_times = |rows: DMatrix<f64>| if upper { math::upper_mul(h, &rows) } else { h * rows };
        // H P = h P[cols, :] (P symmetric), and S = H P Hᵀ + I.
        let hp = h_times(self.P.select_rows(cols));
        let s = hp.select_columns(cols) * h.transpose() + DMatrix::identity(m, m);
        let Some(solver) = math::LowerSolver::cholesky(s) else {
            *self.stats.rejected.entry("update_not_pd").or_default() += 1;
            return;
        };
        // S = L Lᵀ. One blocked solve of L X = [H P | H Φ̃ | r] gives
        // A = L⁻¹ (H P), B = L⁻¹ (H Φ̃) and w = L⁻¹ r; then
        // δx = K r = (H P)ᵀ S⁻¹ r = Aᵀ w.
        let n0 = self.global.as_ref().map_or(0, |g| g.Phi.ncols());
        let mut x = DMatrix::zeros(m, n + n0 + 1);
        x.columns_mut(0, n).copy_from(&hp);
        if let Some(g) = self.global.as_ref() {
            x.columns_mut(n, n0).copy_from(&h_times(g.Phi.select_rows(cols)));
        }
        x.column_mut(n + n0).copy_from(r);
        drop(hp);
        solver.solve_in_place(&mut x);
        // Xᵀ, once: its rows are Aᵀ, Bᵀ and wᵀ, the left factors of every
        // product below, which read views of X and Xᵀ without copying.
        let xt = x.transpose();
        let (at, a) = (xt.rows(0, n), x.columns(0, n));
        let w = x.column(n + n0);
        let mut dx = at * w;
        // K S Kᵀ = (H P)ᵀ S⁻¹ (H P) = Aᵀ A (symmetric rank-m form).
        if self.s.mode == Mode::Schmidt {
            // Keyframes are nuisance states: K_S = 0, P_SS unchanged,
            // P_AS ← P_AS − K_A (H P)_S = P_AS − (Aᵀ A)_AS (§6).
            let (k0, k1) = (ACTIVE_DIM, self.clones_offset());
            dx.rows_mut(k0, k1 - k0).fill(0.0);
            let mut kskt = DMatrix::zeros(n, n);
            math::add_symmetric_product_t(&mut kskt, n, 1.0, at, a);
            kskt.view_mut((k0, k0), (k1 - k0, k1 - k0)).fill(0.0);
            self.P -= kskt;
            self.inject(&dx);
            return;
        }
        if let Some(g) = self.global.as_mut() {
            // C2, C3: Ψ̃ += (HΦ̃)ᵀ S⁻¹ (HΦ̃) = Bᵀ B, q̃ += (HΦ̃)ᵀ S⁻¹ r = Bᵀ w,
            // Φ̃ ← Φ̃ − K (HΦ̃) = Φ̃ − Aᵀ B.
            let (bt, b) = (xt.rows(n, n0), x.columns(n, n0));
            math::add_symmetric_product_t(&mut g.Psi, n0, 1.0, bt, b);
            g.q.gemv(1.0, &bt, &w, 1.0);
            g.Phi.gemm(-1.0, &at, &b, 1.0);
        }
        // P ← P − Aᵀ A, exactly symmetric.
        math::add_symmetric_product_t(&mut self.P, n, -1.0, at, a);
        self.inject(&dx);
    }

    /// Adds `δx[o..o+6] = [δθ, δp]` to a keyframe's nominal pose, if it
    /// still exists (global corrections G3 and P1).
    fn correct_keyframe(&mut self, id: u64, dx: &DVector<f64>, o: usize) {
        if let Some(kf) = self.keyframes.get_mut(&id) {
            kf.delta += dx.fixed_rows::<3>(o);
            kf.p_B_in_W += dx.fixed_rows::<3>(o + 3);
        }
    }

    /// Applies a correction to the local nominal state.
    fn inject(&mut self, dx: &DVector<f64>) {
        self.imu = propagate::boxplus(&self.imu, &dx.as_slice()[..IMU_DIM]);
        self.clock += dx.fixed_rows::<3>(CLK_B);
        for (j, id) in self.local_kfs.clone().iter().enumerate() {
            let o = self.kf_offset(j);
            let kf = self.keyframes.get_mut(id).expect("local keyframe exists");
            kf.delta += dx.fixed_rows::<3>(o);
            kf.p_B_in_W += dx.fixed_rows::<3>(o + 3);
        }
        let co = self.clones_offset();
        for (i, c) in self.clones.iter_mut().enumerate() {
            let o = co + 6 * i;
            c.q_W_B = exp_so3(&dx.fixed_rows::<3>(o).into_owned()) * c.q_W_B;
            c.p_B_in_W += dx.fixed_rows::<3>(o + 3);
        }
    }

    // ------------------------------------------------------- compressed

    /// Forces a global update (compressed mode; on shutdown or for a log).
    pub fn force_global_update(&mut self) {
        if self.s.mode == Mode::Compressed {
            self.finish_rebase_inline();
            self.begin_rebase(GlobalReason::Forced);
            self.finish_rebase_inline();
        }
    }

    /// Marginalises the oldest global keyframes (compressed mode) until at
    /// most `keep` remain (§5 G5: their blocks go dead and the next rebase
    /// drops them). Returns their ids. The local part is not touched, so
    /// the scaling benchmark uses it to give one filter maps of several
    /// sizes with the same local part.
    pub fn marginalise_oldest_global_keyframes(&mut self, keep: usize) -> Vec<u64> {
        let Some(g) = self.global.as_ref() else {
            return Vec::new();
        };
        let drop: Vec<u64> = g.live.keys().copied().take(g.live.len().saturating_sub(keep)).collect();
        for id in &drop {
            self.remove_keyframe(*id);
        }
        drop
    }

    /// Starts a forced rebase and hands out its job instead of running it
    /// (benchmarks time the job alone). `None` outside compressed mode.
    pub fn forced_rebase_job(&mut self) -> Option<std::sync::Arc<RebaseJob>> {
        if self.s.mode != Mode::Compressed {
            return None;
        }
        self.finish_rebase_inline();
        let was = self.s.async_rebase;
        self.s.async_rebase = true;
        self.begin_rebase(GlobalReason::Forced);
        self.s.async_rebase = was;
        self.take_rebase_job()
    }

    /// What runs a synchronous filter's rebase jobs (the evaluation times
    /// them with a wrapper; the result must be the job's `run()`).
    pub fn set_rebase_runner(&mut self, f: fn(&RebaseJob) -> RebaseResult) {
        self.rebase_runner = f;
    }

    /// Asynchronous rebases (§5 R4): see [`Settings::async_rebase`].
    pub fn set_async_rebase(&mut self, on: bool) {
        self.s.async_rebase = on;
    }

    /// The whole state, reconstructed, in a fixed order: IMU, clones,
    /// keyframes by id. Does not change the filter.
    pub fn snapshot(&self) -> Snapshot {
        let mut est = self.clone();
        est.merge_global();
        let kf_pos: BTreeMap<u64, usize> = est
            .local_kfs
            .iter()
            .enumerate()
            .map(|(j, id)| (*id, ACTIVE_DIM + 6 * j))
            .collect();
        let mut idx: Vec<usize> = (0..ACTIVE_DIM).collect();
        let co = est.clones_offset();
        idx.extend(co..co + 6 * est.clones.len());
        for off in kf_pos.values() {
            idx.extend(*off..*off + 6);
        }
        let P = est.P.select_rows(&idx).select_columns(&idx);
        let mut x = Vec::new();
        let push_q = |x: &mut Vec<f64>, q: &UnitQuaternion<f64>| {
            let c = q.coords;
            let s = if c.w < 0.0 { -1.0 } else { 1.0 };
            x.extend([c.w * s, c.x * s, c.y * s, c.z * s]);
        };
        let i = &est.imu;
        push_q(&mut x, &i.q_W_B);
        for v in [i.v_B_in_W, i.p_B_in_W, i.b_g, i.b_a] {
            x.extend(v.iter());
        }
        x.extend(est.clock.iter());
        for c in &est.clones {
            push_q(&mut x, &c.q_W_B);
            x.extend(c.p_B_in_W.iter());
        }
        for id in kf_pos.keys() {
            let kf = &est.keyframes[id];
            x.extend(kf.delta.iter());
            x.extend(kf.p_B_in_W.iter());
        }
        Snapshot {
            x: DVector::from_vec(x),
            P,
        }
    }

    /// Health checks (§9): the covariance finite, symmetric, with a positive
    /// diagonal and a positive-definite active block; the state finite and
    /// within physical bounds; and the NIS monitor's verdict. Returns the
    /// first problem found. Allocation-free, so it can run every IMU sample.
    pub fn check_health(&self) -> Result<(), String> {
        let p = &self.P;
        if !math::all_finite(p.as_slice()) {
            return Err("covariance has non-finite entries".into());
        }
        for i in 0..p.nrows() {
            if p[(i, i)] <= 0.0 {
                return Err(format!("covariance diagonal {i} is {}", p[(i, i)]));
            }
        }
        // Symmetric (updates and propagation keep it exactly so, so any
        // asymmetry is a fault), and
        // the active block positive definite (a Cholesky of 18×18: cheap).
        // |P_ij − P_ji| ≤ 1e-9 √(P_ii P_jj), compared squared (no root).
        let n = p.nrows();
        for i in 0..n.min(ACTIVE_DIM) {
            let pii = p[(i, i)];
            for j in 0..n {
                let d = p[(i, j)] - p[(j, i)];
                if d * d > 1e-18 * pii * p[(j, j)] {
                    return Err(format!("covariance is not symmetric at ({i}, {j})"));
                }
            }
        }
        if p.fixed_view::<ACTIVE_DIM, ACTIVE_DIM>(0, 0)
            .into_owned()
            .cholesky()
            .is_none()
        {
            return Err("the active covariance block is not positive definite".into());
        }
        let i = &self.imu;
        if ![i.v_B_in_W, i.p_B_in_W, i.b_a, i.b_g]
            .iter()
            .all(|v| v.iter().all(|x| x.is_finite()))
        {
            return Err("state has non-finite entries".into());
        }
        // State sanity: a multirotor's envelope, with margin.
        if i.v_B_in_W.norm() > MAX_SPEED_MPS {
            return Err(format!(
                "speed {:.0} m/s is beyond {MAX_SPEED_MPS} m/s",
                i.v_B_in_W.norm()
            ));
        }
        if i.b_a.norm() > MAX_ACCEL_BIAS_MPS2 || i.b_g.norm() > MAX_GYRO_BIAS_RADPS {
            return Err(format!(
                "IMU bias out of range (accel {:.2} m/s², gyro {:.3} rad/s)",
                i.b_a.norm(),
                i.b_g.norm()
            ));
        }
        self.monitor.verdict()
    }
}

/// What one GNSS epoch did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GnssReport {
    pub pseudoranges_used: usize,
    pub range_rates_used: usize,
    pub rejected: BTreeMap<&'static str, u64>,
    /// `(prn, pseudorange residual m, range-rate residual m/s)` before the update.
    pub residuals: Vec<(u8, Option<f64>, Option<f64>)>,
    pub clock_initialised: bool,
}

impl Estimator {
    /// The receiver clock `[c·δt_G (m), c·δṫ (m/s), isb_E (m)]` and its
    /// variances.
    pub fn clock(&self) -> (nalgebra::Vector3<f64>, nalgebra::Vector3<f64>) {
        (
            self.clock,
            nalgebra::Vector3::new(self.P[(CLK_B, CLK_B)], self.P[(CLK_D, CLK_D)], self.P[(CLK_E, CLK_E)]),
        )
    }

    /// Whether a Galileo epoch has set the inter-system bias yet.
    pub fn isb_initialised(&self) -> bool {
        self.isb_initialised
    }

    /// Resets the clock states `ks` to `values`, uncorrelated with the rest,
    /// with the variances `var` (§8, eq. K4).
    fn reset_clock_states(&mut self, ks: &[usize], values: &[f64], var: &[f64]) {
        for ((&k, &x), &v) in ks.iter().zip(values).zip(var) {
            self.clock[k - CLK_B] = x;
            self.P.row_mut(k).fill(0.0);
            self.P.column_mut(k).fill(0.0);
            if let Some(g) = self.global.as_mut() {
                g.Phi.row_mut(k).fill(0.0);
            }
            self.P[(k, k)] = v;
        }
    }

    /// One GNSS epoch at `t_s` (§8): pseudoranges and range rates of the
    /// satellites in `sats`, against the world origin `frame`. GPS is the
    /// reference clock: the first epoch with GPS pseudoranges sets the bias
    /// and drift from the median residuals, and the first with Galileo ones
    /// sets the inter-system bias the same way; until then those
    /// measurements wait.
    pub fn process_gnss(
        &mut self,
        t_s: f64,
        frame: &cmsckf_sitl::geodesy::NedFrame,
        sats: &[gnss_update::SatMeas],
    ) -> Result<GnssReport, InputError> {
        use cmsckf_sitl::gnss::System;
        self.advance_to(t_s, "gnss_time_backwards")?;
        let mut rep = GnssReport::default();
        let mask = self.s.elevation_mask_deg.to_radians();
        let p = self.imu.p_B_in_W;
        let v = self.imu.v_B_in_W;
        let median = |mut v: Vec<f64>| -> Option<f64> {
            v.retain(|x| x.is_finite());
            v.sort_by(|a, b| a.total_cmp(b));
            v.get(v.len() / 2).copied()
        };
        let code_residuals = |sys: System, bias: f64| -> Vec<f64> {
            sats.iter()
                .filter(|s| s.system == sys)
                .filter_map(|s| {
                    s.pseudorange_m
                        .map(|z| z - gnss_update::pseudorange(frame, &p, bias, s).0)
                })
                .collect()
        };
        if !self.clock_initialised {
            let Some(b) = median(code_residuals(System::Gps, 0.0)) else {
                return Ok(rep);
            };
            let d = median(
                sats.iter()
                    .filter_map(|s| {
                        s.range_rate_mps
                            .map(|z| z - gnss_update::range_rate(frame, &p, &v, 0.0, s).0)
                    })
                    .collect(),
            )
            .unwrap_or(0.0);
            self.reset_clock_states(&[CLK_B, CLK_D], &[b, d], &[30.0f64.powi(2), 1.0]);
            self.clock_initialised = true;
            rep.clock_initialised = true;
        }
        if !self.isb_initialised {
            if let Some(isb) = median(code_residuals(System::Galileo, self.clock.x)) {
                self.reset_clock_states(&[CLK_E], &[isb], &[30.0f64.powi(2)]);
                self.isb_initialised = true;
            }
        }
        // Robust pre-screen (K5): each constellation's median code residual
        // stands for its clock error, so a code far from it is an outlier
        // whatever the clock's variance (the χ² gate alone lets a 30 m
        // multipath code through while the clock is still uncertain).
        let isb_of = |s: &gnss_update::SatMeas| if s.system == System::Galileo { 1.0 } else { 0.0 };
        let median_res = |sys: System| {
            median(code_residuals(
                sys,
                self.clock.x + self.clock.z * f64::from(sys == System::Galileo),
            ))
        };
        let medians = [
            (System::Gps, median_res(System::Gps)),
            (System::Galileo, median_res(System::Galileo)),
        ];
        // Columns: velocity, position, clock bias, drift, Galileo ISB.
        let cols = [3usize, 4, 5, 6, 7, 8, CLK_B, CLK_D, CLK_E];
        let mut p_sub = DMatrix::zeros(cols.len(), cols.len());
        math::gather_block(&self.P, &cols, &mut p_sub);
        let mut rows: Vec<([f64; 9], f64)> = Vec::new();
        let gate = cmsckf_sitl::metrics::chi2_quantile(0.99, 1);
        let reject = |rep: &mut GnssReport, st: &mut Stats, why: &'static str| {
            *rep.rejected.entry(why).or_default() += 1;
            *st.rejected.entry(why).or_default() += 1;
        };
        for s in sats {
            let isb = isb_of(s);
            let (pr_pred, hp, el) = gnss_update::pseudorange(frame, &p, self.clock.x + isb * self.clock.z, s);
            if el < mask {
                reject(&mut rep, &mut self.stats, "gnss_below_mask");
                continue;
            }
            let sin_el = el.sin().max(0.1);
            let mut res = (s.prn, None, None);
            if let Some(z) = s.pseudorange_m.filter(|z| z.is_finite()) {
                let sigma = ((self.s.pseudorange_sigma_m * s.noise_scale / sin_el).powi(2) + s.extra_var_m2).sqrt();
                // ∂P/∂[v, p, b, ḃ, isb] (K2): Galileo's code sees b + isb.
                let h = [0.0, 0.0, 0.0, hp[0], hp[1], hp[2], 1.0, 0.0, isb];
                let r = z - pr_pred;
                res.1 = Some(r);
                let median = medians.iter().find(|m| m.0 == s.system).and_then(|m| m.1);
                if median.is_some_and(|m| (r - m).abs() > OUTLIER_SIGMAS * sigma) {
                    reject(&mut rep, &mut self.stats, "gnss_pseudorange_outlier");
                } else if let Some(row) = gated(&h, r, sigma, &p_sub, gate) {
                    rows.push(row);
                    rep.pseudoranges_used += 1;
                } else {
                    reject(&mut rep, &mut self.stats, "gnss_pseudorange_chi2");
                }
            }
            if let Some(z) = s.range_rate_mps.filter(|z| z.is_finite()) {
                let (pred, hv, hpr) = gnss_update::range_rate(frame, &p, &v, self.clock.y, s);
                let sigma = self.s.range_rate_sigma_mps / sin_el;
                let h = [hv[0], hv[1], hv[2], hpr[0], hpr[1], hpr[2], 0.0, 1.0, 0.0];
                let r = z - pred;
                res.2 = Some(r);
                if let Some(row) = gated(&h, r, sigma, &p_sub, gate) {
                    rows.push(row);
                    rep.range_rates_used += 1;
                } else {
                    reject(&mut rep, &mut self.stats, "gnss_range_rate_chi2");
                }
            }
            rep.residuals.push(res);
        }
        let pr_rejected = rep.rejected.get("gnss_pseudorange_chi2").copied().unwrap_or(0)
            + rep.rejected.get("gnss_pseudorange_outlier").copied().unwrap_or(0);
        self.monitor.push_gnss(rep.pseudoranges_used, pr_rejected as usize);
        if rows.is_empty() {
            return Ok(rep);
        }
        let mut h = DMatrix::zeros(rows.len(), cols.len());
        let mut r = DVector::zeros(rows.len());
        for (i, (hr, rr)) in rows.iter().enumerate() {
            for k in 0..cols.len() {
                h[(i, k)] = hr[k];
            }
            r[i] = *rr;
        }
        self.ekf_update(&h, &cols, &r, false);
        self.stats.updates += 1;
        Ok(rep)
    }
}

/// Position σ (m, `√trace`) of the pose block `[δθ, δp]` starting at `o`.
fn position_sigma_m(p: &DMatrix<f64>, o: usize) -> f64 {
    let o = o + 3;
    (p[(o, o)] + p[(o + 1, o + 1)] + p[(o + 2, o + 2)]).max(0.0).sqrt()
}

/// Whitens one scalar measurement row and gates it on `r² / (h P hᵀ + σ²)`.
fn gated<const N: usize>(h: &[f64; N], r: f64, sigma: f64, p: &DMatrix<f64>, gate: f64) -> Option<([f64; N], f64)> {
    let hv = nalgebra::DVector::from_column_slice(h);
    let s = (hv.transpose() * p * &hv)[0] + sigma * sigma;
    if !(r.is_finite() && s > 0.0) || r * r / s > gate {
        return None;
    }
    let mut w = *h;
    for x in w.iter_mut() {
        *x /= sigma;
    }
    Some((w, r / sigma))
}

/// A lower-triangular `L` with `L Lᵀ ≈ P` and a positive diagonal: the
/// Cholesky factor of `P + λ diag(P)` for the smallest `λ ∈ {0, 1e-12, …}`
/// that works, else `diag(√P_ii)`.
fn whitening_factor(p: &DMatrix<f64>) -> DMatrix<f64> {
    let d = DMatrix::from_diagonal(&p.diagonal().map(|v| v.abs().max(1e-300)));
    let mut lambda = 0.0;
    for _ in 0..8 {
        if let Some(ch) = (p + &d * lambda).cholesky() {
            let l = ch.l();
            if l.diagonal().iter().all(|v| *v > 0.0 && v.is_finite()) {
                return l;
            }
        }
        lambda = if lambda == 0.0 { 1e-12 } else { lambda * 100.0 };
    }
    d.map(f64::sqrt)
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

#[cfg(test)]
mod tests;
