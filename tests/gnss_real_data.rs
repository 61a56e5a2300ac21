//! `cmsckf gnss` on real receiver streams against RTKLIB 2.4.3's
//! single-point solutions (tests/data, README there): same model, so the
//! two must agree to centimetres: the checks ask for a median ≤ 5 cm and a
//! 95th percentile ≤ 10 cm of the 3-D distance, epoch by epoch.

use std::process::Command;

fn data(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// GPS time of week (s) of a `YYYY/MM/DD hh:mm:ss.sss` GPST stamp.
fn tow_of(date: &str, time: &str) -> f64 {
    let d: Vec<i64> = date.split('/').map(|x| x.parse().unwrap()).collect();
    let t: Vec<f64> = time.split(':').map(|x| x.parse().unwrap()).collect();
    // Days from civil (Howard Hinnant's algorithm), then from 1980-01-06.
    let (y, m, dd) = (d[0] - (d[1] <= 2) as i64, d[1], d[2]);
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let doy = (153 * (m + if m > 2 { -3 } else { 9 }) + 2) / 5 + dd - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    let days = era * 146097 + doe - 719468 - 3657; // 3657: 1970-01-01 → 1980-01-06
    let secs = days as f64 * 86400.0 + t[0] * 3600.0 + t[1] * 60.0 + t[2];
    secs.rem_euclid(604_800.0)
}

fn reference(name: &str) -> Vec<(f64, [f64; 3])> {
    std::fs::read_to_string(data(name))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('%') && !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            (
                tow_of(f[0], f[1]),
                [f[2].parse().unwrap(), f[3].parse().unwrap(), f[4].parse().unwrap()],
            )
        })
        .collect()
}

/// Agreement asked of every comparison (m): median and 95th percentile.
const MEDIAN_MAX_M: f64 = 0.05;
const P95_MAX_M: f64 = 0.10;

/// Checks the distances of a comparison against the bounds.
fn assert_agrees(name: &str, n: usize, med: f64, p95: f64) {
    eprintln!("{name}: {n} matched, median {med:.4} m, p95 {p95:.4} m");
    assert!(med <= MEDIAN_MAX_M, "{name}: median {med} m");
    assert!(p95 <= P95_MAX_M, "{name}: p95 {p95} m");
}

/// Runs `cmsckf gnss … --csv` and returns `(matched, median, p95 3-D
/// distance, stderr)`.
fn compare(file: &str, iono: &str, week: &str, reference_file: &str) -> (usize, f64, f64, String) {
    compare_with(file, &[], iono, week, reference_file)
}

/// [`compare`] with extra arguments (a later `--systems` wins over the
/// default `G`).
fn compare_with(file: &str, extra: &[&str], iono: &str, week: &str, reference_file: &str) -> (usize, f64, f64, String) {
    compare_filtered(file, extra, iono, week, reference_file, |_| true)
}

/// [`compare_with`] over the epochs whose satellite count passes `keep`.
fn compare_filtered(
    file: &str,
    extra: &[&str],
    iono: &str,
    week: &str,
    reference_file: &str,
    keep: impl Fn(usize) -> bool,
) -> (usize, f64, f64, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_cmsckf"))
        .args(["gnss"])
        .arg(data(file))
        .args(extra)
        .args([
            "--iono",
            iono,
            "--elevation-mask-deg",
            "10",
            "--week-hint",
            week,
            "--csv",
        ])
        .args(if extra.contains(&"--systems") {
            &[][..]
        } else {
            &["--systems", "G"][..]
        })
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    let mut lines = text.lines();
    assert_eq!(
        lines.next().unwrap(),
        "gps_week,gps_tow_s,n_sats,ecef_x_m,ecef_y_m,ecef_z_m,lat_deg,lon_deg,height_m,pdop,residual_rms_m"
    );
    let ours: Vec<(f64, [f64; 3])> = lines
        .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect::<Vec<f64>>())
        .filter(|f| keep(f[2] as usize))
        .map(|f| (f[1], [f[3], f[4], f[5]]))
        .collect();
    let refs = reference(reference_file);
    let mut d: Vec<f64> = Vec::new();
    for (t, r) in &refs {
        if let Some((_, p)) = ours.iter().find(|(u, _)| (u * 10.0).round() == (t * 10.0).round()) {
            d.push(((p[0] - r[0]).powi(2) + (p[1] - r[1]).powi(2) + (p[2] - r[2]).powi(2)).sqrt());
        }
    }
    d.sort_by(|a, b| a.total_cmp(b));
    let median = if d.is_empty() { f64::INFINITY } else { d[d.len() / 2] };
    let p95 = if d.is_empty() {
        f64::INFINITY
    } else {
        d[((d.len() - 1) as f64 * 0.95).round() as usize]
    };
    (d.len(), median, p95, String::from_utf8_lossy(&out.stderr).to_string())
}

#[test]
fn station_3040_msm7_gps_iono_off() {
    let (n, med, p95, counts) = compare("3040_msm7.rtcm3", "off", "1316", "3040_rtklib_spp_gps_ionooff.pos");
    eprintln!("{counts}");
    assert!(n >= 96, "{n} epochs matched");
    assert_agrees("3040 MSM7", n, med, p95);
    assert!(counts.contains("1077:120") && counts.contains("1019:164") && counts.contains("CRC failures: 0"));
}

#[test]
fn station_3040_msm4_gps_iono_off() {
    let (n, med, p95, _) = compare("3040_msm4.rtcm3", "off", "1316", "3040_rtklib_spp_gps_ionooff.pos");
    assert!(n >= 96, "{n} epochs matched");
    assert_agrees("3040 MSM4", n, med, p95);
}

#[test]
fn station_3040_msm7_iono_free() {
    let (n, med, p95, _) = compare(
        "3040_msm7.rtcm3",
        "iono-free",
        "1316",
        "3040_rtklib_spp_gps_ionofree.pos",
    );
    assert!(n >= 96, "{n} epochs matched");
    assert_agrees("3040 iono-free", n, med, p95);
}

#[test]
fn gmsd7_gps_with_four_satellites() {
    // Week 1710 starts at 2012-10-14 00:00 GPST, inside the file.
    let (n, med, p95, counts) = compare(
        "GMSD7_20121014.rtcm3",
        "off",
        "1710",
        "GMSD7_rtklib_spp_gps_ionooff.pos",
    );
    eprintln!("{counts}");
    assert!(n >= 60, "{n} epochs matched");
    assert_agrees("GMSD7 G", n, med, p95);
    // The file ends mid-frame: the tail is reported, not decoded.
    assert!(counts.contains("truncated tail bytes: 302"), "{counts}");
}

/// A u-blox receiver's own raw log (legacy RXM-RAW and RXM-SFRB among
/// NMEA), its orbits from its own subframes, against RTKLIB. In stream
/// order every ephemeris is there from 05:59:48.999: 218 of 242 epochs.
#[test]
fn ubx_legacy_raw_and_subframes() {
    let (n, med, p95, counts) = compare(
        "ubx_20080526.ubx",
        "off",
        "1481",
        "ubx_20080526_rtklib_spp_gps_ionooff.pos",
    );
    eprintln!("{counts}");
    assert!(n >= 200, "{n} epochs matched");
    assert_agrees("u-blox RXM-RAW", n, med, p95);
    assert!(counts.contains("format: UBX"), "{counts}");
    assert!(counts.contains("02-10:242 02-11:842"), "{counts}");
    assert!(
        counts.contains("bytes skipped: 152266  truncated tail bytes: 18"),
        "{counts}"
    );
    assert!(counts.contains("ephemerides: 18"), "{counts}");
}

/// GPS + GLONASS on GMSD7 (a NetR9's MT1087 and MT1020) against RTKLIB's
/// GPS + GLONASS solution: over the epochs with the reference's seven
/// satellites, those after R15's ephemeris has arrived in stream order (the
/// earlier ones, with 4–6 satellites, are other solutions, 11 m away). The
/// 2012 data need GPS − UTC = 16 s, not today's 18, to place GLONASS's
/// Moscow time.
#[test]
fn gmsd7_gps_and_glonass() {
    let (n, med, p95, counts) = compare_filtered(
        "GMSD7_20121014.rtcm3",
        &["--systems", "G,R"],
        "off",
        "1710",
        "GMSD7_rtklib_spp_gr_ionooff.pos",
        |n_sats| n_sats == 7,
    );
    eprintln!("{counts}\nGMSD7 G+R, 7 satellites: {n} matched, median {med:.4} m, p95 {p95:.4} m");
    assert!(n >= 20, "{n} epochs with all seven satellites");
    assert!(med <= 0.2, "median {med} m (target 1 m)");
    assert!(p95 <= 0.3, "p95 {p95} m");
    assert!(counts.contains("1020:16"), "{counts}");
}

/// Legacy RTCM (1004 GPS L1/L2 with its code ambiguity, 1012 GLONASS,
/// 1019/1020 ephemerides, 1005): what many CORS networks and NTRIP casters
/// still send. RTKLIB's `testglo.rtcm3` against RTKLIB 2.4.3's single-point
/// solution of the same stream. The ephemerides arrive one per ten seconds,
/// so the comparison takes the epochs with every satellite RTKLIB used (9
/// GPS; 14 with GLONASS), as RTKLIB had all of them from its navigation
/// file.
#[test]
fn legacy_1004_gps_against_rtklib() {
    let (n, med, p95, counts) = compare_filtered(
        "testglo.rtcm3",
        &[],
        "off",
        "1562",
        "testglo_rtklib_spp_gps_ionooff.pos",
        |n_sats| n_sats == 9,
    );
    eprintln!("{counts}\nlegacy GPS: {n} matched, median {med:.4} m, p95 {p95:.4} m");
    assert!(n >= 80, "{n} epochs with all nine satellites");
    assert_agrees("testglo 1004", n, med, p95);
    assert!(counts.contains("1004:186") && counts.contains("1012:186"), "{counts}");
    assert!(counts.contains("undecodable: 0"), "{counts}");
}

#[test]
fn legacy_1004_and_1012_gps_and_glonass_against_rtklib() {
    let (n, med, p95, counts) = compare_filtered(
        "testglo.rtcm3",
        &["--systems", "G,R"],
        "off",
        "1562",
        "testglo_rtklib_spp_gr_ionooff.pos",
        |n_sats| n_sats == 14,
    );
    eprintln!("{counts}\nlegacy GPS + GLONASS, 14 satellites: {n} matched, median {med:.4} m, p95 {p95:.4} m");
    assert!(n >= 80, "{n} epochs with all fourteen satellites");
    assert!(med <= 0.05 && p95 <= 0.1, "median {med} m, p95 {p95} m from RTKLIB");
    // Every epoch solved, whatever the satellites it had so far: at least
    // 80 % of RTKLIB's, within 1 m (median) of its.
    let (n, med, _, _) = compare_with(
        "testglo.rtcm3",
        &["--systems", "G,R"],
        "off",
        "1562",
        "testglo_rtklib_spp_gr_ionooff.pos",
    );
    eprintln!("legacy GPS + GLONASS, every epoch: {n} of 186 matched, median {med:.4} m");
    assert!(n as f64 >= 0.8 * 186.0 && med <= 1.0, "{n} epochs, median {med} m");
}

/// 3040's RINEX-header position (ECEF, m): the antenna's surveyed point.
const SURVEYED_3040: &str = "-3978242.4348,3382841.1715,3649902.7667";

/// Code DGNSS of rover 3040 against base 0759 (3.3 km, MT1005 in its
/// stream) against RTKLIB's DGPS, and both of our solutions against the
/// surveyed position: the differential one must be the metre-better one.
#[test]
fn dgnss_3040_against_base_0759() {
    let base = data("0759_base_msm7.rtcm3");
    let base = base.to_str().unwrap();
    let extra = ["--base", base, "--surveyed-ecef-m", SURVEYED_3040];
    let (n, med, p95, counts) = compare_with(
        "3040_msm7.rtcm3",
        &extra,
        "off",
        "1316",
        "3040_0759_rtklib_dgps_gps.pos",
    );
    eprintln!("{counts}");
    assert!(n >= 96, "{n} epochs matched");
    assert_agrees("3040-0759 DGNSS", n, med, p95);
    assert!(
        counts.contains("base: station 759 at ECEF -3976219.5082, 3382372.5671, 3652512.9849 m"),
        "{counts}"
    );
    assert!(
        counts.contains("base frames by type: 1005:120 1019:162 1077:120"),
        "{counts}"
    );
    // "SPP: 120 epochs, distance from the surveyed position: median 5.256 m, ..."
    let median_of = |name: &str| -> f64 {
        let line = counts
            .lines()
            .find(|l| l.starts_with(name))
            .unwrap_or_else(|| panic!("{counts}"));
        let v = line.split("median ").nth(1).unwrap().split(' ').next().unwrap();
        v.parse().unwrap()
    };
    let (spp, dgnss) = (median_of("SPP:"), median_of("DGNSS:"));
    assert!(
        (4.5..6.0).contains(&spp),
        "SPP {spp} m from the surveyed point (RTKLIB: 5.25)"
    );
    assert!(dgnss < 0.7, "DGNSS {dgnss} m from the surveyed point (RTKLIB: 0.58)");
}

#[test]
fn bad_arguments_are_clear_errors() {
    let run = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_cmsckf")).args(args).output().unwrap();
        assert!(!o.status.success());
        let e = String::from_utf8_lossy(&o.stderr).to_string();
        assert!(!e.contains("panicked"), "{e}");
        e
    };
    assert!(run(&["gnss", "/no/such.rtcm3"]).contains("/no/such.rtcm3"));
    let f = data("3040_msm7.rtcm3");
    let f = f.to_str().unwrap();
    assert!(run(&["gnss", f, "--iono", "magic"]).contains("unknown ionosphere mode"));
    assert!(run(&["gnss", f, "--systems", "G,X"]).contains("unknown system"));
    assert!(run(&["gnss", f, "--systems", ","]).contains("no system given"));
    assert!(run(&["gnss", f, "--base", "/no/base.rtcm3"]).contains("/no/base.rtcm3"));
    assert!(run(&["gnss", f, "--surveyed-ecef-m", "1,2"]).contains("X,Y,Z"));
    assert!(run(&["gnss", f, "--base-max-age-s", "-1"]).contains("--base-max-age-s"));
}
