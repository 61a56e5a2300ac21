//! Simulated flights for the estimator's integration tests: a scenario
//! generated with the default simulator and config, the one set-up the
//! exactness, GNSS and time-offset tests share.

use cmsckf::config::Config;
use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;

/// A scenario with the default simulator and config.
pub fn scenario(scenario: &str, seed: u64, duration_s: f64) -> (Dataset, Config) {
    let cfg = Config::default();
    let ds = Dataset::generate(scenario, seed, Some(duration_s), &eval::sim_config_for(&cfg)).unwrap();
    (ds, cfg)
}

/// The racetrack with the default simulator and config.
pub fn racetrack(seed: u64, duration_s: f64) -> (Dataset, Config) {
    scenario("racetrack", seed, duration_s)
}

/// The simulator of `config/sim-calibrated.toml` (a calibrated IMU: 100 Hz,
/// a 0.002 rad/s σ turn-on gyro bias, no vibration; the default is an armed
/// multirotor's raw IMU), with the camera and IMU noise of `cfg`.
pub fn calibrated_sim(cfg: &Config) -> cmsckf_sitl::config::SimConfig {
    let mut sim = cmsckf_sitl::config::SimConfig::from_toml(include_str!("../../config/sim-calibrated.toml")).unwrap();
    sim.camera = cfg.camera.clone();
    sim.imu = cfg.imu.clone();
    sim
}

/// The gyro bias's error at the end of `ds` in the filter's own sigmas,
/// per axis: `|b̂_g − b_g| / σ`.
pub fn gyro_bias_error_sigmas(est: &cmsckf::estimator::Estimator, ds: &Dataset) -> nalgebra::Vector3<f64> {
    let err = est.imu_state().b_g - ds.truth.last().unwrap().bias.b_g;
    let sigma = est.imu_covariance().fixed_view::<3, 3>(9, 9).diagonal().map(f64::sqrt);
    err.component_div(&sigma).abs()
}
