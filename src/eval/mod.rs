//! Offline evaluation: runs simulated flights through the estimator,
//! in-process and deterministically, and scores them against the truth.
//!
//! This is what `cmsckf evaluate` prints, and what the consistency and
//! exactness tests use. Wall-clock timing of each frame is measured here, at
//! the boundary, never inside the estimator.

use std::collections::BTreeMap;
use std::time::Instant;

use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use cmsckf_models::feature_wire::PixelFeature;
use cmsckf_sitl::config::SimConfig;
use cmsckf_sitl::dataset::Dataset;

use crate::config::Config;
use crate::estimator::frontend::{NormObs, Normaliser};
use crate::estimator::landed::LandedGate;
use crate::estimator::propagate::{boxplus, Mat15};
use crate::estimator::Mode;
use crate::estimator::{Estimator, ImuMeas, ImuState, Stats};

mod summary;

pub use summary::{max_by_quarter, score, summarise, FlightScore, ModeSummary};

/// The simulator settings that match a daemon config (same camera and IMU).
pub fn sim_config_for(cfg: &Config) -> SimConfig {
    let mut s = SimConfig::new();
    s.camera = cfg.camera.clone();
    s.imu = cfg.imu.clone();
    s
}

/// Initial state: the truth at t = 0 perturbed by a draw from the initial
/// covariance (so the NEES is meaningful from the first sample).
pub fn init_from_truth(ds: &Dataset, p0: &Mat15, seed: u64) -> ImuState {
    let t0 = &ds.truth[0];
    let truth = ImuState {
        q_W_B: t0.truth.q_W_B,
        v_B_in_W: t0.truth.v_B_in_W,
        p_B_in_W: t0.truth.p_B_in_W,
        b_g: t0.bias.b_g,
        b_a: t0.bias.b_a,
    };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(10);
    let d: Vec<f64> = (0..15)
        .map(|k| {
            let z: f64 = StandardNormal.sample(&mut rng);
            z * p0[(k, k)].sqrt()
        })
        .collect();
    boxplus(&truth, &d)
}

/// One flight through one mode.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FlightResult {
    pub mode: Mode,
    /// The simulated urban canyon `[start, end]` (s), if any
    /// (`gnss.canyon_s`): its position error is scored apart.
    pub canyon_s: Option<(f64, f64)>,
    pub t_s: Vec<f64>,
    pub p_est: Vec<Vector3<f64>>,
    pub q_est: Vec<UnitQuaternion<f64>>,
    pub cov_pose: Vec<Matrix6<f64>>,
    pub p_true: Vec<Vector3<f64>>,
    pub q_true: Vec<UnitQuaternion<f64>>,
    pub v_est: Vec<Vector3<f64>>,
    pub v_true: Vec<Vector3<f64>>,
    /// Covariance of the velocity (m²/s²).
    pub cov_vel: Vec<Matrix3<f64>>,
    /// The camera–IMU time offset: the final estimate and the simulator's
    /// truth (s).
    pub time_offset_s: f64,
    pub time_offset_true_s: f64,
    /// The time offset's final σ (s).
    pub time_offset_sigma_s: f64,
    /// Health-check failures (each a reset in the daemon).
    pub resets: u64,
    /// `(t, covariance, state)` normalised differences of compressed from
    /// full at each global update (lockstep runs only,
    /// [`crate::estimator::Snapshot::max_rel_diff_parts`]): the drift of two
    /// filters fed the same data.
    pub diff_vs_full: Vec<(f64, f64, f64)>,
    /// Estimator time per frame (µs), without the compressed rebases, which
    /// the daemon computes on its worker thread.
    pub frame_us: Vec<f64>,
    /// `(global keyframes after, µs)` of each compressed rebase job.
    pub rebase_us: Vec<(usize, f64)>,
    pub stats: Stats,
    pub keyframes: usize,
    /// The accepted tracks' NIS and degrees of freedom, summed over the
    /// flight: their ratio is the NIS per degree of freedom.
    pub nis_sum: f64,
    pub nis_dof: u64,
    /// Largest relative difference from `full` at any global update
    /// (compressed runs in lockstep with full only).
    pub max_rel_diff_vs_full: Option<f64>,
    /// `(t, estimated − true clock bias, estimated − true Galileo ISB)` at
    /// each GNSS epoch (m).
    pub clock_errors: Vec<(f64, f64, f64)>,
    /// Each range-bias state's NEES `(b̂ − b)² / σ²` at the flight's end,
    /// against the simulator's broadcast error of its satellite (§8c, DG5′).
    #[serde(default)]
    pub range_bias_nees: Vec<f64>,
}

/// GNSS input of a run: the broadcast ephemerides, the world origin, and
/// the epochs in the order they reach the host.
#[derive(Clone)]
struct GnssInput {
    ephs: crate::gnss::spp::EphStore,
    frame: cmsckf_models::geodesy::NedFrame,
    /// Epoch indices by delivery time, and the next to deliver.
    order: Vec<usize>,
    next: usize,
    /// Deliver each epoch at its own instant (no latency), for comparisons.
    on_time: bool,
    /// Changes each epoch's measurements before they are fused (tests: a
    /// constellation the simulator has not, relabelled from one it has).
    map: Option<fn(&mut [cmsckf_models::gnss::SatMeas])>,
}

/// The satellites' measurements of epoch `i`, as the daemon would make them.
fn epoch_measurements(ds: &Dataset, ephs: &crate::gnss::spp::EphStore, i: usize) -> Vec<cmsckf_models::gnss::SatMeas> {
    let ep = &ds.gnss[i];
    // The simulated receiver is single-frequency; its ionosphere is off by
    // default, and `sim.gnss.ionosphere` makes it modelled as unknown
    // (variance inflated).
    let iono = if ds.cfg.gnss.ionosphere {
        crate::gnss::IonoMode::Auto
    } else {
        crate::gnss::IonoMode::Off
    };
    crate::gnss::sat_measurements(
        ephs,
        ep.week,
        ep.tow_s,
        crate::gnss::IonoPolicy {
            mode: iono,
            klobuchar: None,
            rx_ecef_m: None,
        },
        ep.sats.iter().map(|s| crate::gnss::RawSat {
            system: s.system,
            prn: s.prn,
            l1_pseudorange_m: Some(s.pseudorange_m),
            l2_pseudorange: None,
            l1_range_rate_mps: Some(s.pseudorange_rate_mps),
        }),
    )
}

/// Drives one estimator through a dataset.
#[derive(Clone)]
pub struct Runner<'a> {
    ds: &'a Dataset,
    normaliser: Normaliser,
    pub est: Estimator,
    imu_next: usize,
    buf: Vec<NormObs>,
    gnss: Option<GnssInput>,
    /// The barometer's readings `(t_s, h_m)` (`barometer.fuse`), and the
    /// next one to fuse.
    baro: Vec<(f64, f64)>,
    baro_next: usize,
    /// `(t, estimated − true clock bias, estimated − true Galileo ISB)` at
    /// each GNSS epoch (m).
    pub clock_errors: Vec<(f64, f64, f64)>,
    /// `(global keyframes after, µs)` of each rebase job, timed apart.
    pub rebase_us: Vec<(usize, f64)>,
    /// Times the health check failed after passing: each would have reset
    /// the daemon's filter.
    pub resets: u64,
    healthy: bool,
    /// Whether the autopilot's landed state gates the zero-velocity
    /// updates, as beside ArduPilot or PX4 (true by default).
    landed_state: bool,
    /// That landed state as the daemon reads it (the dataset's land
    /// detector, at each frame), and the take-off grace it opens.
    gate: LandedGate,
}

thread_local! {
    /// Rebase jobs run on this thread since last drained: `(global keyframes, µs)`.
    static REBASE_US: std::cell::RefCell<Vec<(usize, f64)>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// [`RebaseJob::run`], timed into `REBASE_US`.
fn timed_rebase(job: &crate::estimator::RebaseJob) -> crate::estimator::RebaseResult {
    let t0 = Instant::now();
    let res = job.run();
    let us = t0.elapsed().as_secs_f64() * 1e6;
    REBASE_US.with(|r| r.borrow_mut().push((job.n_global(), us)));
    res
}

impl<'a> Runner<'a> {
    pub fn new(ds: &'a Dataset, cfg: &Config, mode: Mode, init_seed: u64) -> Self {
        let mut c = cfg.clone();
        c.estimator.mode = mode;
        // The antenna's place on the airframe is measured and configured;
        // the camera's time offset is not (the filter estimates it).
        c.gnss.p_A_in_B_m = ds.cfg.gnss.p_A_in_B_m;
        let p0 = c.initial_covariance();
        let x0 = init_from_truth(ds, &p0, init_seed);
        let mut est = Estimator::new(c.estimator_settings(), ds.truth[0].truth.t_s, x0, &p0);
        est.set_rebase_runner(timed_rebase);
        Self {
            ds,
            normaliser: Normaliser::new(&c.camera),
            est,
            rebase_us: Vec::new(),
            imu_next: 0,
            buf: Vec::with_capacity(c.features.max_features),
            gnss: None,
            // The autopilot's SCALED_PRESSURE rate.
            baro: if c.barometer.fuse {
                cmsckf_sitl::barometer::readings(ds, 10.0)
            } else {
                Vec::new()
            },
            baro_next: 0,
            clock_errors: Vec::new(),
            resets: 0,
            healthy: true,
            landed_state: true,
            gate: LandedGate::default(),
        }
    }

    /// Without the autopilot's landed state: zero-velocity updates judged
    /// by the IMU and the camera alone, as beside an autopilot that says
    /// nothing (on a vibrating IMU a hover can then pass for still).
    pub fn without_landed_state(mut self) -> Self {
        self.landed_state = false;
        self
    }

    /// Fuses the dataset's pseudoranges and range rates too, each epoch
    /// as it reaches the host (`t_delivered_s`, late by the simulated
    /// receiver's latency).
    pub fn with_gnss(self) -> Self {
        self.gnss_input(false)
    }

    /// As [`Self::with_gnss`], but each epoch delivered at its own instant:
    /// the reference the late deliveries are compared with.
    pub fn with_gnss_on_time(self) -> Self {
        self.gnss_input(true)
    }

    fn gnss_input(mut self, on_time: bool) -> Self {
        let mut ephs = crate::gnss::spp::EphStore::default();
        for e in &self.ds.ephemerides {
            ephs.insert(e.clone());
        }
        let o = self.ds.cfg.gnss.origin_llh;
        let delivered = |i: usize| {
            let e = &self.ds.gnss[i];
            if on_time {
                e.t_s
            } else {
                e.t_delivered_s
            }
        };
        let mut order: Vec<usize> = (0..self.ds.gnss.len()).collect();
        order.sort_by(|a, b| delivered(*a).total_cmp(&delivered(*b)));
        self.gnss = Some(GnssInput {
            ephs,
            frame: cmsckf_models::geodesy::NedFrame::from_llh_deg(o[0], o[1], o[2]),
            order,
            next: 0,
            on_time,
            map: None,
        });
        self
    }

    /// Passes each epoch's measurements through `map` before fusing them
    /// (after [`Self::with_gnss`]).
    pub fn with_measurement_map(mut self, map: fn(&mut [cmsckf_models::gnss::SatMeas])) -> Self {
        if let Some(g) = self.gnss.as_mut() {
            g.map = Some(map);
        }
        self
    }

    /// The first epoch after `t_s` (index, world origin, measurements),
    /// for tests that fuse it by hand.
    pub fn gnss_epoch_after(
        &self,
        t_s: f64,
    ) -> Option<(
        usize,
        cmsckf_models::geodesy::NedFrame,
        Vec<cmsckf_models::gnss::SatMeas>,
    )> {
        let g = self.gnss.as_ref()?;
        let i = self.ds.gnss.iter().position(|e| e.t_s > t_s)?;
        Some((i, g.frame, epoch_measurements(self.ds, &g.ephs, i)))
    }

    /// Delivers the epochs that reach the host by `t_s`, and brings the
    /// filter to `t_s` (so two runs can be compared at one time).
    pub fn finish_gnss(&mut self, t_s: f64) {
        self.step_gnss(t_s);
        self.feed_imu(t_s);
        self.est.propagate_to(t_s);
    }

    /// Feeds IMU up to just past `t_s`.
    fn feed_imu(&mut self, t_s: f64) {
        while self.imu_next < self.ds.imu.len() {
            if self.imu_next > 0 && self.ds.imu[self.imu_next - 1].t_s > t_s {
                break;
            }
            let m = &self.ds.imu[self.imu_next];
            let _ = self.est.add_imu(ImuMeas {
                t_s: m.t_s,
                accel_mps2: m.accel_mps2,
                gyro_radps: m.gyro_radps,
            });
            self.imu_next += 1;
        }
    }

    /// The barometer's readings up to `t_s`, each once the IMU covers it
    /// (the daemon's queue does the same).
    fn step_baro(&mut self, t_s: f64) {
        while let Some(&(t_b, h_m)) = self.baro.get(self.baro_next) {
            if t_b > t_s {
                break;
            }
            self.baro_next += 1;
            self.feed_imu(t_b);
            let _ = self.est.process_baro(t_b, h_m);
        }
    }

    /// The GNSS epochs that reach the host by `t_s`, in delivery order.
    fn step_gnss(&mut self, t_s: f64) {
        let Some(mut g) = self.gnss.take() else { return };
        let ds = self.ds;
        while let Some(&i) = g.order.get(g.next) {
            let ep = &ds.gnss[i];
            let delivered = if g.on_time { ep.t_s } else { ep.t_delivered_s };
            if delivered > t_s {
                break;
            }
            g.next += 1;
            let mut sats = epoch_measurements(ds, &g.ephs, i);
            if let Some(map) = g.map {
                map(&mut sats);
            }
            let frame = g.frame;
            // The IMU has arrived up to the delivery.
            self.feed_imu(delivered);
            if self.est.process_gnss(ep.t_s, &frame, &sats).is_ok() {
                // The clock is the filter's now, after the epoch.
                let (c, _) = self.est.clock();
                let clock_truth = ep.clock_bias_m + ep.clock_drift_mps * (self.est.time_s() - ep.t_s);
                let isb_err = if self.est.isb_initialised(cmsckf_models::gnss::System::Galileo) {
                    c.z - ep.isb_galileo_m
                } else {
                    f64::NAN
                };
                self.clock_errors.push((ep.t_s, c.x - clock_truth, isb_err));
            }
        }
        self.gnss = Some(g);
    }

    /// A forced global update (compressed mode), its rebase job timed into
    /// `rebase_us` like the others.
    pub fn force_global_update(&mut self) {
        self.est.force_global_update();
        self.collect_rebase_jobs();
    }

    /// Moves the rebase jobs timed since the last call into `rebase_us`;
    /// returns their total time (µs).
    fn collect_rebase_jobs(&mut self) -> f64 {
        let jobs = REBASE_US.with(|r| std::mem::take(&mut *r.borrow_mut()));
        let us = jobs.iter().map(|j| j.1).sum();
        self.rebase_us.extend(jobs);
        us
    }

    /// Feeds IMU up to just past `t_s`, then the frame. Returns the wall
    /// time spent in the estimator (µs) and the frame's report.
    pub fn step_frame(&mut self, k: usize) -> (f64, crate::estimator::FrameReport) {
        self.step_frame_weighted(k, |_| None)
    }

    /// [`Runner::step_frame`] with each feature's σ (px) as a front-end
    /// would send it (`sigma_px(landmark_id)`; `None`: none sent).
    pub fn step_frame_weighted(
        &mut self,
        k: usize,
        mut sigma_px: impl FnMut(u64) -> Option<f64>,
    ) -> (f64, crate::estimator::FrameReport) {
        // The frame reaches the host late; by then the IMU and any GNSS
        // epoch delivered before it are in.
        let t_f = self.ds.frames[k].t_delivered_s;
        self.step_gnss(t_f);
        self.step_baro(self.ds.frames[k].t_s);
        // Everything up to the delivery, plus the first sample after it so
        // the estimator can interpolate at the frame time.
        self.feed_imu(t_f);
        let f = &self.ds.frames[k];
        // What the daemon takes from the autopilot's EXTENDED_SYS_STATE:
        // zero-velocity updates on the ground, and through the take-off's
        // spin-up until the camera sees motion (the land detector says "in
        // the air" before the vehicle rises).
        if self.landed_state {
            self.gate.set_on_ground(f.t_s, self.ds.landed_at(f.t_s));
            self.est.set_zupt_allowed(self.gate.zupt_allowed(f.t_s));
        }
        let start = Instant::now();
        self.normaliser.normalise_into(
            f.features.iter().map(|o| PixelFeature {
                sigma_px: sigma_px(o.landmark_id),
                ..PixelFeature::new(o.landmark_id, o.u_px, o.v_px)
            }),
            &mut self.buf,
        );
        let rep = self.est.process_frame(f.t_s, &self.buf).unwrap_or_default();
        let frame_us = start.elapsed().as_secs_f64() * 1e6;
        if rep.camera_moved {
            self.gate.camera_moved(f.t_s);
        }
        // What the daemon would do: a failed health check resets the filter.
        // Counted at each onset (the evaluation lets the filter run on).
        let healthy = self.est.check_health().is_ok();
        if !healthy && self.healthy {
            self.resets += 1;
        }
        self.healthy = healthy;
        // The frame time without the rebase jobs it ran (which the daemon
        // runs on its worker thread), and those apart.
        let job_us = self.collect_rebase_jobs();
        (frame_us - job_us, rep)
    }
}

/// The estimate after a frame, with the truth at the filter's own time (the
/// frame's stamp plus the estimated time offset).
fn record(r: &mut FlightResult, ds: &Dataset, est: &Estimator) {
    let t_s = est.time_s();
    let x = est.imu_state();
    let tr = ds.trajectory.sample(t_s);
    r.t_s.push(t_s);
    r.p_est.push(x.p_B_in_W);
    r.q_est.push(x.q_W_B);
    r.v_est.push(x.v_B_in_W);
    r.cov_pose.push(est.pose_covariance());
    r.cov_vel
        .push(est.imu_covariance().fixed_view::<3, 3>(3, 3).into_owned());
    r.p_true.push(tr.p_B_in_W);
    r.q_true.push(tr.q_W_B);
    r.v_true.push(tr.v_B_in_W);
}

fn empty(mode: Mode) -> FlightResult {
    FlightResult {
        mode,
        canyon_s: None,
        t_s: vec![],
        p_est: vec![],
        q_est: vec![],
        cov_pose: vec![],
        p_true: vec![],
        q_true: vec![],
        v_est: vec![],
        v_true: vec![],
        cov_vel: vec![],
        time_offset_s: 0.0,
        time_offset_true_s: 0.0,
        time_offset_sigma_s: 0.0,
        resets: 0,
        diff_vs_full: Vec::new(),
        frame_us: vec![],
        rebase_us: vec![],
        stats: Stats::default(),
        keyframes: 0,
        nis_sum: 0.0,
        nis_dof: 0,
        max_rel_diff_vs_full: None,
        clock_errors: Vec::new(),
        range_bias_nees: Vec::new(),
    }
}

/// Adds a frame's accepted tracks' NIS and degrees of freedom.
fn add_nis(r: &mut FlightResult, rep: &crate::estimator::FrameReport) {
    for (nis, dof) in &rep.nis {
        r.nis_sum += nis;
        r.nis_dof += *dof as u64;
    }
}

/// What a run's filter ends with.
fn finish(r: &mut FlightResult, ds: &Dataset, run: &Runner) {
    r.stats = run.est.stats.clone();
    r.keyframes = run.est.keyframes().count();
    r.clock_errors = run.clock_errors.clone();
    r.range_bias_nees = range_bias_nees(ds, &run.est);
    r.rebase_us = run.rebase_us.clone();
    let (td_s, td_var_s2) = run.est.time_offset();
    r.time_offset_s = td_s;
    r.time_offset_sigma_s = td_var_s2.sqrt();
    r.time_offset_true_s = ds.cfg.camera_time_offset_s;
    r.resets = run.resets;
}

/// Each range-bias state's `(b̂ − b)² / σ²` against the broadcast error of
/// its satellite (any epoch's: it holds for the flight).
fn range_bias_nees(ds: &Dataset, est: &Estimator) -> Vec<f64> {
    est.range_biases()
        .into_iter()
        .filter_map(|b| {
            // Constant over the flight: any epoch that saw the satellite.
            let truth_m = ds
                .gnss
                .iter()
                .rev()
                .flat_map(|e| e.sats.iter())
                .find(|s| s.system == b.system && s.prn == b.prn)?
                .broadcast_error_m;
            (b.var_m2 > 0.0).then(|| (b.b_m - truth_m).powi(2) / b.var_m2)
        })
        .collect()
}

/// What a flight fuses besides the IMU and the camera, and what it knows.
#[derive(Clone, Copy, Debug)]
struct Inputs {
    gnss: bool,
    /// The autopilot's landed state ([`Runner::without_landed_state`]).
    landed_state: bool,
}

impl Inputs {
    /// With the autopilot's landed state, as beside ArduPilot or PX4.
    fn beside_autopilot(gnss: bool) -> Self {
        Self {
            gnss,
            landed_state: true,
        }
    }
}

fn runner<'a>(ds: &'a Dataset, cfg: &Config, mode: Mode, seed: u64, inputs: Inputs) -> Runner<'a> {
    let mut r = Runner::new(ds, cfg, mode, seed);
    if !inputs.landed_state {
        r = r.without_landed_state();
    }
    if inputs.gnss {
        r.with_gnss()
    } else {
        r
    }
}

/// Runs one mode over a dataset (with its GNSS if `gnss`).
pub fn run(ds: &Dataset, cfg: &Config, mode: Mode, init_seed: u64, gnss: bool) -> FlightResult {
    run_with(ds, cfg, mode, init_seed, Inputs::beside_autopilot(gnss))
}

fn run_with(ds: &Dataset, cfg: &Config, mode: Mode, init_seed: u64, inputs: Inputs) -> FlightResult {
    let mut runner = runner(ds, cfg, mode, init_seed, inputs);
    let mut r = empty(mode);
    let c = &ds.cfg.gnss.canyon_s;
    r.canyon_s = (c.len() == 2).then(|| (c[0], c[1]));
    for k in 0..ds.frames.len() {
        let (us, rep) = runner.step_frame(k);
        r.frame_us.push(us);
        add_nis(&mut r, &rep);
        record(&mut r, ds, &runner.est);
    }
    finish(&mut r, ds, &runner);
    r
}

/// Runs `compressed` and `full` in lockstep and compares them after every
/// frame with a global update, and at the end after a forced global update.
pub fn run_compressed_vs_full(ds: &Dataset, cfg: &Config, init_seed: u64, gnss: bool) -> (FlightResult, FlightResult) {
    compressed_vs_full_with(ds, cfg, init_seed, Inputs::beside_autopilot(gnss))
}

fn compressed_vs_full_with(ds: &Dataset, cfg: &Config, init_seed: u64, inputs: Inputs) -> (FlightResult, FlightResult) {
    let mut rc = runner(ds, cfg, Mode::Compressed, init_seed, inputs);
    let mut rf = runner(ds, cfg, Mode::Full, init_seed, inputs);
    let (mut c, mut f) = (empty(Mode::Compressed), empty(Mode::Full));
    let mut worst: f64 = 0.0;
    for k in 0..ds.frames.len() {
        let (us_c, rep) = rc.step_frame(k);
        let (us_f, rep_f) = rf.step_frame(k);
        c.frame_us.push(us_c);
        f.frame_us.push(us_f);
        add_nis(&mut c, &rep);
        add_nis(&mut f, &rep_f);
        record(&mut c, ds, &rc.est);
        record(&mut f, ds, &rf.est);
        if rep.global_updates > 0 {
            let d = rc.est.snapshot().max_rel_diff_parts(&rf.est.snapshot());
            c.diff_vs_full.push((rc.est.time_s(), d.0, d.1));
            worst = worst.max(d.0).max(d.1);
        }
    }
    rc.est.force_global_update();
    let d = rc.est.snapshot().max_rel_diff_parts(&rf.est.snapshot());
    c.diff_vs_full.push((rc.est.time_s(), d.0, d.1));
    worst = worst.max(d.0).max(d.1);
    for (r, run) in [(&mut c, &rc), (&mut f, &rf)] {
        finish(r, ds, run);
    }
    c.max_rel_diff_vs_full = Some(worst);
    (c, f)
}

/// The whole evaluation: every mode over every seed.
#[derive(Clone, Debug, Serialize)]
pub struct Evaluation {
    pub scenario: String,
    pub gnss: bool,
    /// Zero-velocity updates gated by the autopilot's landed state.
    pub landed_state: bool,
    /// How many seeds were flown, and which.
    pub seeds: u64,
    pub seed_numbers: Vec<u64>,
    pub duration_s: f64,
    pub modes: BTreeMap<String, ModeSummary>,
}

/// Which seeds an evaluation flies.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Seeds {
    /// Seeds `1..=n`.
    UpTo(u64),
    /// One seed alone (a sweep's task: `cmsckf evaluate --seed K`).
    One(u64),
}

impl Seeds {
    pub fn numbers(&self) -> Vec<u64> {
        match *self {
            Seeds::UpTo(n) => (1..=n).collect(),
            Seeds::One(k) => vec![k],
        }
    }
}

/// What to evaluate.
#[derive(Clone, Debug)]
pub struct EvalSpec {
    pub scenario: String,
    pub modes: Vec<Mode>,
    pub seeds: Seeds,
    /// `None`: the scenario's own length.
    pub duration_s: Option<f64>,
    /// Fuse the simulated GNSS.
    pub gnss: bool,
    /// Gate zero-velocity updates by the autopilot's landed state, as
    /// beside ArduPilot or PX4; false: by the IMU and camera alone.
    pub landed_state: bool,
}

/// Where [`evaluate`] is: flights done of all it will fly, and what the
/// last one was.
#[derive(Clone, Debug)]
pub struct Progress {
    pub done: u64,
    pub total: u64,
    pub message: String,
}

/// The flights of one seed in every mode asked for, with what they were
/// flown on: what `cmsckf evaluate --flights-out` writes, so that seeds flown
/// apart (a sweep's tasks, on other machines) summarise, through [`merge`],
/// exactly as one [`evaluate`] over them all.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SeedFlights {
    pub scenario: String,
    pub gnss: bool,
    pub landed_state: bool,
    pub duration_s: f64,
    /// The modes asked for, in the order given.
    pub modes: Vec<Mode>,
    pub seed: u64,
    /// The daemon config and simulator settings flown with (JSON), and the
    /// build: seeds flown with other ones are not one evaluation.
    pub setup: String,
    /// In the order [`evaluate`] flies them.
    pub flights: Vec<FlightResult>,
}

/// The setup a seed is flown with, as [`SeedFlights::setup`] records it.
fn setup_of(cfg: &Config, sim: &SimConfig) -> String {
    serde_json::json!({
        "config": cfg,
        "sim": sim,
        "build": env!("CARGO_PKG_VERSION"),
    })
    .to_string()
}

impl SeedFlights {
    /// Refuses flights that do not hold together, which would otherwise
    /// panic the summary: one flight per mode asked for, every series of a
    /// flight as long as its times, and at least one frame.
    pub fn check(&self) -> Result<(), MergeError> {
        let bad = |why: String| Err(MergeError::Malformed { seed: self.seed, why });
        let mut modes: Vec<Mode> = self.flights.iter().map(|f| f.mode).collect();
        modes.sort();
        let mut asked = self.modes.clone();
        asked.sort();
        asked.dedup();
        if modes != asked {
            return bad(format!(
                "its flights are in modes {modes:?}, one each of {:?} was asked for",
                self.modes
            ));
        }
        for f in &self.flights {
            let n = f.t_s.len();
            let lens = [
                ("p_est", f.p_est.len()),
                ("q_est", f.q_est.len()),
                ("cov_pose", f.cov_pose.len()),
                ("p_true", f.p_true.len()),
                ("q_true", f.q_true.len()),
                ("v_est", f.v_est.len()),
                ("v_true", f.v_true.len()),
                ("cov_vel", f.cov_vel.len()),
            ];
            if n == 0 {
                return bad(format!("its {} flight has no frame", f.mode.name()));
            }
            if let Some((name, len)) = lens.iter().find(|(_, len)| *len != n) {
                return bad(format!("its {} flight has {len} {name} for {n} times", f.mode.name()));
            }
        }
        Ok(())
    }
}

/// Why seeds flown apart cannot be summarised together.
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    #[error("nothing to merge: give the --flights-out files of at least one seed")]
    Empty,
    #[error(
        "seed {seed} was flown on {field} {theirs}, the first file on {ours}: merge only the seeds of one evaluation"
    )]
    Mismatch {
        seed: u64,
        field: &'static str,
        ours: String,
        theirs: String,
    },
    #[error("seed {0} is given twice: a sweep keeps one result per seed")]
    Duplicate(u64),
    #[error("seed {seed} was flown with another config, simulator settings or build than the first seed: merge only the seeds of one evaluation")]
    OtherSetup { seed: u64 },
    #[error("seed {seed}: {why}: not a file `cmsckf evaluate --flights-out` wrote; fly that seed again")]
    Malformed { seed: u64, why: String },
}

/// Flies one seed in every mode of `spec`. When both `full` and `compressed`
/// are asked for they run in lockstep, and compressed reports its largest
/// difference from full. `flown` hears of each flight as it ends.
pub fn fly_seed(
    spec: &EvalSpec,
    cfg: &Config,
    sim: &SimConfig,
    seed: u64,
    mut flown: impl FnMut(String),
) -> Result<SeedFlights, cmsckf_sitl::trajectory::TrajectoryError> {
    let inputs = Inputs {
        gnss: spec.gnss,
        landed_state: spec.landed_state,
    };
    let ds = Dataset::generate(&spec.scenario, seed, spec.duration_s, sim)?;
    let modes = &spec.modes[..];
    let lockstep = modes.contains(&Mode::Full) && modes.contains(&Mode::Compressed);
    let mut flights = Vec::with_capacity(modes.len());
    if lockstep {
        let (c, f) = compressed_vs_full_with(&ds, cfg, seed, inputs);
        flown(format!(
            "seed {seed}: compressed vs full max rel diff {:.2e}",
            c.max_rel_diff_vs_full.unwrap_or(0.0)
        ));
        flights.push(c);
        flights.push(f);
    }
    for &m in modes {
        if lockstep && (m == Mode::Full || m == Mode::Compressed) {
            continue;
        }
        flights.push(run_with(&ds, cfg, m, seed, inputs));
        flown(format!("seed {seed}: {}", m.name()));
    }
    Ok(SeedFlights {
        scenario: spec.scenario.clone(),
        gnss: spec.gnss,
        landed_state: spec.landed_state,
        duration_s: ds.duration_s,
        modes: modes.to_vec(),
        seed,
        setup: setup_of(cfg, sim),
        flights,
    })
}

/// Flies `spec`'s modes over its seeds and summarises them. `progress`
/// hears of each flight as it ends.
pub fn evaluate(
    spec: &EvalSpec,
    cfg: &Config,
    sim: &SimConfig,
    mut progress: impl FnMut(&Progress),
) -> Result<Evaluation, cmsckf_sitl::trajectory::TrajectoryError> {
    let seeds = spec.seeds.numbers();
    let lockstep = spec.modes.contains(&Mode::Full) && spec.modes.contains(&Mode::Compressed);
    let per_seed = spec.modes.len() as u64 - u64::from(lockstep);
    let mut p = Progress {
        done: 0,
        total: seeds.len() as u64 * per_seed,
        message: String::new(),
    };
    let mut flown = Vec::with_capacity(seeds.len());
    for &seed in &seeds {
        flown.push(fly_seed(spec, cfg, sim, seed, |message| {
            p.done += 1;
            p.message = message;
            progress(&p);
        })?);
    }
    Ok(summarise_seeds(flown))
}

/// Summarises seeds flown apart (each [`fly_seed`]'s result, in any
/// order) exactly as one [`evaluate`] over those seeds: the flights are put
/// in seed order first, as `evaluate` flies them.
pub fn merge(mut seeds: Vec<SeedFlights>) -> Result<Evaluation, MergeError> {
    seeds.sort_by_key(|s| s.seed);
    let first = seeds.first().ok_or(MergeError::Empty)?;
    for (i, s) in seeds.iter().enumerate() {
        if i > 0 && seeds[i - 1].seed == s.seed {
            return Err(MergeError::Duplicate(s.seed));
        }
        let differs = |field: &'static str, ours: String, theirs: String| {
            (ours != theirs).then_some(MergeError::Mismatch {
                seed: s.seed,
                field,
                ours,
                theirs,
            })
        };
        let modes = |m: &[Mode]| m.iter().map(|m| m.name()).collect::<Vec<_>>().join(",");
        let checks = [
            differs("scenario", first.scenario.clone(), s.scenario.clone()),
            differs("gnss", first.gnss.to_string(), s.gnss.to_string()),
            differs(
                "landed_state",
                first.landed_state.to_string(),
                s.landed_state.to_string(),
            ),
            differs("duration_s", first.duration_s.to_string(), s.duration_s.to_string()),
            differs("modes", modes(&first.modes), modes(&s.modes)),
        ];
        if let Some(e) = checks.into_iter().flatten().next() {
            return Err(e);
        }
        if s.setup != first.setup {
            return Err(MergeError::OtherSetup { seed: s.seed });
        }
        s.check()?;
    }
    Ok(summarise_seeds(seeds))
}

/// The evaluation of seeds already flown, in the order given.
fn summarise_seeds(seeds: Vec<SeedFlights>) -> Evaluation {
    let mut per_mode: BTreeMap<Mode, Vec<FlightResult>> = BTreeMap::new();
    let (mut scenario, mut gnss, mut landed_state, mut duration_s) = (String::new(), false, true, 0.0);
    let mut seed_numbers = Vec::with_capacity(seeds.len());
    for s in seeds {
        (scenario, gnss, landed_state, duration_s) = (s.scenario, s.gnss, s.landed_state, s.duration_s);
        seed_numbers.push(s.seed);
        for f in s.flights {
            per_mode.entry(f.mode).or_default().push(f);
        }
    }
    Evaluation {
        scenario,
        gnss,
        landed_state,
        seeds: seed_numbers.len() as u64,
        seed_numbers,
        duration_s,
        modes: per_mode
            .iter()
            .map(|(m, runs)| (m.name().to_string(), summarise(runs)))
            .collect(),
    }
}
