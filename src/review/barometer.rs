//! Our height beside the autopilot's barometer: why this exists is that
//! nothing in a camera and an IMU takes out a height that drifted (a climb
//! flown at the wrong scale stays wrong), and a log without truth has no
//! other independent height to show it. The barometer's height changes are
//! set beside ours from the first instant both exist; their gap is our
//! height's drift plus the barometer's own (weather, temperature, and the
//! rotor wash near the ground, typically decimetres over a flight).

use serde::Serialize;

use super::reader::Data;

pub(super) use cmsckf_models::atmosphere::isa_height_m;

/// The gaps are averaged over bins of this length (s): a barometer
/// scatters by decimetres a reading.
const BIN_S: f64 = 1.0;
/// Fewest readings in a bin for it to count.
const MIN_READINGS: u32 = 3;
/// Our estimates further apart than this (s) are not interpolated between.
const MAX_TRACK_GAP_S: f64 = 0.5;

/// Our height change against the barometer's over the flight.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct BarometerGap {
    /// Bins with a gap.
    pub samples: u64,
    /// Largest `|our height change − the barometer's|` (m), and when (s of
    /// log time, the bin's start).
    pub max_abs_m: f64,
    pub max_at_s: f64,
    /// The gap in the last bin (m; positive: we are higher).
    pub last_m: f64,
}

/// At each of the barometer's readings (`Data::baro`), our height
/// interpolated from our estimates (`Data::track`) at the reading's time,
/// less the barometer's; those differences averaged over each [`BIN_S`] bin
/// with at least [`MIN_READINGS`] of them, and taken from the first such
/// bin's. `None` for a log without a barometer or an estimate.
pub(super) fn gap(d: &Data) -> Option<BarometerGap> {
    let track = &d.track;
    let mut bins = std::collections::BTreeMap::<i64, (f64, u32)>::new();
    let mut j = 0;
    for &(t, h_baro_m) in d.baro.iter().filter(|(t, h)| t.is_finite() && h.is_finite()) {
        while j + 1 < track.len() && track[j + 1].0 < t {
            j += 1;
        }
        let (Some(a), Some(b)) = (track.get(j), track.get(j + 1)) else {
            continue;
        };
        if !(a.0 <= t && t <= b.0 && b.0 - a.0 <= MAX_TRACK_GAP_S) {
            continue;
        }
        let w = if b.0 > a.0 { (t - a.0) / (b.0 - a.0) } else { 0.0 };
        let down_m = a.4 + (b.4 - a.4) * w;
        if !down_m.is_finite() {
            continue;
        }
        let bin = bins.entry((t / BIN_S).floor() as i64).or_default();
        (bin.0, bin.1) = (bin.0 - down_m - h_baro_m, bin.1 + 1);
    }
    let mut start = None;
    let mut out = BarometerGap::default();
    for (k, (sum, n)) in bins {
        if n < MIN_READINGS {
            continue;
        }
        let diff = sum / f64::from(n);
        let g = diff - *start.get_or_insert(diff);
        out.samples += 1;
        if g.abs() >= out.max_abs_m {
            (out.max_abs_m, out.max_at_s) = (g.abs(), k as f64 * BIN_S);
        }
        out.last_m = g;
    }
    (out.samples > 0).then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A climb of 10 m that the barometer sees as we do has no gap; ours
    /// 8 % high from t = 10 s shows by how much, when, and at the end; a
    /// log without the barometer has none.
    #[test]
    fn our_height_is_set_beside_the_barometers() {
        let p_at = cmsckf_models::atmosphere::isa_pressure_pa;
        let climb = |t: f64| (t - 5.0).clamp(0.0, 10.0);
        let mut d = Data::default();
        for k in 0..400 {
            let t = k as f64 * 0.05;
            d.baro.push((t, isa_height_m(p_at(100.0 + climb(t)))));
        }
        for k in 0..600 {
            let t = k as f64 * 1.0 / 30.0;
            d.track.push((t, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], -climb(t)));
        }
        let g = gap(&d).unwrap();
        assert_eq!(g.samples, 20, "{g:?}");
        // A reading between two estimates is set beside ours there, not
        // beside the bin's mean: a climb's slope makes no gap.
        assert!(g.max_abs_m < 0.01, "{g:?}");
        let mut high = Data::default();
        high.baro = d.baro.clone();
        high.track = d
            .track
            .iter()
            .map(|&(t, n, e, q, down)| (t, n, e, q, if t >= 10.0 { 1.08 * down } else { down }))
            .collect();
        let g = gap(&high).unwrap();
        assert!((g.max_abs_m - 0.8).abs() < 0.05 && g.max_at_s >= 15.0, "{g:?}");
        assert!((g.last_m - 0.8).abs() < 0.05, "{g:?}");
        let mut no_barometer = Data::default();
        no_barometer.track = d.track.clone();
        assert_eq!(gap(&no_barometer), None);
    }
}
