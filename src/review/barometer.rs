//! Our height beside the autopilot's barometer: why this exists is that
//! nothing in a camera and an IMU takes out a height that drifted (a climb
//! flown at the wrong scale stays wrong), and a log without truth has no
//! other independent height to show it. The barometer's height changes are
//! set beside ours from the first instant both exist; their gap is our
//! height's drift plus the barometer's own (weather, temperature, and the
//! rotor wash near the ground, typically decimetres over a flight). With
//! `barometer.fuse` (the default) our height follows the barometer's, and
//! the gap is then how far the filter held out against it (the offset's
//! walk and its resets, README §3g): an independent check needs the log
//! replayed with `fuse = false` (`cmsckf replay --config`).

use serde::Serialize;

use super::reader::Data;

/// The gaps are averaged over bins of this length (s): a barometer
/// scatters by decimetres a reading.
const BIN_S: f64 = 1.0;
/// Our estimates further apart than this (s) are not interpolated between.
const MAX_TRACK_GAP_S: f64 = 0.5;

/// Our height change against the barometer's over the flight.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct BarometerGap {
    /// Bins (of [`BIN_S`]) with a gap.
    pub bins: u64,
    /// Largest `|our height change − the barometer's|` (m), and when (s of
    /// log time, the bin's start).
    pub max_abs_m: f64,
    pub max_at_s: f64,
    /// The gap in the last bin (m; positive: we are higher).
    pub last_m: f64,
    /// The autopilot's clock went back (a reboot): only what came before it
    /// is compared, since our height's origin and the bins' times start
    /// again there.
    pub stopped_at_reboot: bool,
}

/// A clock going back by more than this (s) has restarted; less is a
/// record written out of order.
const REBOOT_STEP_S: f64 = 1.0;

/// The first stretch of `series` whose times do not go back by more than
/// [`REBOOT_STEP_S`].
fn first_run<T>(series: &[T], t: impl Fn(&T) -> f64) -> (&[T], bool) {
    let end = series
        .windows(2)
        .position(|w| t(&w[1]) < t(&w[0]) - REBOOT_STEP_S)
        .map_or(series.len(), |i| i + 1);
    (&series[..end], end < series.len())
}

/// At each of the barometer's readings (`Data::baro`), our height
/// interpolated from our estimates (`Data::track`) at the reading's time,
/// less the barometer's; those differences averaged over each [`BIN_S`] bin
/// holding one or more, and taken from the first bin's. Up to the first
/// time either series goes back. `None` for a log without a barometer or
/// an estimate.
pub(super) fn gap(d: &Data) -> Option<BarometerGap> {
    let (track, track_cut) = first_run(&d.track, |p| p.0);
    let (baro, baro_cut) = first_run(&d.baro, |p| p.0);
    let mut bins = std::collections::BTreeMap::<i64, (f64, u32)>::new();
    for &(t, h_baro_m) in baro.iter().filter(|(t, h)| t.is_finite() && h.is_finite()) {
        // The pair of estimates around the reading.
        let i = track.partition_point(|p| p.0 <= t);
        let (Some(a), Some(b)) = (i.checked_sub(1).and_then(|k| track.get(k)), track.get(i)) else {
            continue;
        };
        if b.0 - a.0 > MAX_TRACK_GAP_S {
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
    let mut out = BarometerGap {
        stopped_at_reboot: track_cut || baro_cut,
        ..BarometerGap::default()
    };
    for (k, (sum, n)) in bins {
        let diff = sum / f64::from(n);
        let g = diff - *start.get_or_insert(diff);
        out.bins += 1;
        if g.abs() >= out.max_abs_m {
            (out.max_abs_m, out.max_at_s) = (g.abs(), k as f64 * BIN_S);
        }
        out.last_m = g;
    }
    (out.bins > 0).then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use cmsckf_models::atmosphere::isa_height_m;

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
        assert_eq!(g.bins, 20, "{g:?}");
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
        // The autopilot reboots at 12 s: its clock starts again at 0, and
        // only the first 12 s are compared.
        let mut rebooted = Data::default();
        rebooted.baro = d
            .baro
            .iter()
            .map(|&(t, h)| if t >= 12.0 { (t - 12.0, h) } else { (t, h) })
            .collect();
        rebooted.track = high
            .track
            .iter()
            .map(|&(t, n, e, q, down)| {
                if t >= 12.0 {
                    (t - 12.0, n, e, q, down)
                } else {
                    (t, n, e, q, down)
                }
            })
            .collect();
        let g = gap(&rebooted).unwrap();
        assert!(g.stopped_at_reboot && g.bins == 12, "{g:?}");
        // Its last bin, 11-12 s: 8 % of the mean climb of its readings (6.475 m).
        assert!((g.max_abs_m - 0.08 * 6.475).abs() < 0.01 && g.max_at_s == 11.0, "{g:?}");
        // A barometer read at 1 Hz still counts.
        let mut slow = Data::default();
        slow.baro = d.baro.iter().step_by(20).copied().collect();
        slow.track = d.track.clone();
        assert_eq!(gap(&slow).map(|g| g.bins), Some(20));
    }
}
