//! Single-point positioning from broadcast ephemerides (GPS and Galileo),
//! following the model RTKLIB uses, so that the two agree to centimetres on
//! the same data:
//!
//! - satellite position and clock at transmission time `t_rx − P/c − δt_sv`
//!   (IS-GPS-200 / Galileo OS SIS ICD Kepler orbit, harmonic corrections,
//!   relativistic term; `cmsckf_models::gnss::BroadcastEphemeris::state`), TGD
//!   (GPS) or BGD (Galileo) applied for the single-frequency code;
//! - the Sagnac correction `ω_e (x_s y_r − y_s x_r)/c` added to the range;
//! - Saastamoinen troposphere (standard atmosphere, 70% humidity);
//! - no ionosphere, or the L1/L2 ionosphere-free combination;
//! - weights `1/σ²`, `σ² = 0.09 (1 + 1/sin el) + URA² + σ_iono² + (0.3/(sin el + 0.1))² + 0.09`;
//! - Gauss–Newton least squares on `[x, y, z, c·δt_G, c·δt_E]`: one receiver
//!   clock per constellation present (the second is the first plus the
//!   inter-system bias), then a χ² test of the residuals; with two or more
//!   redundant satellites a failed test excludes the worst satellite and
//!   tries again (RAIM fault detection and exclusion). With exactly as many
//!   satellites as unknowns the solution is determined and RAIM is
//!   impossible.

use nalgebra::{DMatrix, DVector, Vector3};

use cmsckf_models::geodesy::{ecef_to_llh, elevation_azimuth, C_MPS, OMEGA_E_RADPS};
use cmsckf_models::gnss::{niell_hydrostatic_mapping, saastamoinen_m, saastamoinen_zenith_hydrostatic_m, SatState};
use cmsckf_models::stats::chi2_quantile;

pub use super::ephemeris_store::{EphStore, Orbit};
use super::options::{clock_group, IonoMode};
pub use super::raw_sat::iono_free;
use super::raw_sat::RawSat;
use super::rtcm::{SatObs, System};

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
    Excluded(System, u8),
}

/// A solution.
#[derive(Clone, Debug, PartialEq)]
pub struct SppSolution {
    pub week: u32,
    pub tow_s: f64,
    pub r_ecef_m: Vector3<f64>,
    /// The receiver clock `c·δt` (m) against the first constellation solved
    /// (GPS when present).
    pub clock_bias_m: f64,
    /// Each constellation's clock `c·δt` (m); the differences are the
    /// inter-system biases.
    pub system_clocks_m: Vec<(System, f64)>,
    pub sats: Vec<(System, u8)>,
    pub pdop: f64,
    pub residual_rms_m: f64,
    pub raim: Raim,
    /// Whether the ionosphere-free combination was used.
    pub iono_free: bool,
}

/// Why an epoch was not solved.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SppError {
    #[error("{have} usable satellites; at least {need} are needed")]
    TooFewSatellites { have: usize, need: usize },
    #[error("the least squares did not converge")]
    NotConverged,
    #[error("the residuals fail the χ² test and RAIM could not isolate a fault")]
    Chi2,
    #[error("geometry too weak (GDOP {0:.1})")]
    Geometry(u32),
}

/// The satellite's state at the transmission time of a signal received at
/// `week`/`tow_rx_s` with pseudorange `pr_m`: `t_tx = t_rx − P/c − δt_sv`
/// (RTKLIB's `satposs`).
pub fn state_at_transmission(orbit: Orbit<'_>, week: u32, tow_rx_s: f64, pr_m: f64) -> SatState {
    let t0 = tow_rx_s - pr_m / C_MPS;
    let clk0 = orbit.state(week, t0).dt_s + orbit.tgd_s();
    orbit.state(week, t0 - clk0)
}

/// One satellite ready for the solver.
pub(super) struct Meas {
    pub sat: (System, u8),
    pub pr_m: f64,
    pub r_sat: Vector3<f64>,
    pub dts_m: f64,
    pub ura_m: f64,
}

/// What the code measurements of an epoch are, which sets the troposphere
/// and the weights of the least squares.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CodeModel {
    /// One frequency, no ionosphere model: Saastamoinen, RTKLIB's variance
    /// with 5 m of ionosphere.
    Single,
    /// The ionosphere-free combination: Saastamoinen, tripled σ.
    IonoFree,
    /// Rover-minus-base corrected codes (`dgnss.rs`): the hydrostatic
    /// Saastamoinen zenith delay mapped by Niell's function at day of year
    /// `doy`, variance `2 (0.3² + 0.3²/sin² el)` (RTKLIB's relative-mode
    /// code error, the rover's and the base's), no URA: orbit, clock and
    /// ionosphere errors cancel in the difference.
    Differential { doy: f64 },
}

impl CodeModel {
    /// The modelled troposphere (m) at latitude `lat`, height `h` (m) and
    /// elevation `el` (rad).
    pub fn troposphere_m(self, lat: f64, h: f64, el: f64) -> f64 {
        match self {
            CodeModel::Single | CodeModel::IonoFree => saastamoinen_m(lat, h, el),
            CodeModel::Differential { doy } => {
                saastamoinen_zenith_hydrostatic_m(lat, h) * niell_hydrostatic_mapping(lat, h, el, doy)
            }
        }
    }
}

/// Solves one epoch of observations at `week`/`tow_s`.
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
    for s in sats.iter().filter(|s| opt.systems.contains(&s.system)) {
        let Some((pr, is_if)) = RawSat::from_obs(s).code(opt.iono) else {
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
        let Some(orbit) = ephs.orbit(s.system, s.prn, week, tow_s) else {
            continue;
        };
        let st = state_at_transmission(orbit, week, tow_s, pr);
        // The single-frequency code sees clock − TGD (already in `dt_s`); the
        // iono-free combination sees the clock without TGD.
        let dts = if is_if { st.dt_s + orbit.tgd_s() } else { st.dt_s };
        meas.push(Meas {
            sat: (s.system, s.prn),
            pr_m: pr,
            r_sat: st.r_ecef_m,
            dts_m: dts * C_MPS,
            ura_m: orbit.accuracy_m(),
        });
    }
    let iono_free = iono_free_used.unwrap_or(false);
    let model = if iono_free {
        CodeModel::IonoFree
    } else {
        CodeModel::Single
    };
    solve_meas(&meas, week, tow_s, opt, model)
}

/// Least squares with RAIM fault detection and exclusion over prepared
/// measurements of one epoch.
pub(super) fn solve_meas(
    meas: &[Meas],
    week: u32,
    tow_s: f64,
    opt: &SppOptions,
    model: CodeModel,
) -> Result<SppSolution, SppError> {
    let mut excluded: Option<(System, u8)> = None;
    let first = lsq(meas, None, opt, model);
    let sol = match first {
        Ok(s) => s,
        Err(SppError::Chi2) => {
            // RAIM FDE: the exclusion with the smallest residuals that passes
            // (needs one redundant satellite left after the exclusion).
            let mut best: Option<(f64, LsqOut, (System, u8))> = None;
            for m in meas {
                if let Ok(s) = lsq(meas, Some(m.sat), opt, model) {
                    if s.sats.len() > s.n_unknowns && best.as_ref().is_none_or(|b| s.rms < b.0) {
                        best = Some((s.rms, s, m.sat));
                    }
                }
            }
            let (_, s, sat) = best.ok_or(SppError::Chi2)?;
            excluded = Some(sat);
            s
        }
        Err(e) => return Err(e),
    };
    let raim = match excluded {
        Some((sys, p)) => Raim::Excluded(sys, p),
        None if sol.sats.len() == sol.n_unknowns => Raim::NotPossible,
        None => Raim::Passed,
    };
    Ok(SppSolution {
        week,
        tow_s,
        r_ecef_m: sol.x,
        clock_bias_m: sol.clocks_m.first().map_or(0.0, |c| c.1),
        system_clocks_m: sol.clocks_m,
        sats: sol.sats,
        pdop: sol.pdop,
        residual_rms_m: sol.rms,
        raim,
        iono_free: model == CodeModel::IonoFree,
    })
}

/// One satellite's row of the least squares: the negated line of sight, its
/// constellation's clock column, residual (m), variance (m²) and name.
type Row = (Vector3<f64>, usize, f64, f64, (System, u8));

struct LsqOut {
    x: Vector3<f64>,
    clocks_m: Vec<(System, f64)>,
    sats: Vec<(System, u8)>,
    n_unknowns: usize,
    pdop: f64,
    rms: f64,
}

/// Weighted Gauss–Newton least squares on the position and one clock per
/// constellation, from the Earth's centre; `exclude` leaves one satellite
/// out (RAIM). Ends with the χ² test of the residuals and the DOPs.
fn lsq(meas: &[Meas], exclude: Option<(System, u8)>, opt: &SppOptions, model: CodeModel) -> Result<LsqOut, SppError> {
    let mut x = Vector3::zeros();
    // One clock per constellation present, in a fixed order (GPS first).
    let mut systems: Vec<System> = meas.iter().map(|m| clock_group(m.sat.0)).collect();
    systems.sort();
    systems.dedup();
    let nu = 3 + systems.len();
    let mut clk = vec![0.0; systems.len()];
    let mask = opt.elevation_mask_deg.to_radians();
    for _iter in 0..10 {
        let rows = lsq_rows(meas, exclude, &x, &systems, &clk, mask, model);
        let n = rows.len();
        // Every constellation's clock needs one of its own satellites.
        let present = (0..systems.len()).filter(|k| rows.iter().any(|r| r.1 == *k)).count();
        let need = 3 + present.max(1);
        if n < need || present < systems.len() {
            return Err(SppError::TooFewSatellites { have: n, need });
        }
        let ls = LsqSystem::new(&rows, nu);
        let Some(ch) = (ls.a.transpose() * &ls.a).cholesky() else {
            return Err(SppError::Geometry(u32::MAX));
        };
        let dx = ch.solve(&(ls.a.transpose() * &ls.b));
        x += Vector3::new(dx[0], dx[1], dx[2]);
        for (k, c) in clk.iter_mut().enumerate() {
            *c += dx[3 + k];
        }
        if dx.norm() < 1e-4 {
            return converged(&ls, &dx, &rows, x, &systems, &clk);
        }
    }
    Err(SppError::NotConverged)
}

/// The rows of one iteration at the receiver position `x` (m, ECEF) and
/// clocks `clk` (m): each satellite above `mask` (rad), all of them while
/// the position is still unknown (near the Earth's centre).
fn lsq_rows(
    meas: &[Meas],
    exclude: Option<(System, u8)>,
    x: &Vector3<f64>,
    systems: &[System],
    clk: &[f64],
    mask: f64,
    model: CodeModel,
) -> Vec<Row> {
    let (lat, _, h) = ecef_to_llh(x);
    let known = x.norm() > 6.0e6;
    // (−line of sight, clock column, residual m, variance m², satellite)
    let mut rows: Vec<Row> = Vec::new();
    for m in meas.iter().filter(|m| Some(m.sat) != exclude) {
        let (el, _) = if known {
            elevation_azimuth(x, &m.r_sat)
        } else {
            (std::f64::consts::FRAC_PI_2, 0.0)
        };
        if known && el < mask {
            continue;
        }
        let k = systems.iter().position(|s| *s == clock_group(m.sat.0)).unwrap_or(0);
        let d = m.r_sat - x;
        let rho = d.norm() + OMEGA_E_RADPS * (m.r_sat.x * x.y - m.r_sat.y * x.x) / C_MPS;
        let u = d / d.norm();
        let trop = if known { model.troposphere_m(lat, h, el) } else { 0.0 };
        let v = m.pr_m - (rho + clk[k] - m.dts_m + trop);
        rows.push((-u, k, v, code_variance_m2(el, m.ura_m, model, m.sat.0), m.sat));
    }
    rows
}

/// How much noisier a constellation's codes are than GPS's: RTKLIB's error
/// factor, 1.5 for GLONASS, whose FDMA channels each carry their own
/// receiver delay (the inter-frequency bias, which no state models here;
/// estimator README §8c).
pub fn code_sigma_factor(system: System) -> f64 {
    if system == System::Glonass {
        1.5
    } else {
        1.0
    }
}

/// A pseudorange's variance (m²) at elevation `el` (rad): the RTKLIB model
/// (tripled σ for the iono-free combination, else 5 m of ionosphere), plus
/// the URA `ura_m`; for differential codes, RTKLIB's relative-mode
/// `2 (0.3² + 0.3²/sin² el)`.
fn code_variance_m2(el: f64, ura_m: f64, model: CodeModel, system: System) -> f64 {
    let sin_el = el.sin();
    let fact2 = code_sigma_factor(system).powi(2);
    let iono_free = match model {
        CodeModel::Differential { .. } => return fact2 * 2.0 * (0.09 + 0.09 / (sin_el * sin_el)),
        CodeModel::Single => false,
        CodeModel::IonoFree => true,
    };
    let mut var = fact2 * 0.09 * (1.0 + 1.0 / sin_el);
    if iono_free {
        var *= 9.0;
    }
    let var_iono = if iono_free { 0.0 } else { 25.0 };
    var += ura_m * ura_m + 0.09 + var_iono + (0.3 / (sin_el + 0.1)).powi(2);
    var
}

/// One iteration's linear system: the geometry matrix `g` (unweighted), and
/// `a`, `b` weighted by `1/σ`.
struct LsqSystem {
    g: DMatrix<f64>,
    a: DMatrix<f64>,
    b: DVector<f64>,
}

impl LsqSystem {
    fn new(rows: &[Row], nu: usize) -> Self {
        let n = rows.len();
        // Geometry matrix G (unweighted) and the weighted system.
        let mut g = DMatrix::zeros(n, nu);
        for (i, (e, k, ..)) in rows.iter().enumerate() {
            g.view_mut((i, 0), (1, 3)).copy_from(&e.transpose());
            g[(i, 3 + k)] = 1.0;
        }
        let w = DVector::from_iterator(n, rows.iter().map(|r| 1.0 / r.3.sqrt()));
        let a = DMatrix::from_fn(n, nu, |i, j| g[(i, j)] * w[i]);
        let b = DVector::from_iterator(n, rows.iter().zip(w.iter()).map(|(r, wi)| r.2 * wi));
        Self { g, a, b }
    }
}

/// The converged solution (`x`, `clk`, after the step `dx`): residuals at
/// the solution, the χ² test and the DOPs.
fn converged(
    ls: &LsqSystem,
    dx: &DVector<f64>,
    rows: &[Row],
    x: Vector3<f64>,
    systems: &[System],
    clk: &[f64],
) -> Result<LsqOut, SppError> {
    let (n, nu) = ls.a.shape();
    let vv = (&ls.b - &ls.a * dx).norm_squared();
    let rms = (rows.iter().map(|r| r.2 * r.2).sum::<f64>() / n as f64).sqrt();
    if n > nu && vv > chi2_quantile(0.999, n - nu) {
        return Err(SppError::Chi2);
    }
    let q = (ls.g.transpose() * &ls.g)
        .try_inverse()
        .ok_or(SppError::Geometry(u32::MAX))?;
    let gdop = q.trace().sqrt();
    if !(gdop > 0.0 && gdop <= 30.0) {
        return Err(SppError::Geometry(gdop.min(1e9) as u32));
    }
    let pdop = (q[(0, 0)] + q[(1, 1)] + q[(2, 2)]).sqrt();
    Ok(LsqOut {
        x,
        clocks_m: systems.iter().copied().zip(clk.iter().copied()).collect(),
        sats: rows.iter().map(|r| r.4).collect(),
        n_unknowns: nu,
        pdop,
        rms,
    })
}
