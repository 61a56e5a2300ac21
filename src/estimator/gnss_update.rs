//! The tightly coupled GNSS update, whole: pseudoranges and range rates
//! against satellite states from broadcast ephemerides (README.md §8): the
//! clock states' initialisation from the first epochs, the robust pre-screen
//! and χ² gate of each measurement, and their Jacobians; the update itself
//! goes through [`Estimator::ekf_update`].
//!
//! The receiver is at the body origin, `r = o + R_en p_B_in_W` in ECEF with
//! `o` the world origin and `R_en` the NED→ECEF rotation. Everything here
//! involves only active states (velocity, position, clock), so in compressed
//! mode it is a local update.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector, Matrix3, RowVector3, Vector3};

use cmsckf_models::geodesy::{ecef_to_llh, elevation_azimuth, NedFrame, C_MPS, OMEGA_E_RADPS};
use cmsckf_models::gnss::{saastamoinen_m, SatMeas, System};

use super::{math, Estimator, InputError, Stats, CLK_B, CLK_D, CLK_E, OUTLIER_SIGMAS};

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

/// Columns of `P` a GNSS measurement involves: velocity, position, clock
/// bias, drift, Galileo ISB.
const GNSS_COLS: [usize; 9] = [3, 4, 5, 6, 7, 8, CLK_B, CLK_D, CLK_E];

/// One whitened measurement row over [`GNSS_COLS`] and its residual.
type GnssRow = ([f64; 9], f64);

/// The median of the finite values (upper median), if any.
fn median(mut v: Vec<f64>) -> Option<f64> {
    v.retain(|x| x.is_finite());
    v.sort_by(|a, b| a.total_cmp(b));
    v.get(v.len() / 2).copied()
}

/// Code residuals of constellation `sys` at position `p` with clock `bias`.
fn code_residuals(frame: &NedFrame, sats: &[SatMeas], p: &Vector3<f64>, sys: System, bias: f64) -> Vec<f64> {
    sats.iter()
        .filter(|s| s.system == sys)
        .filter_map(|s| s.pseudorange_m.map(|z| z - pseudorange(frame, p, bias, s).0))
        .collect()
}

/// Counts a rejected GNSS measurement in the epoch's report and the stats.
fn reject(rep: &mut GnssReport, st: &mut Stats, why: &'static str) {
    *rep.rejected.entry(why).or_default() += 1;
    *st.rejected.entry(why).or_default() += 1;
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

    /// One GNSS epoch at `t_s` (§8): pseudoranges and range rates of the
    /// satellites in `sats`, against the world origin `frame`. GPS is the
    /// reference clock: the first epoch with GPS pseudoranges sets the bias
    /// and drift from the median residuals, and the first with Galileo ones
    /// sets the inter-system bias the same way; until then those
    /// measurements wait.
    pub fn process_gnss(&mut self, t_s: f64, frame: &NedFrame, sats: &[SatMeas]) -> Result<GnssReport, InputError> {
        self.advance_to(t_s, "gnss_time_backwards")?;
        let mut rep = GnssReport::default();
        if !self.init_clock_states(frame, sats, &mut rep) {
            return Ok(rep);
        }
        let rows = self.gnss_rows(frame, sats, &mut rep);
        let pr_rejected = rep.rejected.get("gnss_pseudorange_chi2").copied().unwrap_or(0)
            + rep.rejected.get("gnss_pseudorange_outlier").copied().unwrap_or(0);
        self.monitor.push_gnss(rep.pseudoranges_used, pr_rejected as usize);
        if rows.is_empty() {
            return Ok(rep);
        }
        let mut h = DMatrix::zeros(rows.len(), GNSS_COLS.len());
        let mut r = DVector::zeros(rows.len());
        for (i, (hr, rr)) in rows.iter().enumerate() {
            for k in 0..GNSS_COLS.len() {
                h[(i, k)] = hr[k];
            }
            r[i] = *rr;
        }
        self.ekf_update(&h, &GNSS_COLS, &r, false);
        self.stats.updates += 1;
        Ok(rep)
    }

    /// Sets the clock states the first time an epoch can (§8, eq. K4): GPS's
    /// bias and the drift from the median residuals of the first epoch with
    /// GPS codes, Galileo's inter-system bias from the first with Galileo
    /// ones. `false`: no GPS code yet, the epoch waits.
    fn init_clock_states(&mut self, frame: &NedFrame, sats: &[SatMeas], rep: &mut GnssReport) -> bool {
        let p = self.imu.p_B_in_W;
        let v = self.imu.v_B_in_W;
        if !self.clock_initialised {
            let Some(b) = median(code_residuals(frame, sats, &p, System::Gps, 0.0)) else {
                return false;
            };
            let d = median(
                sats.iter()
                    .filter_map(|s| s.range_rate_mps.map(|z| z - range_rate(frame, &p, &v, 0.0, s).0))
                    .collect(),
            )
            .unwrap_or(0.0);
            self.reset_clock_states(&[CLK_B, CLK_D], &[b, d], &[30.0f64.powi(2), 1.0]);
            self.clock_initialised = true;
            rep.clock_initialised = true;
        }
        if !self.isb_initialised {
            if let Some(isb) = median(code_residuals(frame, sats, &p, System::Galileo, self.clock.x)) {
                self.reset_clock_states(&[CLK_E], &[isb], &[30.0f64.powi(2)]);
                self.isb_initialised = true;
            }
        }
        true
    }

    /// The gated, whitened rows of an epoch's measurements. Robust
    /// pre-screen (K5): each constellation's median code residual stands for
    /// its clock error, so a code far from it is an outlier whatever the
    /// clock's variance (the χ² gate alone lets a 30 m multipath code through
    /// while the clock is still uncertain).
    fn gnss_rows(&mut self, frame: &NedFrame, sats: &[SatMeas], rep: &mut GnssReport) -> Vec<GnssRow> {
        let p = self.imu.p_B_in_W;
        let median_res = |sys: System| {
            median(code_residuals(
                frame,
                sats,
                &p,
                sys,
                self.clock.x + self.clock.z * f64::from(sys == System::Galileo),
            ))
        };
        let medians = [
            (System::Gps, median_res(System::Gps)),
            (System::Galileo, median_res(System::Galileo)),
        ];
        let mut p_sub = DMatrix::zeros(GNSS_COLS.len(), GNSS_COLS.len());
        math::gather_block(&self.P, &GNSS_COLS, &mut p_sub);
        let gate = cmsckf_models::stats::chi2_quantile(0.99, 1);
        let mut rows: Vec<GnssRow> = Vec::new();
        for s in sats {
            let median = medians.iter().find(|m| m.0 == s.system).and_then(|m| m.1);
            self.sat_rows(frame, s, median, &p_sub, gate, rep, &mut rows);
        }
        rows
    }

    /// One satellite's pseudorange and range-rate rows (K2, K3), gated;
    /// its residuals go to the report.
    #[allow(clippy::too_many_arguments)]
    fn sat_rows(
        &mut self,
        frame: &NedFrame,
        s: &SatMeas,
        median: Option<f64>,
        p_sub: &DMatrix<f64>,
        gate: f64,
        rep: &mut GnssReport,
        rows: &mut Vec<GnssRow>,
    ) {
        let (p, v) = (self.imu.p_B_in_W, self.imu.v_B_in_W);
        let isb = if s.system == System::Galileo { 1.0 } else { 0.0 };
        let (pr_pred, hp, el) = pseudorange(frame, &p, self.clock.x + isb * self.clock.z, s);
        if el < self.s.elevation_mask_deg.to_radians() {
            reject(rep, &mut self.stats, "gnss_below_mask");
            return;
        }
        let sin_el = el.sin().max(0.1);
        let mut res = (s.prn, None, None);
        if let Some(z) = s.pseudorange_m.filter(|z| z.is_finite()) {
            let sigma = ((self.s.pseudorange_sigma_m * s.noise_scale / sin_el).powi(2) + s.extra_var_m2).sqrt();
            // ∂P/∂[v, p, b, ḃ, isb] (K2): Galileo's code sees b + isb.
            let h = [0.0, 0.0, 0.0, hp[0], hp[1], hp[2], 1.0, 0.0, isb];
            let r = z - pr_pred;
            res.1 = Some(r);
            if median.is_some_and(|m| (r - m).abs() > OUTLIER_SIGMAS * sigma) {
                reject(rep, &mut self.stats, "gnss_pseudorange_outlier");
            } else if let Some(row) = gated(&h, r, sigma, p_sub, gate) {
                rows.push(row);
                rep.pseudoranges_used += 1;
            } else {
                reject(rep, &mut self.stats, "gnss_pseudorange_chi2");
            }
        }
        if let Some(z) = s.range_rate_mps.filter(|z| z.is_finite()) {
            let (pred, hv, hpr) = range_rate(frame, &p, &v, self.clock.y, s);
            let sigma = self.s.range_rate_sigma_mps / sin_el;
            let h = [hv[0], hv[1], hv[2], hpr[0], hpr[1], hpr[2], 0.0, 1.0, 0.0];
            let r = z - pred;
            res.2 = Some(r);
            if let Some(row) = gated(&h, r, sigma, p_sub, gate) {
                rows.push(row);
                rep.range_rates_used += 1;
            } else {
                reject(rep, &mut self.stats, "gnss_range_rate_chi2");
            }
        }
        rep.residuals.push(res);
    }
}

/// Predicted pseudorange (K2): `|r_s − r| + ω_e (x_s y − y_s x)/c + b − c·δt_s + T`,
/// with its Jacobians with respect to the position in the world frame and
/// the clock bias (1). Also returns the elevation.
pub fn pseudorange(
    frame: &NedFrame,
    p_B_in_W: &Vector3<f64>,
    clock_bias_m: f64,
    s: &SatMeas,
) -> (f64, RowVector3<f64>, f64) {
    let r = frame.to_ecef(p_B_in_W);
    let d = s.r_sat_ecef_m - r;
    let rho = d.norm();
    let u = d / rho;
    let sagnac = OMEGA_E_RADPS * (s.r_sat_ecef_m.x * r.y - s.r_sat_ecef_m.y * r.x) / C_MPS;
    let (el, _) = elevation_azimuth(&r, &s.r_sat_ecef_m);
    let (lat, _, h) = ecef_to_llh(&r);
    let trop = saastamoinen_m(lat, h, el);
    // ∂ρ/∂r = −uᵀ + (ω_e/c)(−y_s, x_s, 0); the troposphere varies with height
    // (down = −height), its slope taken by a ±1 m difference of the model; its
    // variation with elevation is below 1e-6 m/m and neglected.
    let drho = -u.transpose() + RowVector3::new(-s.r_sat_ecef_m.y, s.r_sat_ecef_m.x, 0.0) * (OMEGA_E_RADPS / C_MPS);
    let dtrop_dh = (saastamoinen_m(lat, h + 1.0, el) - saastamoinen_m(lat, h - 1.0, el)) / 2.0;
    let h_p = drho * frame.R_ecef_ned + RowVector3::new(0.0, 0.0, -dtrop_dh);
    (rho + sagnac + clock_bias_m - s.dts_m + trop, h_p, el)
}

/// Predicted range rate (K3): `(v_s − v)·u + ḃ − c·δṫ_s`, with Jacobians with
/// respect to the world-frame velocity and position.
pub fn range_rate(
    frame: &NedFrame,
    p_B_in_W: &Vector3<f64>,
    v_B_in_W: &Vector3<f64>,
    clock_drift_mps: f64,
    s: &SatMeas,
) -> (f64, RowVector3<f64>, RowVector3<f64>) {
    let r = frame.to_ecef(p_B_in_W);
    let v = frame.R_ecef_ned * v_B_in_W;
    let d = s.r_sat_ecef_m - r;
    let rho = d.norm();
    let u = d / rho;
    let dv = s.v_sat_ecef_mps - v;
    // ∂u/∂r = −(I − uuᵀ)/ρ.
    let du_dr: Matrix3<f64> = -(Matrix3::identity() - u * u.transpose()) / rho;
    let h_v = -u.transpose() * frame.R_ecef_ned;
    let h_p = dv.transpose() * du_dr * frame.R_ecef_ned;
    (dv.dot(&u) + clock_drift_mps - s.ddts_mps, h_v, h_p)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sat() -> (NedFrame, SatMeas) {
        let frame = NedFrame::from_llh_deg(-33.88, 151.2, 40.0);
        let up = frame.origin_ecef.normalize();
        let east = frame.R_ecef_ned.column(1).into_owned();
        let r_sat = frame.origin_ecef + up * 2.0e7 + east * 8.0e6;
        (
            frame,
            SatMeas {
                system: cmsckf_models::gnss::System::Gps,
                prn: 5,
                r_sat_ecef_m: r_sat,
                v_sat_ecef_mps: Vector3::new(1200.0, -2500.0, 1800.0),
                dts_m: 30.0,
                ddts_mps: 0.01,
                pseudorange_m: None,
                range_rate_mps: None,
                noise_scale: 1.0,
                extra_var_m2: 0.0,
            },
        )
    }

    /// Jacobians of the pseudorange and range rate against central
    /// differences.
    #[test]
    fn gnss_jacobians_match_finite_differences() {
        let (frame, s) = sat();
        let p = Vector3::new(120.0, -40.0, -8.0);
        let v = Vector3::new(14.0, 3.0, -0.5);
        let (_, hp, _) = pseudorange(&frame, &p, 100.0, &s);
        let (_, hv, hp_rate) = range_rate(&frame, &p, &v, 2.0, &s);
        let h = 1e-3;
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let fd =
                (pseudorange(&frame, &(p + d), 100.0, &s).0 - pseudorange(&frame, &(p - d), 100.0, &s).0) / (2.0 * h);
            assert!((fd - hp[k]).abs() < 1e-5, "pr/p{k}: {fd} vs {}", hp[k]);
            let fd =
                (range_rate(&frame, &p, &(v + d), 2.0, &s).0 - range_rate(&frame, &p, &(v - d), 2.0, &s).0) / (2.0 * h);
            assert!((fd - hv[k]).abs() < 1e-9, "rate/v{k}");
            let hh = 1.0;
            let mut dp = Vector3::zeros();
            dp[k] = hh;
            let fd = (range_rate(&frame, &(p + dp), &v, 2.0, &s).0 - range_rate(&frame, &(p - dp), &v, 2.0, &s).0)
                / (2.0 * hh);
            assert!((fd - hp_rate[k]).abs() < 1e-9, "rate/p{k}: {fd} vs {}", hp_rate[k]);
        }
        // Clock terms enter with unit slope.
        assert!((pseudorange(&frame, &p, 101.0, &s).0 - pseudorange(&frame, &p, 100.0, &s).0 - 1.0).abs() < 1e-9);
        assert!((range_rate(&frame, &p, &v, 3.0, &s).0 - range_rate(&frame, &p, &v, 2.0, &s).0 - 1.0).abs() < 1e-12);
    }
}
