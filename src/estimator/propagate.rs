//! IMU propagation of the nominal state (RK4), the error-state transition
//! `F` and the discrete process noise `Q` (README.md §2).
//!
//! Error state of the IMU, in this order (15): `[δθ, δv, δp, δb_g, δb_a]`,
//! with the world-frame (left) rotation perturbation `R = Exp(δθ) R̂`.
//!
//! The filter's side of it is here too: buffering IMU samples, stepping the
//! nominal state and the clock through them (the covariance step itself is
//! `covariance.rs`'s), and the low-latency prediction the outputs use.

use crate::counters::Counter;
use nalgebra::{Matrix3, SMatrix, UnitQuaternion, Vector3};

use super::math::{exp_so3, skew};
use cmsckf_models::sensors::ImuConfig;

use super::{Estimator, InputError, MatActive, ACTIVE_DIM, BARO, CLK_B, CLK_D, CLK_E, IMU_BUFFER_CAP, ISB_SYSTEMS};

pub type Mat15 = SMatrix<f64, 15, 15>;

/// Offsets of the IMU error-state blocks.
pub const TH: usize = 0;
pub const V: usize = 3;
pub const P: usize = 6;
pub const BG: usize = 9;
pub const BA: usize = 12;
pub const IMU_DIM: usize = 15;

/// Nominal IMU state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuState {
    pub q_W_B: UnitQuaternion<f64>,
    pub v_B_in_W: Vector3<f64>,
    pub p_B_in_W: Vector3<f64>,
    pub b_g: Vector3<f64>,
    pub b_a: Vector3<f64>,
}

/// One IMU measurement in the body frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuMeas {
    pub t_s: f64,
    pub accel_mps2: Vector3<f64>,
    pub gyro_radps: Vector3<f64>,
}

impl ImuMeas {
    /// Linear interpolation between two samples at time `t_s`.
    pub fn lerp(a: &ImuMeas, b: &ImuMeas, t_s: f64) -> ImuMeas {
        let span = b.t_s - a.t_s;
        let f = if span > 0.0 {
            ((t_s - a.t_s) / span).clamp(0.0, 1.0)
        } else {
            1.0
        };
        ImuMeas {
            t_s,
            accel_mps2: a.accel_mps2 + (b.accel_mps2 - a.accel_mps2) * f,
            gyro_radps: a.gyro_radps + (b.gyro_radps - a.gyro_radps) * f,
        }
    }
}

/// One IMU step's bias-corrected specific force at its start, middle and
/// end, and the attitude at each: the rotation over each half step with the
/// mean rate of that half. [`integrate`] and [`transition`] both stand on
/// it, so the nominal state and its transition cannot drift apart.
struct HalfSteps {
    dt: f64,
    a0: Vector3<f64>,
    ah: Vector3<f64>,
    a1: Vector3<f64>,
    q0: UnitQuaternion<f64>,
    qh: UnitQuaternion<f64>,
    q1: UnitQuaternion<f64>,
}

/// [`HalfSteps`] of the step from `m0` to `m1`, the biases of `x` removed.
fn half_steps(x: &ImuState, m0: &ImuMeas, m1: &ImuMeas) -> HalfSteps {
    let dt = m1.t_s - m0.t_s;
    let w0 = m0.gyro_radps - x.b_g;
    let w1 = m1.gyro_radps - x.b_g;
    let wh = (w0 + w1) * 0.5;
    let a0 = m0.accel_mps2 - x.b_a;
    let a1 = m1.accel_mps2 - x.b_a;
    let ah = (a0 + a1) * 0.5;
    // Rotation over each half step with the mean rate of that half.
    let q0 = x.q_W_B;
    let qh = q0 * exp_so3(&((w0 + wh) * (0.25 * dt)));
    let q1 = qh * exp_so3(&((wh + w1) * (0.25 * dt)));
    HalfSteps {
        dt,
        a0,
        ah,
        a1,
        q0,
        qh,
        q1,
    }
}

/// Integrates the nominal state from `m0.t_s` to `m1.t_s` with RK4
/// (README §2, eq. N1), the measurements linearly interpolated in between:
/// `Ṙ = R [ω_m − b_g]×`, `v̇ = R (a_m − b_a) + g`, `ṗ = v`.
pub fn integrate(x: &ImuState, m0: &ImuMeas, m1: &ImuMeas, g_W: &Vector3<f64>) -> ImuState {
    let HalfSteps {
        dt,
        a0,
        ah,
        a1,
        q0,
        qh,
        q1,
    } = half_steps(x, m0, m1);
    let acc = |q: &UnitQuaternion<f64>, a: &Vector3<f64>| q * a + g_W;
    let k1v = acc(&q0, &a0);
    let k1p = x.v_B_in_W;
    let k2v = acc(&qh, &ah);
    let k2p = x.v_B_in_W + k1v * (0.5 * dt);
    let k3v = k2v;
    let k3p = x.v_B_in_W + k2v * (0.5 * dt);
    let k4v = acc(&q1, &a1);
    let k4p = x.v_B_in_W + k3v * dt;
    ImuState {
        q_W_B: q1,
        v_B_in_W: x.v_B_in_W + (k1v + k2v * 2.0 + k3v * 2.0 + k4v) * (dt / 6.0),
        p_B_in_W: x.p_B_in_W + (k1p + k2p * 2.0 + k3p * 2.0 + k4p) * (dt / 6.0),
        b_g: x.b_g,
        b_a: x.b_a,
    }
}

/// Error-state transition and discrete noise over one step (README §2,
/// eqs. F1–F3 and Q1). Continuous model: `δθ̇ = −R δb_g − R n_g`,
/// `δv̇ = −[R a]× δθ − R δb_a − R n_a`, `δṗ = δv`, `δḃ_g = n_wg`,
/// `δḃ_a = n_wa`. The transition's blocks are the exact integrals of this
/// model along the step, `F_vθ = −[∫R a]×`, `F_pθ = −[∫(Δt−τ) R a]×`,
/// `F_θb_g = F_vb_a = −∫R`, …, evaluated with Simpson's rule on the start,
/// middle and end of the step.
pub fn transition(x: &ImuState, m0: &ImuMeas, m1: &ImuMeas, imu: &ImuConfig) -> (Mat15, Mat15) {
    let HalfSteps {
        dt,
        a0,
        ah,
        a1,
        q0,
        qh,
        q1,
    } = half_steps(x, m0, m1);
    let (r0, rh, r1) = (
        q0.to_rotation_matrix().into_inner(),
        qh.to_rotation_matrix().into_inner(),
        q1.to_rotation_matrix().into_inner(),
    );
    let (f0, fh, f1) = (r0 * a0, rh * ah, r1 * a1);
    // ∫R, ∫R a, ∫(Δt−τ) R, ∫(Δt−τ) R a over the step (Simpson).
    let int_r = (r0 + rh * 4.0 + r1) * (dt / 6.0);
    let int_ra = (f0 + fh * 4.0 + f1) * (dt / 6.0);
    let int2_r = (r0 * dt + rh * (2.0 * dt)) * (dt / 6.0);
    let int2_ra = (f0 * dt + fh * (2.0 * dt)) * (dt / 6.0);
    // g(τ) = [R a]×(τ) ∫₀^τ R: the velocity response to a gyro-bias error.
    let g_h = skew(&fh) * ((r0 + rh) * (0.25 * dt));
    let g_1 = skew(&f1) * int_r;
    let f_vbg = (g_h * 4.0 + g_1) * (dt / 6.0);
    let f_pbg = g_h * (dt * dt / 3.0);
    let mut f = Mat15::identity();
    f.fixed_view_mut::<3, 3>(TH, BG).copy_from(&(-int_r));
    f.fixed_view_mut::<3, 3>(V, TH).copy_from(&(-skew(&int_ra)));
    f.fixed_view_mut::<3, 3>(V, BG).copy_from(&f_vbg);
    f.fixed_view_mut::<3, 3>(V, BA).copy_from(&(-int_r));
    f.fixed_view_mut::<3, 3>(P, TH).copy_from(&(-skew(&int2_ra)));
    f.fixed_view_mut::<3, 3>(P, V)
        .copy_from(&(nalgebra::Matrix3::identity() * dt));
    f.fixed_view_mut::<3, 3>(P, BG).copy_from(&f_pbg);
    f.fixed_view_mut::<3, 3>(P, BA).copy_from(&(-int2_r));
    // Q = ∫ F(τ) G Qc Gᵀ F(τ)ᵀ dτ, to the leading order of each block.
    let sg2 = imu.gyro_noise_density.powi(2);
    let sa2 = imu.accel_noise_density.powi(2);
    let swg2 = imu.gyro_random_walk.powi(2);
    let swa2 = imu.accel_random_walk.powi(2);
    let mut q = Mat15::zeros();
    for i in 0..3 {
        q[(TH + i, TH + i)] = sg2 * dt;
        q[(V + i, V + i)] = sa2 * dt;
        q[(P + i, P + i)] = sa2 * dt * dt * dt / 3.0;
        q[(P + i, V + i)] = sa2 * dt * dt / 2.0;
        q[(V + i, P + i)] = sa2 * dt * dt / 2.0;
        q[(BG + i, BG + i)] = swg2 * dt;
        q[(BA + i, BA + i)] = swa2 * dt;
    }
    (f, q)
}

/// The blocks of `F − I` that [`transition`] fills (eq. F2), as (row,
/// column) offsets: the attitude's response to the gyro bias, the
/// velocity's to the attitude and both biases, the position's to the
/// attitude, the velocity and both biases. Every other block of `F` is the
/// identity's.
pub const TRANSITION_BLOCKS: [(usize, usize); 8] =
    [(TH, BG), (V, TH), (V, BG), (V, BA), (P, TH), (P, V), (P, BG), (P, BA)];

/// One step's transition of the active block (§2, eqs. F2 and K1) kept as
/// what it is: the identity plus the IMU's eight 3×3 blocks
/// ([`TRANSITION_BLOCKS`]) and the clock's `∂b/∂d = Δt`. `F X` then costs
/// 8 × 9 multiply-adds a column instead of a dense product's 22 × 22: the
/// covariance step runs at every IMU sample (400 Hz on OpenVINS's
/// simulator), where the dense products were a quarter of the estimator's
/// time (issue 43's profile, docs/performance.md).
#[derive(Clone, Copy, Debug)]
pub struct ActiveTransition {
    pub imu: [Matrix3<f64>; 8],
    pub clock_dt_s: f64,
}

impl ActiveTransition {
    /// Reads the blocks of an IMU transition `f15` (zero elsewhere off the
    /// identity, as [`transition`] builds it) and the step's `Δt`.
    pub fn new(f15: &Mat15, dt_s: f64) -> Self {
        Self {
            imu: TRANSITION_BLOCKS.map(|(r, c)| f15.fixed_view::<3, 3>(r, c).into_owned()),
            clock_dt_s: dt_s,
        }
    }

    /// `F X` (`X` has the active block's rows), without allocating:
    /// `(F X)_r = X_r + Σ_c N_rc X_c` over the blocks, and the clock bias's
    /// row gains `Δt` times the drift's.
    pub fn mul_left(&self, x: &MatActive) -> MatActive {
        let mut y = *x;
        for (&(r, c), b) in TRANSITION_BLOCKS.iter().zip(&self.imu) {
            for j in 0..ACTIVE_DIM {
                for i in 0..3 {
                    y[(r + i, j)] += b[(i, 0)] * x[(c, j)] + b[(i, 1)] * x[(c + 1, j)] + b[(i, 2)] * x[(c + 2, j)];
                }
            }
        }
        for j in 0..ACTIVE_DIM {
            y[(CLK_B, j)] += self.clock_dt_s * x[(CLK_D, j)];
        }
        y
    }

    /// The dense `F` (for the tests).
    #[cfg(test)]
    pub fn dense(&self) -> MatActive {
        self.mul_left(&MatActive::identity())
    }
}

/// Samples further apart than this (s) leave a gap: the samples at its ends
/// say nothing of the motion in between (a 20 Hz IMU, 50 ms apart with
/// jitter, still samples it).
pub const MAX_SAMPLED_STEP_S: f64 = 0.06;
/// A gap this long (s) or longer leaves the poses off by more than the
/// tracks across it can be judged against at once: the monitor's vision
/// checks wait their grace period from its end (§9). Shorter gaps, however
/// many, never hold the monitor off.
pub const GAP_GRACE_MIN_S: f64 = 0.25;

/// The motion an IMU gap hides (eq. N3): over a gap of 1 s the body rate
/// and the specific force differ from their interpolation by a vehicle's
/// own manoeuvring, `σ_ω` and `σ_a`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GapNoise {
    pub sigma_rate_radps: f64,
    pub sigma_accel_mps2: f64,
}

/// Adds to the `Q` of a step of `dt_s` within a gap of `gap_s` (samples
/// more than [`MAX_SAMPLED_STEP_S`] apart) the motion the gap hides (README
/// §2, eq. N3): rate and specific-force errors of the interpolation, `σ_ω`
/// and `σ_a`, held over the gap, turn the attitude by `σ_ω S` and move the
/// velocity by `σ_a S` over the whole gap `S`; each step takes its share
/// `dt/S` of that variance, so that a gap split at a frame's time adds up to
/// the whole: Q1's form with densities `σ_ω² S` and `σ_a² S`,
/// `Q_θθ += σ_ω² S dt`, `Q_vv += σ_a² S dt`, `Q_pv += σ_a² S dt²/2`,
/// `Q_pp += σ_a² S dt³/3`. Without it a 1 s gap
/// bridged by interpolation left 6–10° of tilt error under a 0.25° sigma,
/// and the frames after it tripped the divergence monitor, restart after
/// restart.
pub fn add_gap_noise(q: &mut Mat15, dt_s: f64, gap_s: f64, gap: &GapNoise) {
    let t = dt_s;
    let (qw, qa) = (
        gap.sigma_rate_radps.powi(2) * gap_s,
        gap.sigma_accel_mps2.powi(2) * gap_s,
    );
    for i in 0..3 {
        q[(TH + i, TH + i)] += qw * t;
        q[(V + i, V + i)] += qa * t;
        q[(P + i, V + i)] += qa * t * t / 2.0;
        q[(V + i, P + i)] += qa * t * t / 2.0;
        q[(P + i, P + i)] += qa * t * t * t / 3.0;
    }
}

/// The error `x_true ⊖ x_est` in the IMU error-state order.
pub fn boxminus(x_true: &ImuState, x_est: &ImuState) -> SMatrix<f64, 15, 1> {
    let mut e = SMatrix::<f64, 15, 1>::zeros();
    e.fixed_rows_mut::<3>(TH)
        .copy_from(&(x_true.q_W_B * x_est.q_W_B.inverse()).scaled_axis());
    e.fixed_rows_mut::<3>(V).copy_from(&(x_true.v_B_in_W - x_est.v_B_in_W));
    e.fixed_rows_mut::<3>(P).copy_from(&(x_true.p_B_in_W - x_est.p_B_in_W));
    e.fixed_rows_mut::<3>(BG).copy_from(&(x_true.b_g - x_est.b_g));
    e.fixed_rows_mut::<3>(BA).copy_from(&(x_true.b_a - x_est.b_a));
    e
}

/// `x ⊕ δx` for the IMU block.
pub fn boxplus(x: &ImuState, d: &[f64]) -> ImuState {
    let v3 = |o: usize| Vector3::new(d[o], d[o + 1], d[o + 2]);
    ImuState {
        q_W_B: exp_so3(&v3(TH)) * x.q_W_B,
        v_B_in_W: x.v_B_in_W + v3(V),
        p_B_in_W: x.p_B_in_W + v3(P),
        b_g: x.b_g + v3(BG),
        b_a: x.b_a + v3(BA),
    }
}

impl Estimator {
    /// Queues an IMU sample; it is integrated when a frame or a query needs
    /// it. Non-finite or non-increasing samples are rejected.
    pub(super) fn queue_imu(&mut self, m: ImuMeas) -> Result<(), InputError> {
        if !(m.t_s.is_finite()
            && m.accel_mps2.iter().all(|v| v.is_finite())
            && m.gyro_radps.iter().all(|v| v.is_finite()))
        {
            *self.stats.rejected.entry(Counter::ImuNonFinite).or_default() += 1;
            return Err(InputError::NonFiniteImu(m.t_s));
        }
        let prev = self
            .imu_buf
            .back()
            .map(|b| b.t_s)
            .or(self.last_meas.map(|l| l.t_s))
            .unwrap_or(f64::NEG_INFINITY);
        if m.t_s <= prev {
            *self.stats.rejected.entry(Counter::ImuTimeBackwards).or_default() += 1;
            return Err(InputError::ImuTimeBackwards {
                t_s: m.t_s,
                prev_s: prev,
            });
        }
        self.stats.imu_samples += 1;
        if self.rate_history.len() == super::RATE_HISTORY_CAP {
            self.rate_history.pop_front();
        }
        self.rate_history.push_back((m.t_s, m.gyro_radps));
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
            *self.stats.rejected.entry(Counter::ImuOverflow).or_default() += 1;
            res = Err(InputError::ImuOverflow(IMU_BUFFER_CAP));
        }
        self.imu_buf.push_back(m);
        res
    }

    /// Integrates one step from the last measurement to `m` (§2): the
    /// nominal state, the IMU covariance block and the accumulated
    /// transition. No allocation.
    ///
    /// `spacing_s` is the time between the real samples that the step lies
    /// between: beyond [`MAX_SAMPLED_STEP_S`] the step is (part of) a gap.
    pub(super) fn step(&mut self, m: ImuMeas, spacing_s: f64) {
        let Some(m0) = self.last_meas else {
            self.last_meas = Some(m);
            return;
        };
        if m.t_s <= m0.t_s {
            return;
        }
        let (mut f15, mut q15) = transition(&self.imu, &m0, &m, &self.s.imu);
        // The clock: bias integrates drift, both random walks (§8, eq. K1).
        let dt = m.t_s - m0.t_s;
        if spacing_s > MAX_SAMPLED_STEP_S {
            add_gap_noise(&mut q15, dt, spacing_s, &self.s.imu_gap);
            if spacing_s >= GAP_GRACE_MIN_S {
                // The tracks the gap spans are judged again once the updates
                // have had the grace period to pull the poses it left off
                // back in (§9; the GNSS and the state's sanity are judged
                // throughout).
                self.vision_grace_from_s = self.vision_grace_from_s.max(m.t_s);
            }
        }
        // First-estimate Jacobians (§3d, eq. F5): the step's velocity and
        // position increments measured from the values before the last
        // updates, `F_vθ = −[v₁ − v₀^FE − g Δt]×`,
        // `F_pθ = −[p₁ − p₀^FE − v₀^FE Δt − ½ g Δt²]×`: the updates'
        // corrections `δv`, `δp` join the brackets.
        if self.fej_dv != Vector3::zeros() || self.fej_dp != Vector3::zeros() {
            let dv = self.fej_dv;
            let dp = self.fej_dp + self.fej_dv * dt;
            let fv = f15.fixed_view::<3, 3>(V, TH) - skew(&dv);
            let fp = f15.fixed_view::<3, 3>(P, TH) - skew(&dp);
            f15.fixed_view_mut::<3, 3>(V, TH).copy_from(&fv);
            f15.fixed_view_mut::<3, 3>(P, TH).copy_from(&fp);
            self.fej_dv = Vector3::zeros();
            self.fej_dp = Vector3::zeros();
        }
        let f = ActiveTransition::new(&f15, dt);
        let mut q = MatActive::zeros();
        q.fixed_view_mut::<15, 15>(0, 0).copy_from(&q15);
        let (qb, qd) = (self.s.clock_bias_rw.powi(2), self.s.clock_drift_rw.powi(2));
        q[(CLK_B, CLK_B)] = qb * dt + qd * dt * dt * dt / 3.0;
        q[(CLK_B, CLK_D)] = qd * dt * dt / 2.0;
        q[(CLK_D, CLK_B)] = qd * dt * dt / 2.0;
        q[(CLK_D, CLK_D)] = qd * dt;
        for k in 0..ISB_SYSTEMS.len() {
            q[(CLK_E + k, CLK_E + k)] = self.s.isb_rw.powi(2) * dt;
        }
        // The barometer's offset walks (§3g, B1).
        q[(BARO, BARO)] = self.s.baro.offset_rw_m_per_sqrt_s.powi(2) * dt;
        self.still.push(&m, dt, &self.imu, &self.g_W);
        self.imu = integrate(&self.imu, &m0, &m, &self.g_W);
        self.clock.x += self.clock.y * dt;
        self.propagate_covariance(&f, &q);
        self.t_s = m.t_s;
        self.last_meas = Some(m);
    }

    /// Propagates the filter to `t_s` through the buffered samples,
    /// interpolating the last one (or holding it if none is later). On the
    /// way it clones the state at each instant a GNSS epoch is expected
    /// (§8b), and marginalises the clones whose epochs never came.
    pub(super) fn propagate_filter_to(&mut self, t_s: f64) {
        let oldest_useful = t_s - self.s.gnss_max_delay_s;
        while let Some(g) = self.gnss_grid.as_mut() {
            let tc = g.next_s;
            if tc > t_s {
                break;
            }
            if tc < oldest_useful {
                // Instants the filter jumps over by more than the delay
                // bound (a gap in the IMU) are not cloned: their epochs
                // would be refused as late anyway.
                g.next_s = tc + g.period_s * ((oldest_useful - tc) / g.period_s).ceil().max(1.0);
                continue;
            }
            g.next_s = tc + g.period_s;
            self.propagate_through(tc);
            self.take_gnss_clone(tc);
        }
        self.propagate_through(t_s);
        self.drop_stale_gnss_clones();
    }

    /// Propagates the filter to `t_s` through the buffered samples,
    /// interpolating the last one (or holding it if none is later).
    fn propagate_through(&mut self, t_s: f64) {
        while let Some(&m) = self.imu_buf.front() {
            if m.t_s > t_s {
                break;
            }
            self.imu_buf.pop_front();
            let spacing_s = m.t_s - self.last_sample_t_s;
            self.last_sample_t_s = m.t_s;
            self.step(m, spacing_s);
        }
        if t_s > self.t_s {
            if let Some(last) = self.last_meas {
                // Part of the step to the next sample, or, with none yet, the
                // last one held.
                let (m, next_t_s) = match self.imu_buf.front() {
                    Some(next) => (ImuMeas::lerp(&last, next, t_s), next.t_s),
                    None => (ImuMeas { t_s, ..last }, t_s),
                };
                self.step(m, next_t_s - self.last_sample_t_s);
            } else {
                self.t_s = t_s;
            }
        }
    }

    /// The body state predicted to `t_s` through the buffered IMU samples,
    /// without changing the filter (for low-latency output).
    pub(super) fn predict_imu_state(&self, t_s: f64) -> ImuState {
        let mut x = self.imu;
        let Some(mut last) = self.last_meas else {
            return x;
        };
        for m in self.imu_buf.iter() {
            let target = if m.t_s > t_s { ImuMeas::lerp(&last, m, t_s) } else { *m };
            if target.t_s > last.t_s {
                x = integrate(&x, &last, &target, &self.g_W);
            }
            last = target;
            if m.t_s >= t_s {
                return x;
            }
        }
        if t_s > last.t_s {
            x = integrate(&x, &last, &ImuMeas { t_s, ..last }, &self.g_W);
        }
        x
    }

    /// Brings the filter to a measurement at `t_s`, which must not be in
    /// its past (else it is counted under `counter` and refused).
    pub(super) fn advance_to(&mut self, t_s: f64, counter: Counter) -> Result<(), InputError> {
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
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// A moving, turning state with biases: the fixture of the IMU and GNSS
    /// model tests.
    pub(in crate::estimator) fn state() -> ImuState {
        ImuState {
            q_W_B: UnitQuaternion::from_euler_angles(0.2, -0.3, 1.1),
            v_B_in_W: Vector3::new(12.0, -3.0, 0.5),
            p_B_in_W: Vector3::new(100.0, 20.0, -5.0),
            b_g: Vector3::new(0.01, -0.02, 0.005),
            b_a: Vector3::new(0.1, -0.05, 0.2),
        }
    }

    /// An IMU measurement of that motion at `t_s`.
    pub(in crate::estimator) fn meas(t_s: f64) -> ImuMeas {
        ImuMeas {
            t_s,
            accel_mps2: Vector3::new(1.0, 2.5, -9.0),
            gyro_radps: Vector3::new(0.3, -0.4, 0.8),
        }
    }

    /// F against finite differences: perturb the start state along each
    /// error direction, integrate, and take the error at the end.
    #[test]
    fn transition_matches_finite_differences() {
        let x = ImuState {
            q_W_B: UnitQuaternion::from_euler_angles(0.2, -0.3, 1.1),
            v_B_in_W: Vector3::new(12.0, -3.0, 0.5),
            p_B_in_W: Vector3::new(100.0, 20.0, -5.0),
            b_g: Vector3::new(0.01, -0.02, 0.005),
            b_a: Vector3::new(0.1, -0.05, 0.2),
        };
        let g = Vector3::new(0.0, 0.0, 9.81);
        let m0 = ImuMeas {
            t_s: 0.0,
            accel_mps2: Vector3::new(1.0, 2.5, -9.0),
            gyro_radps: Vector3::new(0.3, -0.4, 0.8),
        };
        let m1 = ImuMeas {
            t_s: 0.01,
            accel_mps2: Vector3::new(1.2, 2.2, -9.3),
            gyro_radps: Vector3::new(0.35, -0.38, 0.75),
        };
        let (f, _) = transition(&x, &m0, &m1, &ImuConfig::default());
        let x1 = integrate(&x, &m0, &m1, &g);
        let h = 1e-6;
        for k in 0..15 {
            let mut d = [0.0; 15];
            d[k] = h;
            let xp = integrate(&boxplus(&x, &d), &m0, &m1, &g);
            d[k] = -h;
            let xm = integrate(&boxplus(&x, &d), &m0, &m1, &g);
            let col = (boxminus(&xp, &x1) - boxminus(&xm, &x1)) / (2.0 * h);
            let err = (col - f.column(k)).amax();
            // Within 2e-7: the O(|ω|Δt²) right-Jacobian terms of ∂R/∂b_g are neglected.
            assert!(
                err < 2e-7,
                "column {k}: fd {:?} vs analytic {:?}",
                col.as_slice(),
                f.column(k).iter().collect::<Vec<_>>()
            );
        }
    }

    /// The structured transition is the dense one: [`transition`] fills
    /// only [`TRANSITION_BLOCKS`] off the identity (so nothing is dropped),
    /// and `F X` through the blocks equals the dense product, the clock's
    /// `Δt` included.
    #[test]
    fn structured_transition_equals_the_dense_product() {
        let x = state();
        let (f15, _) = transition(&x, &meas(0.0), &meas(0.0025), &ImuConfig::default());
        let mut rest = f15 - Mat15::identity();
        for (r, c) in TRANSITION_BLOCKS {
            rest.fixed_view_mut::<3, 3>(r, c).fill(0.0);
        }
        assert_eq!(rest.amax(), 0.0, "transition fills a block outside TRANSITION_BLOCKS");
        let dt = 0.0025;
        let f = ActiveTransition::new(&f15, dt);
        let mut dense = MatActive::identity();
        dense.fixed_view_mut::<15, 15>(0, 0).copy_from(&f15);
        dense[(CLK_B, CLK_D)] = dt;
        assert_eq!(f.dense(), dense);
        let xm = MatActive::from_fn(|i, j| ((i * 7 + j * 13) % 11) as f64 - 5.0 + 0.1 * (i + j) as f64);
        let err = (f.mul_left(&xm) - dense * xm).amax();
        assert!(err <= 1e-12 * (dense * xm).amax(), "F X differs by {err}");
    }

    /// §3b, eq. T3: the body pose at `t + δt_d` moves by `[R ω_B; v] δt_d`.
    /// Finite differences of the integrated pose against that column.
    #[test]
    fn time_offset_column_matches_finite_differences() {
        let x = state();
        let g = Vector3::new(0.0, 0.0, 9.81);
        let m0 = meas(0.0);
        let h = 1e-5;
        let fwd = integrate(&x, &m0, &meas(h), &g);
        let bwd = integrate(&x, &m0, &meas(-h), &g);
        let d_th = (fwd.q_W_B * bwd.q_W_B.inverse()).scaled_axis() / (2.0 * h);
        let d_p = (fwd.p_B_in_W - bwd.p_B_in_W) / (2.0 * h);
        let w_W = x.q_W_B * (m0.gyro_radps - x.b_g);
        assert!((d_th - w_W).amax() < 1e-8, "rotation: fd {d_th:?} vs {w_W:?}");
        assert!(
            (d_p - x.v_B_in_W).amax() < 1e-8,
            "position: fd {d_p:?} vs {:?}",
            x.v_B_in_W
        );
    }
}
