//! Single-point positioning from broadcast ephemerides (GPS), following the
//! model RTKLIB uses, so that the two agree to centimetres on the same data:
//!
//! - satellite position and clock at transmission time `t_rx − P/c − δt_sv`
//!   (IS-GPS-200 Kepler orbit, harmonic corrections, relativistic term;
//!   `cmsckf_sitl::gnss::GpsEphemeris::state`), TGD applied for L1;
//! - the Sagnac correction `ω_e (x_s y_r − y_s x_r)/c` added to the range;
//! - Saastamoinen troposphere (standard atmosphere, 70% humidity);
//! - no ionosphere, or the L1/L2 ionosphere-free combination;
//! - weights `1/σ²`, `σ² = 0.09 (1 + 1/sin el) + URA² + σ_iono² + (0.3/(sin el + 0.1))² + 0.09`;
//! - Gauss–Newton least squares on `[x, y, z, c·δt]`, then a χ² test of the
//!   residuals; with 6 or more satellites a failed test excludes the worst
//!   satellite and tries again (RAIM fault detection and exclusion). With
//!   exactly 4 satellites the solution is determined and RAIM is impossible.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector, Vector3};

use cmsckf_sitl::geodesy::{ecef_to_llh, elevation_azimuth, C_MPS, OMEGA_E_RADPS};
use cmsckf_sitl::gnss::{saastamoinen_m, GpsEphemeris};
use cmsckf_sitl::metrics::chi2_quantile;

use super::rtcm::{SatObs, System};
use crate::config::IonoMode;

/// GPS L1 and L2 frequencies (Hz).
const F1: f64 = 1_575.42e6;
const F2: f64 = 1_227.60e6;
/// URA index → metres (IS-GPS-200).
const URA_M: [f64; 15] = [
    2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0,
];
/// Largest `|t − toe|` for an ephemeris to be used (s).
const MAX_AGE_S: f64 = 7200.0;

/// Broadcast ephemerides by satellite, with resolved weeks.
#[derive(Clone, Debug, Default)]
pub struct EphStore {
    by_prn: BTreeMap<u8, Vec<GpsEphemeris>>,
    /// Week and toe of the latest ephemeris, to place a time of week.
    last: Option<(u32, f64)>,
}

impl EphStore {
    /// Adds an ephemeris, replacing one with the same `toe` and IODE.
    pub fn insert(&mut self, eph: GpsEphemeris) {
        self.last = Some((eph.week, eph.toe_s));
        let v = self.by_prn.entry(eph.prn).or_default();
        v.retain(|e| !(e.toe_s == eph.toe_s && e.week == eph.week && e.iode == eph.iode));
        v.push(eph);
        // Bounded: keep the newest 8 per satellite.
        if v.len() > 8 {
            v.remove(0);
        }
    }

    /// The healthy ephemeris with `toe` nearest to the time (RTKLIB's rule).
    pub fn select(&self, prn: u8, week: u32, tow_s: f64) -> Option<&GpsEphemeris> {
        self.by_prn
            .get(&prn)?
            .iter()
            .filter(|e| e.health == 0)
            .map(|e| (e, ((week as f64 - e.week as f64) * 604_800.0 + tow_s - e.toe_s).abs()))
            .filter(|(_, d)| *d <= MAX_AGE_S)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(e, _)| e)
    }

    /// The full week of a time of week near the latest ephemeris.
    pub fn week_for_tow(&self, tow_s: f64) -> Option<u32> {
        let (w, toe) = self.last?;
        let d = tow_s - toe;
        Some(if d < -302_400.0 {
            w + 1
        } else if d > 302_400.0 {
            w.saturating_sub(1)
        } else {
            w
        })
    }

    pub fn len(&self) -> usize {
        self.by_prn.values().map(Vec::len).sum()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Settings of the solver.
#[derive(Clone, Debug)]
pub struct SppOptions {
    pub elevation_mask_deg: f64,
    pub iono: IonoMode,
    pub systems: Vec<System>,
}

/// RAIM outcome.
#[derive(Clone, Debug, PartialEq)]
pub enum Raim {
    /// The residuals pass the χ² test.
    Passed,
    /// Exactly determined (4 satellites): no redundancy to test.
    NotPossible,
    /// A satellite was excluded.
    Excluded(u8),
}

/// A solution.
#[derive(Clone, Debug, PartialEq)]
pub struct SppSolution {
    pub week: u32,
    pub tow_s: f64,
    pub r_ecef_m: Vector3<f64>,
    pub clock_bias_m: f64,
    pub sats: Vec<u8>,
    pub pdop: f64,
    pub residual_rms_m: f64,
    pub raim: Raim,
    /// Whether the ionosphere-free combination was used.
    pub iono_free: bool,
}

/// Why an epoch was not solved.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SppError {
    #[error("{0} usable satellites; at least 4 are needed")]
    TooFewSatellites(usize),
    #[error("the least squares did not converge")]
    NotConverged,
    #[error("the residuals fail the χ² test and RAIM could not isolate a fault")]
    Chi2,
    #[error("geometry too weak (GDOP {0:.1})")]
    Geometry(u32),
}

/// The satellite's state at the transmission time of a signal received at
/// `tow_rx_s` with pseudorange `pr_m`: `t_tx = t_rx − P/c − δt_sv` (RTKLIB's
/// `satposs`).
pub fn state_at_transmission(eph: &GpsEphemeris, tow_rx_s: f64, pr_m: f64) -> cmsckf_sitl::gnss::SatState {
    let t0 = tow_rx_s - pr_m / C_MPS;
    let clk0 = eph.state(t0).dt_s + eph.tgd_s;
    eph.state(t0 - clk0)
}

/// One satellite ready for the solver.
struct Meas {
    prn: u8,
    pr_m: f64,
    r_sat: Vector3<f64>,
    dts_m: f64,
    ura_m: f64,
}

/// The L1/L2 ionosphere-free pseudorange `(P2 − γ P1)/(1 − γ)`, `γ = (f1/f2)²`.
pub fn iono_free(p1: f64, p2: f64) -> f64 {
    let g = (F1 / F2).powi(2);
    (p2 - g * p1) / (1.0 - g)
}

/// Picks the code measurement of a satellite: L1 C/A, or the L1/L2
/// ionosphere-free combination. Returns `(pseudorange, iono-free?)`.
fn code_for(s: &SatObs, iono: IonoMode) -> Option<(f64, bool)> {
    let l1 = s
        .signals
        .iter()
        .find(|g| g.band == 1 && g.attribute == 'C')
        .and_then(|g| g.pseudorange_m);
    let l2 = s.signals.iter().filter(|g| g.band == 2).find_map(|g| g.pseudorange_m);
    let want_if = matches!(iono, IonoMode::IonoFree | IonoMode::Auto);
    match (l1, l2) {
        (Some(p1), Some(p2)) if want_if => Some((iono_free(p1, p2), true)),
        (Some(p1), _) if iono != IonoMode::IonoFree => Some((p1, false)),
        _ => None,
    }
}

/// Solves one epoch of GPS observations at `week`/`tow_s`.
pub fn solve(
    sats: &[SatObs],
    week: u32,
    tow_s: f64,
    ephs: &EphStore,
    opt: &SppOptions,
) -> Result<SppSolution, SppError> {
    // Satellite states at transmission time.
    let mut meas = Vec::new();
    let mut iono_free_used = None;
    for s in sats {
        let Some((pr, is_if)) = code_for(s, opt.iono) else {
            continue;
        };
        // All satellites of an epoch use the same combination: the first
        // decides (dual-frequency receivers give L2 for every satellite).
        if *iono_free_used.get_or_insert(is_if) != is_if {
            continue;
        }
        if !(1.0e7..=4.0e7).contains(&pr) {
            continue;
        }
        let Some(eph) = ephs.select(s.prn, week, tow_s) else {
            continue;
        };
        let t0 = tow_s - pr / C_MPS;
        let clk0 = eph.state(t0).dt_s + eph.tgd_s; // without TGD or relativity: close enough to step
        let st = eph.state(t0 - clk0);
        // L1 C/A sees clock − TGD (already in `dt_s`); the iono-free
        // combination sees the clock without TGD.
        let dts = if is_if { st.dt_s + eph.tgd_s } else { st.dt_s };
        meas.push(Meas {
            prn: s.prn,
            pr_m: pr,
            r_sat: st.r_ecef_m,
            dts_m: dts * C_MPS,
            ura_m: URA_M.get(eph.ura_index as usize).copied().unwrap_or(6144.0),
        });
    }
    let iono_free = iono_free_used.unwrap_or(false);
    let mut excluded: Option<u8> = None;
    let first = lsq(&meas, None, opt, iono_free);
    let sol = match first {
        Ok(s) => s,
        Err(SppError::Chi2) if meas.len() >= 6 => {
            // RAIM FDE: the exclusion with the smallest residuals that passes.
            let mut best: Option<(f64, LsqOut, u8)> = None;
            for m in &meas {
                if let Ok(s) = lsq(&meas, Some(m.prn), opt, iono_free) {
                    if best.as_ref().is_none_or(|b| s.rms < b.0) {
                        best = Some((s.rms, s, m.prn));
                    }
                }
            }
            let (_, s, prn) = best.ok_or(SppError::Chi2)?;
            excluded = Some(prn);
            s
        }
        Err(e) => return Err(e),
    };
    let raim = match excluded {
        Some(p) => Raim::Excluded(p),
        None if sol.sats.len() == 4 => Raim::NotPossible,
        None => Raim::Passed,
    };
    Ok(SppSolution {
        week,
        tow_s,
        r_ecef_m: sol.x,
        clock_bias_m: sol.clock_m,
        sats: sol.sats,
        pdop: sol.pdop,
        residual_rms_m: sol.rms,
        raim,
        iono_free,
    })
}

struct LsqOut {
    x: Vector3<f64>,
    clock_m: f64,
    sats: Vec<u8>,
    pdop: f64,
    rms: f64,
}

fn lsq(meas: &[Meas], exclude: Option<u8>, opt: &SppOptions, iono_free: bool) -> Result<LsqOut, SppError> {
    let mut x = Vector3::zeros();
    let mut clk = 0.0;
    let mask = opt.elevation_mask_deg.to_radians();
    for _iter in 0..10 {
        let (lat, _, h) = ecef_to_llh(&x);
        let known = x.norm() > 6.0e6;
        let mut rows: Vec<([f64; 4], f64, f64, u8)> = Vec::new();
        for m in meas.iter().filter(|m| Some(m.prn) != exclude) {
            let (el, _) = if known {
                elevation_azimuth(&x, &m.r_sat)
            } else {
                (std::f64::consts::FRAC_PI_2, 0.0)
            };
            if known && el < mask {
                continue;
            }
            let d = m.r_sat - x;
            let rho = d.norm() + OMEGA_E_RADPS * (m.r_sat.x * x.y - m.r_sat.y * x.x) / C_MPS;
            let u = d / d.norm();
            let trop = if known { saastamoinen_m(lat, h, el) } else { 0.0 };
            let v = m.pr_m - (rho + clk - m.dts_m + trop);
            let sin_el = el.sin();
            let mut var = 0.09 * (1.0 + 1.0 / sin_el);
            if iono_free {
                var *= 9.0;
            }
            let var_iono = if iono_free { 0.0 } else { 25.0 };
            var += m.ura_m * m.ura_m + 0.09 + var_iono + (0.3 / (sin_el + 0.1)).powi(2);
            rows.push(([-u.x, -u.y, -u.z, 1.0], v, var, m.prn));
        }
        let n = rows.len();
        if n < 4 {
            return Err(SppError::TooFewSatellites(n));
        }
        let mut a = DMatrix::zeros(n, 4);
        let mut b = DVector::zeros(n);
        for (i, (h, v, var, _)) in rows.iter().enumerate() {
            let w = 1.0 / var.sqrt();
            for k in 0..4 {
                a[(i, k)] = h[k] * w;
            }
            b[i] = v * w;
        }
        let ata = a.transpose() * &a;
        let Some(ch) = ata.clone().cholesky() else {
            return Err(SppError::Geometry(u32::MAX));
        };
        let dx = ch.solve(&(a.transpose() * &b));
        x += Vector3::new(dx[0], dx[1], dx[2]);
        clk += dx[3];
        if dx.norm() < 1e-4 {
            // Residuals at the solution, the χ² test and the DOPs.
            let vv: f64 = (0..n)
                .map(|i| {
                    let r = b[i] - (a.row(i) * &dx)[0];
                    r * r
                })
                .sum();
            let rms = (rows.iter().map(|r| r.1 * r.1).sum::<f64>() / n as f64).sqrt();
            if n > 4 && vv > chi2_quantile(0.999, n - 4) {
                return Err(SppError::Chi2);
            }
            let mut g = DMatrix::zeros(n, 4);
            for (i, (h, ..)) in rows.iter().enumerate() {
                for k in 0..4 {
                    g[(i, k)] = h[k];
                }
            }
            let q = (g.transpose() * g).try_inverse().ok_or(SppError::Geometry(u32::MAX))?;
            let gdop = q.trace().sqrt();
            if !(gdop > 0.0 && gdop <= 30.0) {
                return Err(SppError::Geometry(gdop.min(1e9) as u32));
            }
            let pdop = (q[(0, 0)] + q[(1, 1)] + q[(2, 2)]).sqrt();
            return Ok(LsqOut {
                x,
                clock_m: clk,
                sats: rows.iter().map(|r| r.3).collect(),
                pdop,
                rms,
            });
        }
    }
    Err(SppError::NotConverged)
}
