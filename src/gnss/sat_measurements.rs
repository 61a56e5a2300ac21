//! Satellite states and measurements for the filter (README §8), from an
//! epoch's satellites and the ephemeris store, with the ionosphere handled
//! per the configured policy.

use cmsckf_models::gnss::Klobuchar;

use super::ephemeris_store::EphStore;
use super::options::IonoMode;
use super::raw_sat::RawSat;
use super::spp;

/// How [`sat_measurements`] treats the ionosphere.
#[derive(Clone, Copy, Debug)]
pub struct IonoPolicy<'a> {
    pub mode: IonoMode,
    /// Broadcast parameters, if known (RTCM carries none: from the config).
    pub klobuchar: Option<&'a Klobuchar>,
    /// An approximate receiver position (ECEF, m) for the Klobuchar geometry.
    pub rx_ecef_m: Option<nalgebra::Vector3<f64>>,
}

/// Satellite states and measurements for the filter (§8), with the
/// ionosphere handled per the policy: the L1/L2 ionosphere-free combination
/// where both codes exist (`iono-free`, `auto`); else L1 C/A corrected by
/// Klobuchar when its parameters and a receiver position are known
/// (`klobuchar`, `auto`; residual variance (0.5·I)²); else, without a model
/// (`auto`, `klobuchar`), L1 with its variance inflated by (5 m)², as RTKLIB
/// does; `off` ignores the ionosphere.
pub fn sat_measurements(
    ephs: &EphStore,
    week: u32,
    tow_s: f64,
    policy: IonoPolicy<'_>,
    sats: impl IntoIterator<Item = RawSat>,
) -> Vec<cmsckf_models::gnss::SatMeas> {
    let iono = policy.mode;
    let c = cmsckf_models::geodesy::C_MPS;
    sats.into_iter()
        .filter_map(|s| {
            let orbit = ephs.orbit(s.system, s.prn, week, tow_s)?;
            let (pr, is_if) = match s.code(iono) {
                Some((p, is_if)) => (Some(p), is_if),
                None => (None, false),
            };
            let st = spp::state_at_transmission(orbit, week, tow_s, pr.unwrap_or(0.075 * c));
            // The iono-free combination sees the clock without TGD (§8).
            let dts = if is_if { st.dt_s + orbit.tgd_s() } else { st.dt_s };
            let klob = match (policy.klobuchar, policy.rx_ecef_m) {
                (Some(k), Some(r)) if !is_if && iono != IonoMode::Off => {
                    let (lat, lon, _) = cmsckf_models::geodesy::ecef_to_llh(&r);
                    let (el, az) = cmsckf_models::geodesy::elevation_azimuth(&r, &st.r_ecef_m);
                    Some(k.delay_m(lat, lon, az, el, tow_s))
                }
                _ => None,
            };
            let (noise_scale, extra_var_m2) = match (is_if, iono, klob) {
                (true, _, _) => (3.0, 0.0),
                (false, IonoMode::Off, _) => (1.0, 0.0),
                (false, _, Some(i)) => (1.0, (0.5 * i).powi(2)),
                (false, _, None) => (1.0, 25.0),
            };
            let pr = pr.map(|p| p - klob.unwrap_or(0.0));
            let noise_scale = noise_scale * spp::code_sigma_factor(s.system);
            Some(cmsckf_models::gnss::SatMeas {
                system: s.system,
                prn: s.prn,
                r_sat_ecef_m: st.r_ecef_m,
                v_sat_ecef_mps: st.v_ecef_mps,
                dts_m: dts * c,
                ddts_mps: st.ddt * c,
                pseudorange_m: pr,
                range_rate_mps: s.l1_range_rate_mps,
                noise_scale,
                extra_var_m2,
                correction: None,
            })
        })
        .collect()
}
