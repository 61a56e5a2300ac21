//! Criterion benchmarks of the real-time path. Workloads:
//! - `propagate`: one 100 Hz IMU sample through the filter (22 active states: IMU 15, clock 5, time offset 1, barometer offset 1;
//!   11 clones, 3 keyframes);
//! - `msckf_update/N`: one camera frame with N = 50, 100, 200 simulated features, 11 clones, compressed mode,
//!   taken from a racetrack flight after 10 s (2–3 keyframes);
//! - `gnss_update`: one GNSS epoch (pseudoranges and range rates, GPS and Galileo, each satellite's
//!   range bias and the zenith troposphere as states) fused at its own instant, on the same flight at
//!   10 s with GNSS on, compressed mode;
//! - `householder/400x73`: the camera update's stacked triangularisation (README §3, Q1) at its mean shape
//!   on udel_gore with OpenVINS's settings (400 rows, 72 state columns and the residual);
//! - `feature_line_decode`: parsing one 200-feature JSON line of the feature socket;
//! - `rtcm_decode`: framing, CRC and decoding of one real MSM7 epoch (station 3040).
//!
//! Run: `cargo bench --bench estimator`; results are in docs/performance.md.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};

use cmsckf::config::Config;
use cmsckf::estimator::ImuMeas;
use cmsckf::estimator::Mode;
use cmsckf::eval::{sim_config_for, Runner};
use cmsckf_sitl::dataset::Dataset;

fn warmed(cfg: &Config, per_frame: usize, until_s: f64) -> (Dataset, usize) {
    let mut sim = sim_config_for(cfg);
    sim.features.per_frame = per_frame;
    let ds = Dataset::generate("racetrack", 1, Some(until_s + 2.0), &sim).expect("dataset");
    let k = ds.frames.iter().position(|f| f.t_s >= until_s).unwrap_or(0);
    (ds, k)
}

fn bench_propagate(c: &mut Criterion) {
    let cfg = Config::default();
    let (ds, k) = warmed(&cfg, 100, 10.0);
    let mut run = Runner::new(&ds, &cfg, Mode::Compressed, 1);
    for i in 0..k {
        run.step_frame(i);
    }
    let mut est = run.est;
    let last = ds
        .imu
        .iter()
        .rev()
        .find(|m| m.t_s <= est.time_s() + 0.011)
        .copied()
        .expect("imu");
    let mut t = est.time_s();
    c.bench_function("propagate", |b| {
        b.iter(|| {
            t += 0.01;
            let _ = est.add_imu(ImuMeas {
                t_s: t,
                accel_mps2: last.accel_mps2,
                gyro_radps: last.gyro_radps,
            });
            est.propagate_to(t);
        })
    });
}

fn bench_msckf_update(c: &mut Criterion) {
    let cfg = Config::default();
    let mut g = c.benchmark_group("msckf_update");
    g.sample_size(30);
    for n in [50usize, 100, 200] {
        let (ds, k) = warmed(&cfg, n, 10.0);
        let mut run = Runner::new(&ds, &cfg, Mode::Compressed, 1);
        for i in 0..k {
            run.step_frame(i);
        }
        g.bench_function(format!("{n}"), |b| {
            b.iter_batched(|| run.clone(), |mut r| r.step_frame(k), BatchSize::LargeInput)
        });
    }
    g.finish();
}

fn bench_gnss_update(c: &mut Criterion) {
    let cfg = Config::default();
    let (ds, k) = warmed(&cfg, 100, 10.0);
    let mut run = Runner::new(&ds, &cfg, Mode::Compressed, 1).with_gnss_on_time();
    for i in 0..k {
        run.step_frame(i);
    }
    let (e, frame, sats) = run.gnss_epoch_after(run.est.time_s()).expect("an epoch ahead");
    let t_e = ds.gnss[e].t_s;
    // The filter brought to the epoch's instant, so each iteration is the
    // update alone.
    let mut est = run.est;
    let t0 = est.time_s();
    for m in ds.imu.iter().filter(|m| m.t_s > t0 && m.t_s <= t_e + 0.011) {
        let _ = est.add_imu(ImuMeas {
            t_s: m.t_s,
            accel_mps2: m.accel_mps2,
            gyro_radps: m.gyro_radps,
        });
    }
    est.propagate_to(t_e);
    let used = est.clone().process_gnss(t_e, &frame, &sats).expect("fused");
    println!(
        "gnss_update: {} satellites, {} pseudoranges and {} range rates used",
        sats.len(),
        used.pseudoranges_used,
        used.range_rates_used
    );
    c.bench_function("gnss_update", |b| {
        b.iter_batched(
            || est.clone(),
            |mut e| e.process_gnss(t_e, &frame, &sats).expect("fused"),
            BatchSize::LargeInput,
        )
    });
}

fn bench_householder(c: &mut Criterion) {
    use nalgebra::DMatrix;
    // A dense stand-in with the stacked system's mean shape (`evaluate
    // --scenario tum:udel_gore --sim-config config/sim-openvins.toml`: 400 rows
    // over 72 state columns a frame); its entries do not change the work.
    let (m, n) = (400, 73);
    let a = DMatrix::from_fn(m, n, |i, j| {
        ((i * 31 + j * 17) % 23) as f64 / 7.0 - 1.5 + (i as f64 * 0.1).sin()
    });
    c.bench_function("householder/400x73", |b| {
        b.iter_batched_ref(
            || a.clone(),
            |x| cmsckf::estimator::math::householder_in_place(x, n - 1),
            BatchSize::SmallInput,
        )
    });
}

fn bench_decode(c: &mut Criterion) {
    let mut line = String::from("{\"v\":1,\"t_us\":123456789,\"cam\":0,\"features\":[");
    for i in 0..200 {
        if i > 0 {
            line.push(',');
        }
        line += &format!(
            "[{},{:.3},{:.3}]",
            1000 + i,
            10.0 + i as f64 * 3.1,
            20.0 + i as f64 * 2.3
        );
    }
    line += "]}";
    c.bench_function("feature_line_decode", |b| {
        b.iter(|| cmsckf::io::feature_pipe::parse_line(line.as_bytes(), 1000).expect("valid line"))
    });

    let bytes = std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join("3040_msm7.rtcm3"),
    )
    .expect("3040 data");
    // The first MSM7 frame.
    let start = bytes.iter().position(|&b| b == 0xD3).expect("frame");
    let len = (((bytes[start + 1] & 3) as usize) << 8 | bytes[start + 2] as usize) + 6;
    let frame = bytes[start..start + len].to_vec();
    c.bench_function("rtcm_decode", |b| {
        let mut out = Vec::new();
        b.iter(|| {
            let mut d = cmsckf::gnss::rtcm::RtcmDecoder::new();
            out.clear();
            d.push(&frame, &mut out);
            assert_eq!(out.len(), 1);
        })
    });
}

criterion_group!(
    benches,
    bench_propagate,
    bench_msckf_update,
    bench_gnss_update,
    bench_householder,
    bench_decode
);
criterion_main!(benches);
