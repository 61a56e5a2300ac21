//! The Schmidt update (README §6) against the formula it replaced.
//!
//! The branch of the EKF update for Schmidt mode used to form `AᵀA` over the
//! whole state (n × n, `O(m·n²)`, the cost of the full update), zero its
//! keyframe block and subtract it. It now touches the keyframes only through
//! their cross-covariances (`math::add_gram_outside_block`, `O(m·n_A·n)`).
//! The former formula is kept here, and a filter runs it instead once
//! [`Estimator::set_schmidt_downdate`] is given it, so that single updates
//! and whole flights can be compared.

use nalgebra::{DMatrix, DMatrixView, DVector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use cmsckf::config::Config;
use cmsckf::estimator::{math, Estimator, Mode, ACTIVE_DIM};
use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;

/// The former Schmidt branch, verbatim: `K S Kᵀ = AᵀA` formed n × n, its
/// keyframe block zeroed, subtracted from `P`.
fn former_downdate(
    p: &mut DMatrix<f64>,
    alpha: f64,
    at: DMatrixView<'_, f64>,
    a: DMatrixView<'_, f64>,
    k0: usize,
    k1: usize,
) {
    assert_eq!(alpha, -1.0, "the former formula only subtracted");
    let n = p.nrows();
    let mut kskt = DMatrix::zeros(n, n);
    math::add_symmetric_product_t(&mut kskt, n, 1.0, at, a);
    kskt.view_mut((k0, k0), (k1 - k0, k1 - k0)).fill(0.0);
    *p -= kskt;
}

/// `max |P_ij − Q_ij| / √(R_ii R_jj)`: with `R` the covariance before the
/// update, the scale at which `P − AᵀA` rounds (a strong update cancels
/// most of `R_ii`, so the posterior's own diagonal would measure the
/// cancellation, not the formula).
fn normalised_diff(p: &DMatrix<f64>, q: &DMatrix<f64>, r: &DMatrix<f64>) -> f64 {
    assert_eq!(p.shape(), q.shape());
    assert_eq!(p.shape(), r.shape());
    let d = r.diagonal();
    assert!(d.iter().all(|v| *v > 0.0), "covariance has a non-positive diagonal");
    let mut worst: f64 = 0.0;
    for j in 0..q.ncols() {
        for i in 0..q.nrows() {
            worst = worst.max((p[(i, j)] - q[(i, j)]).abs() / (d[i] * d[j]).sqrt());
        }
    }
    worst
}

/// A random symmetric positive-definite matrix whose scales span four
/// decades, exactly symmetric.
fn random_spd(rng: &mut ChaCha8Rng, n: usize) -> DMatrix<f64> {
    let m = DMatrix::from_fn(n, n + 5, |_, _| rng.random_range(-1.0..1.0));
    let s = DVector::from_fn(n, |_, _| 10f64.powf(rng.random_range(-3.0..1.0)));
    let mut p = &m * m.transpose() / (n as f64) + DMatrix::identity(n, n) * 0.05;
    for j in 0..n {
        for i in 0..n {
            p[(i, j)] *= s[i] * s[j];
        }
    }
    (&p + p.transpose()) * 0.5
}

/// A racetrack flight in Schmidt mode with a keyframe every second, so that
/// the state is past the kernels' block and tile sizes.
fn schmidt_flight(seed: u64, duration_s: f64) -> (Dataset, Config) {
    let mut cfg = Config::default();
    cfg.keyframe.interval_s = 1.0;
    let ds = Dataset::generate("racetrack", seed, Some(duration_s), &eval::sim_config_for(&cfg)).unwrap();
    (ds, cfg)
}

/// One update in both forms from the same state: the covariances agree to
/// 1e-12 per entry relative to `√(P_ii P_jj)`, the new one is exactly
/// symmetric with its keyframe block bit-for-bit unchanged, and the
/// nominal states are identical (the correction is common code).
fn check_update(est: &Estimator, h: &DMatrix<f64>, cols: &[usize], r: &DVector<f64>, upper: bool, what: &str) -> f64 {
    let (k0, k1) = (ACTIVE_DIM, est.clones_offset());
    let mut new = est.clone();
    new.ekf_update(h, cols, r, upper);
    let mut old = est.clone();
    old.set_schmidt_downdate(former_downdate);
    old.ekf_update(h, cols, r, upper);
    assert_eq!(new.stats.rejected, est.stats.rejected, "{what}: update refused");
    let (p_new, p_old, p_est) = (new.covariance(), old.covariance(), est.covariance());
    let d = normalised_diff(p_new, p_old, p_est);
    assert!(d <= 1e-12, "{what}: new and former Schmidt covariances differ by {d:e}");
    assert_eq!(p_new, &p_new.transpose(), "{what}: not exactly symmetric");
    assert_eq!(
        p_new.view((k0, k0), (k1 - k0, k1 - k0)),
        p_est.view((k0, k0), (k1 - k0, k1 - k0)),
        "{what}: P_SS changed"
    );
    let x_new = new.snapshot().x;
    assert_eq!(x_new, old.snapshot().x, "{what}: nominal states differ");
    // Each keyframe's chart `[δ, p]`, in id order after the IMU, the clock,
    // the time offset and the clones (the snapshot's layout).
    let x_est = est.snapshot().x;
    let kf0 = ACTIVE_DIM + 6 * est.n_clones();
    for (j, kf) in est.keyframes().enumerate() {
        let id = kf.id;
        assert_eq!(
            x_new.rows(kf0 + 6 * j, 6),
            x_est.rows(kf0 + 6 * j, 6),
            "{what}: keyframe {id} corrected"
        );
    }
    // The update did something to the cross-covariances.
    assert!(
        p_new.view((0, k0), (k0, k1 - k0)) != p_est.view((0, k0), (k0, k1 - k0)),
        "{what}: P_AS unchanged"
    );
    d
}

/// The new Schmidt branch equals the former formula on one update, from a
/// state built in Schmidt mode, with its own covariance and with random SPD
/// ones (also one with pose-like states after the clones, which are
/// updated), for dense and sparse, tall and wide, and upper-triangular (Q1)
/// Jacobians with columns in the active block, the keyframes and the clones.
#[test]
fn schmidt_update_equals_the_former_formula() {
    let (ds, cfg) = schmidt_flight(3, 25.0);
    let mut run = eval::Runner::new(&ds, &cfg, Mode::Schmidt, 3);
    for k in 0..ds.frames.len() {
        run.step_frame(k);
    }
    let base = run.est.clone();
    let (k0, k1) = (ACTIVE_DIM, base.clones_offset());
    let n = base.covariance().nrows();
    assert!(k1 - k0 >= 6 * 15, "only {} keyframes", (k1 - k0) / 6);
    assert!(n > k1, "no clones");

    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut worst: f64 = 0.0;
    let mut states = vec![("flight", base.clone())];
    let mut random = base.clone();
    random.set_covariance(random_spd(&mut rng, n));
    states.push(("random P", random));
    // States after the clones (the updated set is not contiguous on either
    // side of the keyframes); the nominal correction ignores them.
    let mut extra = base.clone();
    extra.set_covariance(random_spd(&mut rng, n + 12));
    states.push(("random P, 12 states after the clones", extra));

    for (name, est) in &states {
        let n = est.covariance().nrows();
        let kf_cols: Vec<usize> = (k0..k1).collect();
        let mut sparse: Vec<usize> = (0..9).collect();
        sparse.extend(k0 + 6..k0 + 18);
        sparse.extend(k1 - 6..k1);
        sparse.extend(k1 + 12..n);
        let cases: Vec<(&str, Vec<usize>, usize, bool)> = vec![
            ("dense, all columns", (0..n).collect(), 40, false),
            ("dense, one row", (0..n).collect(), 1, false),
            ("sparse columns, tall", sparse.clone(), sparse.len() + 10, false),
            ("sparse columns, wide", sparse.clone(), 20, false),
            ("upper triangular (Q1)", sparse.clone(), sparse.len(), true),
            ("active block only (GNSS)", (0..ACTIVE_DIM).collect(), 3, false),
            ("keyframes only", kf_cols, 12, false),
        ];
        for (case, cols, m, upper) in cases {
            let c = cols.len();
            let mut h = DMatrix::from_fn(m, c, |_, _| rng.random_range(-1.0..1.0));
            if upper {
                for j in 0..c {
                    for i in j + 1..c {
                        h[(i, j)] = 0.0;
                    }
                }
            }
            // Scale H to the state: P_jj^-1/2 on column j, times a few,
            // so that the update is strong but S stays well conditioned.
            for (j, &col) in cols.iter().enumerate() {
                let s = 3.0 / est.covariance()[(col, col)].sqrt();
                h.column_mut(j).scale_mut(s);
            }
            let r = DVector::from_fn(m, |_, _| rng.random_range(-1.0..1.0));
            let d = check_update(est, &h, &cols, &r, upper, &format!("{name}, {case}"));
            worst = worst.max(d);
        }
    }
    eprintln!("worst normalised difference, new vs former Schmidt update: {worst:e}");
}

/// A Schmidt flight (camera and GNSS, loop closures on keyframes) with the
/// new update equals the same flight with the former formula, frame by
/// frame: from the new filter's state at every frame, the former formula
/// gives the same events, tracks and updates, and a state and covariance
/// equal to 1e-10 (`Snapshot::max_rel_diff`; a few ulps per update). Each
/// frame starts both from one state: run apart over the whole flight, the
/// two drift as any two nonlinear filters do, round-off amplified (README,
/// "Compressed equals full"), and on the armed, vibrating IMU passed 1e-10
/// at frame 822.
#[test]
fn schmidt_flight_equals_the_former_formula() {
    let (ds, cfg) = schmidt_flight(4, 60.0);
    let mut new = eval::Runner::new(&ds, &cfg, Mode::Schmidt, 4).with_gnss();
    let mut worst: f64 = 0.0;
    for k in 0..ds.frames.len() {
        let mut old = new.clone();
        old.est.set_schmidt_downdate(former_downdate);
        let (_, rep_new) = new.step_frame(k);
        let (_, rep_old) = old.step_frame(k);
        assert_eq!(rep_new.tracks_used, rep_old.tracks_used, "frame {k}");
        assert_eq!(rep_new.events, rep_old.events, "frame {k}");
        assert_eq!(new.est.stats, old.est.stats, "frame {k}");
        let d = new.est.snapshot().max_rel_diff(&old.est.snapshot());
        worst = worst.max(d);
        assert!(d <= 1e-10, "frame {k}: new and former Schmidt filters differ by {d:e}");
    }
    let s = &new.est.stats;
    assert!(s.loop_closure_updates > 0, "no loop closure on a keyframe");
    let n_keyframes = (new.est.clones_offset() - ACTIVE_DIM) / 6;
    assert!(n_keyframes >= 40, "only {n_keyframes} keyframes");
    assert!(!new.clock_errors.is_empty(), "no GNSS epoch fused");
    eprintln!(
        "{} frames, {} updates, {} loop-closure updates, {} keyframes: worst difference {worst:e}",
        ds.frames.len(),
        s.updates,
        s.loop_closure_updates,
        n_keyframes
    );
}
