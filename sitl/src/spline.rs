//! Uniform quintic B-splines in R³ and on SO(3).
//!
//! Every simulated trajectory, analytic or loaded from a file, ends up as one
//! pair of splines. That gives a single mechanism with exact analytic
//! derivatives: velocity and acceleration come from differentiating the basis
//! polynomials, and body angular velocity from the cumulative-spline recursion
//! of Sommer et al. (2020). A quintic (order 6) spline is C⁴, so specific force
//! and angular rate are continuous and consistent with the pose by
//! construction.

use nalgebra::{UnitQuaternion, Vector3};

/// Order of the spline (degree + 1).
pub const ORDER: usize = 6;

/// Basis matrix `M[j][n]`: the weight of control point `i+j` is
/// `B_j(u) = Σ_n M[j][n] uⁿ` on the segment `u ∈ [0,1)`.
fn basis_matrix() -> [[f64; ORDER]; ORDER] {
    // General uniform B-spline basis (Qin, 2000):
    // M[j][n] = C(k-1, n) / (k-1)! · Σ_{s=j}^{k-1} (-1)^{s-j} C(k, s-j) (k-1-s)^{k-1-n}
    let k = ORDER;
    let binom = |n: usize, r: usize| -> f64 {
        let mut v = 1.0;
        for i in 0..r {
            v = v * (n - i) as f64 / (i + 1) as f64;
        }
        v
    };
    let fact: f64 = (1..k).map(|x| x as f64).product();
    let mut m = [[0.0; ORDER]; ORDER];
    for (j, row) in m.iter_mut().enumerate() {
        for (n, cell) in row.iter_mut().enumerate() {
            let mut sum = 0.0;
            for s in j..k {
                let sign = if (s - j) % 2 == 0 { 1.0 } else { -1.0 };
                sum += sign * binom(k, s - j) * ((k - 1 - s) as f64).powi((k - 1 - n) as i32);
            }
            *cell = binom(k - 1, n) / fact * sum;
        }
    }
    m
}

/// Values of the basis (or cumulative basis) and its first two derivatives
/// with respect to `u`.
#[derive(Clone, Copy)]
struct Weights {
    w: [f64; ORDER],
    dw: [f64; ORDER],
    ddw: [f64; ORDER],
}

fn eval_weights(m: &[[f64; ORDER]; ORDER], u: f64) -> Weights {
    let mut pw = [0.0; ORDER];
    let mut dpw = [0.0; ORDER];
    let mut ddpw = [0.0; ORDER];
    for n in 0..ORDER {
        pw[n] = u.powi(n as i32);
        if n >= 1 {
            dpw[n] = n as f64 * u.powi(n as i32 - 1);
        }
        if n >= 2 {
            ddpw[n] = (n * (n - 1)) as f64 * u.powi(n as i32 - 2);
        }
    }
    let mut out = Weights {
        w: [0.0; ORDER],
        dw: [0.0; ORDER],
        ddw: [0.0; ORDER],
    };
    for j in 0..ORDER {
        for n in 0..ORDER {
            out.w[j] += m[j][n] * pw[n];
            out.dw[j] += m[j][n] * dpw[n];
            out.ddw[j] += m[j][n] * ddpw[n];
        }
    }
    out
}

/// Knot timing shared by both splines: control point `m` sits at time
/// `t0_s + m·dt_s`, and segment `i` (control points `i..i+5`) covers
/// `[t(i+2), t(i+3))`, so the curve follows its control points in time.
#[derive(Clone, Debug)]
struct Knots {
    t0_s: f64,
    dt_s: f64,
    n: usize,
}

impl Knots {
    /// Segment index and local parameter for time `t_s`, clamped to the
    /// valid range.
    fn locate(&self, t_s: f64) -> (usize, f64) {
        let s = (t_s - self.t0_s) / self.dt_s - 2.0;
        let max_seg = self.n - ORDER;
        if !s.is_finite() || s <= 0.0 {
            return (0, 0.0);
        }
        let i = s.floor() as usize;
        if i > max_seg {
            return (max_seg, 1.0);
        }
        (i, s - i as f64)
    }
    fn first_valid_s(&self) -> f64 {
        self.t0_s + 2.0 * self.dt_s
    }
    fn last_valid_s(&self) -> f64 {
        self.t0_s + (self.n - ORDER + 3) as f64 * self.dt_s
    }
}

/// Quintic B-spline in R³ with analytic derivatives.
#[derive(Clone, Debug)]
pub struct PositionSpline {
    knots: Knots,
    ctrl: Vec<Vector3<f64>>,
    m: [[f64; ORDER]; ORDER],
}

/// Position, velocity and acceleration at one time.
#[derive(Clone, Copy, Debug)]
pub struct PosSample {
    pub p: Vector3<f64>,
    pub v: Vector3<f64>,
    pub a: Vector3<f64>,
}

impl PositionSpline {
    /// Builds a spline whose control point `m` is at `t0_s + m·dt_s`.
    /// Needs at least `ORDER` control points.
    pub fn new(t0_s: f64, dt_s: f64, ctrl: Vec<Vector3<f64>>) -> Self {
        assert!(
            ctrl.len() >= ORDER && dt_s > 0.0,
            "spline needs ≥6 control points and dt > 0"
        );
        Self {
            knots: Knots {
                t0_s,
                dt_s,
                n: ctrl.len(),
            },
            ctrl,
            m: basis_matrix(),
        }
    }

    /// The time span over which the spline is defined.
    pub fn valid_range_s(&self) -> (f64, f64) {
        (self.knots.first_valid_s(), self.knots.last_valid_s())
    }

    pub fn eval(&self, t_s: f64) -> PosSample {
        let (i, u) = self.knots.locate(t_s);
        let wt = eval_weights(&self.m, u);
        let inv_dt = 1.0 / self.knots.dt_s;
        let mut out = PosSample {
            p: Vector3::zeros(),
            v: Vector3::zeros(),
            a: Vector3::zeros(),
        };
        for j in 0..ORDER {
            let c = &self.ctrl[i + j];
            out.p += c * wt.w[j];
            out.v += c * (wt.dw[j] * inv_dt);
            out.a += c * (wt.ddw[j] * inv_dt * inv_dt);
        }
        out
    }
}

/// Cumulative quintic B-spline on SO(3) (Kim et al. 1995; Sommer et al. 2020):
/// `R(t) = R_i · Π_{j=1..5} Exp(B̃_j(u) d_j)`, `d_j = Log(R_{i+j-1}ᵀ R_{i+j})`.
#[derive(Clone, Debug)]
pub struct RotationSpline {
    knots: Knots,
    ctrl: Vec<UnitQuaternion<f64>>,
    /// `d_j` for consecutive control points: `deltas[m] = Log(R_mᵀ R_{m+1})`.
    deltas: Vec<Vector3<f64>>,
    cm: [[f64; ORDER]; ORDER],
}

/// Orientation and body-frame angular velocity at one time.
#[derive(Clone, Copy, Debug)]
pub struct RotSample {
    pub q: UnitQuaternion<f64>,
    /// Angular velocity of the body, in the body frame (rad/s).
    pub w: Vector3<f64>,
}

impl RotationSpline {
    pub fn new(t0_s: f64, dt_s: f64, ctrl: Vec<UnitQuaternion<f64>>) -> Self {
        assert!(
            ctrl.len() >= ORDER && dt_s > 0.0,
            "spline needs ≥6 control points and dt > 0"
        );
        let m = basis_matrix();
        // Cumulative basis: B̃_j = Σ_{l≥j} B_l.
        let mut cm = [[0.0; ORDER]; ORDER];
        for j in 0..ORDER {
            for n in 0..ORDER {
                cm[j][n] = (j..ORDER).map(|l| m[l][n]).sum();
            }
        }
        let deltas = ctrl.windows(2).map(|w| (w[0].inverse() * w[1]).scaled_axis()).collect();
        Self {
            knots: Knots {
                t0_s,
                dt_s,
                n: ctrl.len(),
            },
            ctrl,
            deltas,
            cm,
        }
    }

    pub fn eval(&self, t_s: f64) -> RotSample {
        let (i, u) = self.knots.locate(t_s);
        let wt = eval_weights(&self.cm, u);
        let inv_dt = 1.0 / self.knots.dt_s;
        let mut q = self.ctrl[i];
        // ω⁽ʲ⁾ = Exp(-λ_j d_j) ω⁽ʲ⁻¹⁾ + λ̇_j d_j (body frame), ω⁽⁰⁾ = 0.
        let mut w = Vector3::zeros();
        for j in 1..ORDER {
            let d = self.deltas[i + j - 1];
            let a = UnitQuaternion::from_scaled_axis(d * wt.w[j]);
            q *= a;
            w = a.inverse_transform_vector(&w) + d * (wt.dw[j] * inv_dt);
        }
        RotSample { q, w }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_partition_of_unity_and_cubic_reference() {
        let m = basis_matrix();
        for u in [0.0, 0.3, 0.77, 0.999] {
            let w = eval_weights(&m, u);
            let s: f64 = w.w.iter().sum();
            assert!((s - 1.0).abs() < 1e-12, "sum {s}");
            assert!(w.dw.iter().sum::<f64>().abs() < 1e-12);
            assert!(w.w.iter().all(|&x| x >= -1e-15));
        }
        // At u = 0 the quintic weights are the known (1,26,66,26,1,0)/120.
        let w0 = eval_weights(&m, 0.0).w;
        let expect = [1.0, 26.0, 66.0, 26.0, 1.0, 0.0];
        for j in 0..ORDER {
            assert!((w0[j] - expect[j] / 120.0).abs() < 1e-14);
        }
    }

    #[test]
    fn continuity_across_segments() {
        let ctrl: Vec<_> = (0..20)
            .map(|k| {
                let t = k as f64 * 0.1;
                Vector3::new(t.sin(), (2.0 * t).cos(), t * t)
            })
            .collect();
        let s = PositionSpline::new(0.0, 0.1, ctrl);
        let knot = 0.5; // a segment boundary
        let a = s.eval(knot - 1e-9);
        let b = s.eval(knot + 1e-9);
        assert!((a.p - b.p).norm() < 1e-8);
        assert!((a.v - b.v).norm() < 1e-6);
        assert!((a.a - b.a).norm() < 1e-5);
    }

    #[test]
    fn derivatives_match_finite_differences() {
        let ctrl: Vec<_> = (0..30)
            .map(|k| {
                let t = k as f64 * 0.2;
                Vector3::new(3.0 * t.sin(), (0.7 * t).cos(), 0.1 * t * t)
            })
            .collect();
        let s = PositionSpline::new(0.0, 0.2, ctrl);
        let qctrl: Vec<_> = (0..30)
            .map(|k| {
                let t = k as f64 * 0.2;
                UnitQuaternion::from_euler_angles(0.3 * t.sin(), 0.2 * t, (1.3 * t).cos())
            })
            .collect();
        let r = RotationSpline::new(0.0, 0.2, qctrl);
        let h = 1e-5;
        for t in [0.6, 1.234, 2.0, 3.77, 4.9] {
            let (a, b, c) = (s.eval(t - h), s.eval(t), s.eval(t + h));
            let v_fd = (c.p - a.p) / (2.0 * h);
            let a_fd = (c.v - a.v) / (2.0 * h);
            assert!((v_fd - b.v).norm() < 1e-7, "v at {t}");
            assert!((a_fd - b.a).norm() < 1e-6, "a at {t}");
            let (ra, rb, rc) = (r.eval(t - h), r.eval(t), r.eval(t + h));
            let w_fd = (ra.q.inverse() * rc.q).scaled_axis() / (2.0 * h);
            assert!((w_fd - rb.w).norm() < 1e-7, "w at {t}: {w_fd} vs {}", rb.w);
        }
    }
}
