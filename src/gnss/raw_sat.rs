//! One satellite's code and Doppler as the solvers and the filter take
//! them: which signal of a message's is the first-frequency code, which the
//! second, and the code a mode of the ionosphere asks for.

use super::options::IonoMode;
use super::rtcm::{SatObs, System};

/// One satellite's code and Doppler as they reach [`sat_measurements`](super::sat_measurements) and
/// the single-point solver.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawSat {
    pub system: System,
    pub prn: u8,
    /// The first-frequency code: GPS L1 C/A, Galileo E1 (m).
    pub l1_pseudorange_m: Option<f64>,
    /// A second-frequency code and its carrier frequency `(m, Hz)`: GPS L2
    /// or L5, Galileo E5a or E5b.
    pub l2_pseudorange: Option<(f64, f64)>,
    pub l1_range_rate_mps: Option<f64>,
}

/// Carrier frequencies (Hz) by RINEX band.
pub(super) const F_L2_HZ: f64 = 1_227.60e6;
const F_L5_HZ: f64 = 1_176.45e6;
const F_E5B_HZ: f64 = 1_207.14e6;

impl RawSat {
    /// Picks the signals the solver uses: on L1/E1 the C/A or pilot code
    /// (attributes C, then X, then B), and the first second-frequency code in
    /// the message's signal order.
    pub fn from_obs(s: &SatObs) -> Self {
        // The first frequency: L1/E1/G1 (C/A, pilot or data code), and for
        // BeiDou B1I (RINEX band 2, the signal its TGD1 is for).
        let (band, attributes): (u8, &[char]) = match s.system {
            System::BeiDou => (2, &['I', 'X']),
            System::Glonass => (1, &['C', 'P']),
            System::Gps | System::Galileo | System::Qzss => (1, &['C', 'X', 'B']),
        };
        let l1 = attributes
            .iter()
            .find_map(|a| {
                s.signals
                    .iter()
                    .find(|g| g.band == band && g.attribute == *a && g.pseudorange_m.is_some())
            })
            .or_else(|| {
                s.signals
                    .iter()
                    .find(|g| g.band == band && g.attribute == attributes[0])
            });
        // QZSS transmits on GPS's frequencies.
        let second = |band: u8| match (s.system, band) {
            (System::Gps | System::Qzss, 2) => Some(F_L2_HZ),
            (System::Gps | System::Galileo | System::Qzss, 5) => Some(F_L5_HZ),
            (System::Galileo, 7) => Some(F_E5B_HZ),
            _ => None,
        };
        Self {
            system: s.system,
            prn: s.prn,
            l1_pseudorange_m: l1.and_then(|g| g.pseudorange_m),
            l2_pseudorange: s.signals.iter().find_map(|g| Some((g.pseudorange_m?, second(g.band)?))),
            l1_range_rate_mps: l1.and_then(|g| g.range_rate_mps),
        }
    }

    /// The code measurement under `iono`: `(pseudorange m, iono-free?)`.
    /// The ionosphere-free combination where a second code exists and the
    /// mode wants it (`iono-free`, `auto`); otherwise L1/E1 unless the mode
    /// is `iono-free`.
    pub fn code(&self, iono: IonoMode) -> Option<(f64, bool)> {
        let want_if = matches!(iono, IonoMode::IonoFree | IonoMode::Auto);
        match (self.l1_pseudorange_m, self.l2_pseudorange) {
            (Some(p1), Some((p2, f2))) if want_if => Some((iono_free(p1, p2, f2), true)),
            (Some(p1), _) if iono != IonoMode::IonoFree => Some((p1, false)),
            _ => None,
        }
    }
}

/// The first frequency (GPS L1, Galileo E1), Hz.
const F1: f64 = 1_575.42e6;

/// The ionosphere-free pseudorange `(P2 − γ P1)/(1 − γ)`, `γ = (f1/f2)²`,
/// of an L1/E1 code and a second code on `f2_hz`.
pub fn iono_free(p1: f64, p2: f64, f2_hz: f64) -> f64 {
    let g = (F1 / f2_hz).powi(2);
    (p2 - g * p1) / (1.0 - g)
}
