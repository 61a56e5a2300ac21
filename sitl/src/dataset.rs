//! A whole simulated flight: truth at every IMU sample, IMU, camera frames and
//! GNSS epochs, from a scenario, a seed and a duration.
//!
//! Each sensor draws from its own ChaCha8 stream derived from the seed, so the
//! same scenario and seed give a bit-identical dataset, and switching one
//! sensor off does not change the others' noise.
//!
//! Real sensors are late and off-clock, and so are these: a camera frame is
//! exposed on the IMU clock's frame grid `k / rate`, stamped by the camera's
//! clock `camera_time_offset_s` earlier (`t_imu = t_cam + t_d`) and
//! delivered `camera_latency_s` after its exposure; a GNSS epoch is
//! delivered `gnss.latency_s` after its instant. The latencies are drawn
//! uniformly per frame and per epoch from streams of their own, so the
//! sensors' noise is the same with and without them.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::config::SimConfig;
use crate::features::FeatureSim;
use crate::gnss::GnssModel;
use crate::imu::{gauss3, ImuBias, ImuModel};
use crate::trajectory::{GustField, Trajectory, TrajectoryError, TruthSample};
use cmsckf_models::camera::Camera;

pub use crate::flight::{Dataset, TruthRow};
use crate::render::{Renderer, World};
use crate::rng::rng_for;

/// Height above the start (m) and speed (m/s) under which the vehicle is
/// on the ground ([`Dataset::on_ground`]; the simulated autopilot's land
/// detector, [`Dataset::landed_at`], says so from that truth).
pub const LANDED_HEIGHT_M: f64 = 0.1;
pub const LANDED_SPEED_MPS: f64 = 0.1;
/// The land detector's look-ahead is checked at this spacing (s): no
/// multirotor leaves the ground and comes back within it.
pub const LAND_DETECTOR_STEP_S: f64 = 0.05;

/// A draw from `[lo, hi]` (s), uniform; exactly `lo` when they are equal.
fn uniform_in(range: [f64; 2], rng: &mut ChaCha8Rng) -> f64 {
    range[0] + (range[1] - range[0]) * rng.random::<f64>()
}

impl Dataset {
    /// Generates the flight. `duration_s = None` takes the scenario's own
    /// length (70 s, or the TUM file's span); an analytic scenario starts
    /// with `cfg.standstill_s` on the ground.
    pub fn generate(
        scenario: &str,
        seed: u64,
        duration_s: Option<f64>,
        cfg: &SimConfig,
    ) -> Result<Self, TrajectoryError> {
        if let Some(dir) = scenario.strip_prefix("euroc:") {
            return crate::euroc::load(std::path::Path::new(dir), cfg);
        }
        let gusts = GustField::new(&cfg.wind, &mut rng_for(seed, 10));
        let traj = Trajectory::from_scenario(scenario, duration_s, cfg.standstill_s, &gusts)?;
        Ok(Self::from_trajectory(&traj, seed, cfg))
    }

    pub fn from_trajectory(traj: &Trajectory, seed: u64, cfg: &SimConfig) -> Self {
        let duration = traj.duration_s;
        let mut rng_bias = rng_for(seed, 1);
        let mut rng_imu = rng_for(seed, 2);
        let mut rng_cam = rng_for(seed, 3);
        let mut rng_gnss = rng_for(seed, 4);
        let mut rng_cam_latency = rng_for(seed, 5);
        let mut rng_gnss_latency = rng_for(seed, 6);

        let bias0 = ImuBias {
            b_a: gauss3(&mut rng_bias) * cfg.accel_bias0_sigma,
            b_g: gauss3(&mut rng_bias) * cfg.gyro_bias0_sigma,
        };
        let mut imu_model =
            ImuModel::new(&cfg.imu, cfg.imu_rate_hz, bias0).with_vibration(&cfg.vibration, &mut rng_for(seed, 7));
        let n_imu = (duration * cfg.imu_rate_hz).floor() as usize + 1;
        let mut truth = Vec::with_capacity(n_imu);
        let mut imu = Vec::with_capacity(n_imu);
        for k in 0..n_imu {
            let t = k as f64 / cfg.imu_rate_hz;
            let s = traj.sample(t);
            let (m, b) = imu_model.measure(&s, &mut rng_imu);
            truth.push(TruthRow { truth: s, bias: b });
            imu.push(m);
        }

        let true_camera = cfg.lens.draw(&cfg.camera, &mut rng_for(seed, 12));
        let mut fsim = FeatureSim::new(
            &cfg.features,
            Camera::from_config(&true_camera),
            cfg.camera.pixel_noise_px,
        );
        let n_cam = (duration * cfg.camera.rate_hz).floor() as usize + 1;
        let frames = (0..n_cam)
            .map(|k| {
                let t_exposure_s = k as f64 / cfg.camera.rate_hz;
                fsim.frame(&traj.sample(t_exposure_s), &mut rng_cam).stamped(
                    cfg.camera_time_offset_s,
                    uniform_in(cfg.camera_latency_s, &mut rng_cam_latency),
                )
            })
            .collect();

        let mut gnss_model = GnssModel::new(&cfg.gnss, &mut rng_gnss).for_flight(seed);
        let gnss = if cfg.gnss.enabled {
            let n = (duration * cfg.gnss.rate_hz).floor() as usize + 1;
            (0..n)
                .map(|k| {
                    gnss_model
                        .epoch_at(traj, k as f64 / cfg.gnss.rate_hz, &mut rng_gnss)
                        .delivered(uniform_in(cfg.gnss.latency_s, &mut rng_gnss_latency))
                })
                .collect()
        } else {
            Vec::new()
        };
        let base = &cfg.gnss.base;
        let p_base = nalgebra::Vector3::from(base.p_base_in_W_m);
        let (base_gnss, base_arp_ecef_m) = if cfg.gnss.enabled && base.enabled {
            let mut rng = rng_for(seed, 8);
            let mut rng_latency = rng_for(seed, 9);
            let mut model = gnss_model.base_station((-4_000.0, -2.0), seed);
            let n = (duration * cfg.gnss.rate_hz).floor() as usize + 1;
            let epochs = (0..n)
                .map(|k| {
                    let mut ep = model
                        .static_epoch_at(&p_base, k as f64 / cfg.gnss.rate_hz, &mut rng)
                        .delivered(uniform_in(base.latency_s, &mut rng_latency));
                    if !base.galileo {
                        ep.sats.retain(|s| s.system != cmsckf_models::gnss::System::Galileo);
                    }
                    ep
                })
                .collect();
            (epochs, Some(gnss_model.frame.to_ecef(&p_base).into()))
        } else {
            (Vec::new(), None)
        };
        Self {
            scenario: traj.name.clone(),
            seed,
            duration_s: duration,
            cfg: cfg.clone(),
            truth,
            imu,
            frames,
            frame_images: Vec::new(),
            gnss,
            base_gnss,
            base_arp_ecef_m,
            ephemerides: gnss_model.ephemerides,
            track_stats: fsim.stats,
            true_camera: Some(true_camera),
            trajectory: traj.clone(),
        }
    }

    /// The camera as the flight saw it: its true lens if simulated, else
    /// the calibration (the best a recorded flight knows).
    pub fn camera_as_flown(&self) -> &cmsckf_models::sensors::CameraConfig {
        self.true_camera.as_ref().unwrap_or(&self.cfg.camera)
    }

    /// How far the flight's lens puts each pixel from where its
    /// calibration does (RMS over the image, px; `crate::lens`); `None`
    /// for a recorded flight.
    pub fn lens_rms_px(&self) -> Option<f64> {
        self.true_camera
            .as_ref()
            .map(|lens| crate::lens::reprojection_rms_px(&self.cfg.camera, lens))
    }

    /// The autopilot's landed state at flight time `t_s`, as its land
    /// detector reports it (`EXTENDED_SYS_STATE`): on the ground while the
    /// vehicle stays on the ground ([`Self::on_ground`]) from `t_s` to
    /// `autopilot.land_detector_lead_s` later (checked every
    /// [`LAND_DETECTOR_STEP_S`]): in the lead before each lift-off its
    /// motors spin up and the detector already says "in the air", and a hop
    /// or a stop shorter than the lead is never called landed. A flight
    /// started in the air is never on the ground at its start height
    /// unless it stops there.
    pub fn landed_at(&self, t_s: f64) -> bool {
        let lead_s = self.cfg.autopilot.land_detector_lead_s.max(0.0);
        let steps = (lead_s / LAND_DETECTOR_STEP_S).ceil() as usize;
        (0..=steps).all(|k| self.on_ground_at(t_s + (k as f64 * LAND_DETECTOR_STEP_S).min(lead_s)))
    }

    /// Whether the vehicle is on the ground at flight time `t_s`, truly
    /// ([`Self::on_ground`]).
    pub fn on_ground_at(&self, t_s: f64) -> bool {
        self.on_ground(&self.trajectory.sample(t_s))
    }

    /// The truth of a sample already taken: on the ground while the vehicle
    /// is within [`LANDED_HEIGHT_M`] of where it started and slower than
    /// [`LANDED_SPEED_MPS`].
    pub fn on_ground(&self, s: &TruthSample) -> bool {
        self.truth.first().is_some_and(|start| {
            (s.p_B_in_W.z - start.truth.p_B_in_W.z).abs() < LANDED_HEIGHT_M && s.v_B_in_W.norm() < LANDED_SPEED_MPS
        })
    }

    /// One summary line per sensor: rate, count and noise.
    pub fn summary(&self) -> Vec<String> {
        let c = &self.cfg;
        let dt = 1.0 / c.imu_rate_hz;
        let standstill = if self.scenario.starts_with("tum:") {
            String::new()
        } else {
            format!(", {:.1} s standstill before take-off", c.standstill_s)
        };
        let mut out = vec![format!(
            "truth:  {:.1} s of '{}' (seed {}), {} samples{standstill}",
            self.duration_s,
            self.scenario,
            self.seed,
            self.truth.len()
        )];
        out.push(format!(
            "imu:    {:.1} Hz, {} samples, accel σ {:.4} m/s² ({:.2e} m/s²/√Hz), gyro σ {:.5} rad/s ({:.2e} rad/s/√Hz)",
            c.imu_rate_hz,
            self.imu.len(),
            c.imu.accel_noise_density / dt.sqrt(),
            c.imu.accel_noise_density,
            c.imu.gyro_noise_density / dt.sqrt(),
            c.imu.gyro_noise_density
        ));
        let s = &self.track_stats;
        out.push(format!(
            "camera: {:.1} Hz, {} frames, {:.1} features/frame, σ {:.2} px, lens {} off its calibration, {} landmarks, \
             {} re-identifications, {} outliers; clock offset t_d {:+.1} ms (t_imu = t_cam + t_d), delivered {:.0}–{:.0} ms after exposure",
            c.camera.rate_hz,
            self.frames.len(),
            s.observations as f64 / s.frames.max(1) as f64,
            c.camera.pixel_noise_px,
            self.lens_rms_px().map_or("unknown".to_string(), |px| format!("{px:.2} px RMS")),
            s.landmarks,
            s.reidentified,
            s.outliers,
            c.camera_time_offset_s * 1e3,
            c.camera_latency_s[0] * 1e3,
            c.camera_latency_s[1] * 1e3
        ));
        let nsat: usize = self.gnss.iter().map(|e| e.sats.len()).sum();
        let a = c.gnss.p_A_in_B_m;
        out.push(format!(
            "gnss:   {:.1} Hz, {} epochs, {:.1} satellites/epoch, pseudorange σ {:.2} m, rate σ {:.3} m/s at zenith; \
             delivered {:.2}–{:.2} s after the epoch, antenna at [{:.3}, {:.3}, {:.3}] m body FRD ({:.3} m from the IMU)",
            if c.gnss.enabled { c.gnss.rate_hz } else { 0.0 },
            self.gnss.len(),
            nsat as f64 / self.gnss.len().max(1) as f64,
            c.gnss.pseudorange_noise_m,
            c.gnss.pseudorange_rate_noise_mps,
            c.gnss.latency_s[0],
            c.gnss.latency_s[1],
            a[0],
            a[1],
            a[2],
            (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
        ));
        out
    }

    /// Writes `truth.csv`, `imu.csv`, `features.csv` and `gnss.csv` into `dir`.
    /// In `features.csv`, `t_s` is the camera's stamp and `t_exposure_s`,
    /// `t_delivered_s` are on the IMU clock; in `gnss.csv`, `t_s` is the
    /// epoch and `t_delivered_s` its arrival, both on the IMU clock.
    pub fn write_csv(&self, dir: &Path) -> std::io::Result<()> {
        std::fs::create_dir_all(dir)?;
        let mut s = String::from("t_s,p_n_m,p_e_m,p_d_m,v_n_mps,v_e_mps,v_d_mps,qw,qx,qy,qz,w_x_radps,w_y_radps,w_z_radps,ba_x,ba_y,ba_z,bg_x,bg_y,bg_z\n");
        for r in &self.truth {
            let t = &r.truth;
            let q = t.q_W_B.quaternion();
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                t.t_s,
                t.p_B_in_W.x,
                t.p_B_in_W.y,
                t.p_B_in_W.z,
                t.v_B_in_W.x,
                t.v_B_in_W.y,
                t.v_B_in_W.z,
                q.w,
                q.i,
                q.j,
                q.k,
                t.w_B.x,
                t.w_B.y,
                t.w_B.z,
                r.bias.b_a.x,
                r.bias.b_a.y,
                r.bias.b_a.z,
                r.bias.b_g.x,
                r.bias.b_g.y,
                r.bias.b_g.z
            );
        }
        write_file(&dir.join("truth.csv"), &s)?;
        let mut s = String::from("t_s,ax_mps2,ay_mps2,az_mps2,gx_radps,gy_radps,gz_radps\n");
        for m in &self.imu {
            let (a, g) = (m.accel_mps2, m.gyro_radps);
            let _ = writeln!(s, "{},{},{},{},{},{},{}", m.t_s, a.x, a.y, a.z, g.x, g.y, g.z);
        }
        write_file(&dir.join("imu.csv"), &s)?;
        let mut s = String::from("t_s,t_exposure_s,t_delivered_s,landmark_id,u_px,v_px\n");
        for f in &self.frames {
            for o in &f.features {
                let _ = writeln!(
                    s,
                    "{},{},{},{},{},{}",
                    f.t_s, f.t_exposure_s, f.t_delivered_s, o.landmark_id, o.u_px, o.v_px
                );
            }
        }
        write_file(&dir.join("features.csv"), &s)?;
        let mut s = String::from("t_s,t_delivered_s,gps_week,gps_tow_s,prn,pseudorange_m,pseudorange_rate_mps,cn0_dbhz,elevation_deg,clock_bias_m,clock_drift_mps\n");
        for e in &self.gnss {
            for o in &e.sats {
                let _ = writeln!(
                    s,
                    "{},{},{},{},{},{},{},{},{},{},{}",
                    e.t_s,
                    e.t_delivered_s,
                    e.week,
                    e.tow_s,
                    o.prn,
                    o.pseudorange_m,
                    o.pseudorange_rate_mps,
                    o.cn0_dbhz,
                    o.elevation_deg,
                    e.clock_bias_m,
                    e.clock_drift_mps
                );
            }
        }
        write_file(&dir.join("gnss.csv"), &s)
    }
}

impl Renderer {
    /// The renderer of a simulated flight: its world drawn around its
    /// trajectory from its seed, its camera and `[render]` settings.
    pub fn for_dataset(ds: &Dataset) -> Self {
        Self::new(
            World::around(&ds.trajectory, ds.seed),
            Camera::from_config(ds.camera_as_flown()),
            ds.cfg.render.clone(),
        )
    }
}

fn write_file(path: &Path, s: &str) -> std::io::Result<()> {
    let mut f = std::fs::File::create(path)?;
    f.write_all(s.as_bytes())?;
    f.sync_all()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On the ground through the standstill, in the air once climbing; the
    /// land detector says "in the air" its lead before the truth rises.
    #[test]
    fn the_vehicle_is_landed_until_it_takes_off() {
        let cfg = SimConfig::new();
        let ds = Dataset::generate("hover", 1, Some(20.0), &cfg).unwrap();
        assert!(ds.on_ground_at(0.0) && ds.on_ground_at(cfg.standstill_s - 0.5));
        let airborne = (0..200)
            .map(|k| f64::from(k) * 0.1)
            .filter(|t| !ds.on_ground_at(*t))
            .count();
        assert!(airborne > 50, "airborne {airborne} of 200 instants");
        assert!(!ds.on_ground_at(19.9), "hovering at 19.9 s is not landed");
        // The first instant off the ground, by the truth and by the
        // detector (0.01 s steps).
        let first = |f: &dyn Fn(f64) -> bool| (0..2000).map(|k| f64::from(k) * 0.01).find(|t| !f(*t));
        let (rose, said) = (
            first(&|t| ds.on_ground_at(t)).unwrap(),
            first(&|t| ds.landed_at(t)).unwrap(),
        );
        let lead = cfg.autopilot.land_detector_lead_s;
        assert!(lead > 1.0);
        assert!((rose - said - lead).abs() < 0.02, "rose at {rose} s, said at {said} s");
        // An autopilot that reports the truth says it as the truth leaves.
        let mut truthful = cfg.clone();
        truthful.autopilot = crate::config::AutopilotSimConfig::truth();
        let ds = Dataset::generate("hover", 1, Some(20.0), &truthful).unwrap();
        assert!((0..2000)
            .map(|k| f64::from(k) * 0.01)
            .all(|t| ds.landed_at(t) == ds.on_ground_at(t)));
    }

    #[test]
    fn same_seed_same_files_other_seed_differs() {
        let cfg = SimConfig::new();
        let a = Dataset::generate("figure8", 7, Some(5.0), &cfg).unwrap();
        let b = Dataset::generate("figure8", 7, Some(5.0), &cfg).unwrap();
        let c = Dataset::generate("figure8", 8, Some(5.0), &cfg).unwrap();
        let dir = tempfile::tempdir().unwrap();
        a.write_csv(&dir.path().join("a")).unwrap();
        b.write_csv(&dir.path().join("b")).unwrap();
        c.write_csv(&dir.path().join("c")).unwrap();
        for f in ["truth.csv", "imu.csv", "features.csv", "gnss.csv"] {
            let fa = std::fs::read(dir.path().join("a").join(f)).unwrap();
            let fb = std::fs::read(dir.path().join("b").join(f)).unwrap();
            let fc = std::fs::read(dir.path().join("c").join(f)).unwrap();
            assert!(fa.len() > 100, "{f} is empty");
            assert_eq!(fa, fb, "{f} differs between identical runs");
            assert_ne!(fa, fc, "{f} does not depend on the seed");
        }
        assert_eq!(a.imu.len(), (5.0 * cfg.imu_rate_hz) as usize + 1);
        assert_eq!(a.frames.len(), 151);
        assert_eq!(a.gnss.len(), 6);
        let summary = a.summary().join("\n");
        for part in [
            "standstill",
            "t_d +12.0 ms",
            "30–60 ms",
            "0.20–0.60 s",
            "0.150 m from the IMU",
        ] {
            assert!(summary.contains(part), "{part}: {summary}");
        }
    }

    /// A frame is exposed on the IMU clock's grid, its features are the
    /// projections of the landmarks from the truth at that exposure (not at
    /// its stamp), its stamp is the camera clock's `t_exposure − t_d`, and
    /// it is delivered within the latency range.
    #[test]
    fn frames_are_exposed_on_the_imu_clock_stamped_by_the_camera_and_late() {
        use nalgebra::{Point3, Vector2, Vector3};
        let mut cfg = SimConfig::new();
        cfg.standstill_s = 0.0; // moving from the start, so the times differ in pixels
        cfg.camera.pixel_noise_px = 0.0;
        cfg.features.outlier_prob = 0.0;
        let seed = 3;
        let ds = Dataset::generate("racetrack", seed, Some(3.0), &cfg).unwrap();
        // Seen through its own lens, drawn off the calibration ...
        assert!(ds.true_camera.as_ref().is_some_and(|lens| *lens != cfg.camera));
        assert!(ds.lens_rms_px().is_some_and(|px| px > 0.0));
        let cam = Camera::from_config(ds.camera_as_flown());
        // The same front end on the same stream, fed the truth at exposure.
        let mut sim = FeatureSim::new(&cfg.features, cam.clone(), 0.0);
        let mut rng = rng_for(seed, 3);
        let [lo, hi] = cfg.camera_latency_s;
        let (mut lat_min, mut lat_max, mut off_px) = (f64::MAX, 0.0f64, 0.0f64);
        let (calibrated, mut lens_px) = (Camera::from_config(&cfg.camera), 0.0f64);
        for (k, f) in ds.frames.iter().enumerate() {
            assert_eq!(f.t_exposure_s, k as f64 / cfg.camera.rate_hz);
            assert!((f.t_s - (f.t_exposure_s - 0.012)).abs() < 1e-12, "{f:?}");
            let lat = f.t_delivered_s - f.t_exposure_s;
            assert!(lat >= lo && lat <= hi, "latency {lat}");
            (lat_min, lat_max) = (lat_min.min(lat), lat_max.max(lat));
            let truth = ds.trajectory.sample(f.t_exposure_s);
            assert_eq!(sim.frame(&truth, &mut rng).features, f.features);
            let by_id: std::collections::BTreeMap<u64, Vector3<f64>> = sim
                .landmarks()
                .iter()
                .filter_map(|l| l.id().map(|id| (id, l.p_in_W)))
                .collect();
            let T_C_W = sim.camera_pose(&truth).inverse();
            let T_C_W_at_stamp = sim.camera_pose(&ds.trajectory.sample(f.t_s)).inverse();
            for o in &f.features {
                let p = Point3::from(by_id[&o.landmark_id]);
                let uv = Vector2::new(o.u_px, o.v_px);
                let proj = cam.project(&(T_C_W * p).coords).unwrap();
                assert!((proj - uv).norm() < 1e-6, "{proj} vs {uv}");
                if let Some(cal) = calibrated.project(&(T_C_W * p).coords) {
                    lens_px = lens_px.max((cal - uv).norm());
                }
                if let Some(at_stamp) = cam.project(&(T_C_W_at_stamp * p).coords) {
                    off_px = off_px.max((at_stamp - uv).norm());
                }
            }
        }
        assert!(off_px > 1.0, "the stamp's pose projects within {off_px} px");
        // ... which puts the features a fraction of a pixel from where the
        // calibration would.
        assert!(
            lens_px > 0.01 && lens_px < 2.0,
            "the lens moves a feature by up to {lens_px} px"
        );
        assert!(lat_min < lo + 0.003 && lat_max > hi - 0.003, "{lat_min}..{lat_max}");
    }

    #[test]
    fn gnss_epochs_are_delivered_late() {
        let cfg = SimConfig::new();
        let ds = Dataset::generate("hover", 4, Some(40.0), &cfg).unwrap();
        let [lo, hi] = cfg.gnss.latency_s;
        let lat: Vec<f64> = ds.gnss.iter().map(|e| e.t_delivered_s - e.t_s).collect();
        assert_eq!(lat.len(), 41);
        for (k, e) in ds.gnss.iter().enumerate() {
            // The epoch is the receiver's tag k/rate at true time tag − δt.
            assert!((e.t_s - (k as f64 - e.clock_bias_m / cmsckf_models::geodesy::C_MPS)).abs() < 1e-9);
        }
        assert!(lat.iter().all(|&l| l >= lo && l <= hi), "{lat:?}");
        let spread = lat.iter().fold(f64::MAX, |a, &b| a.min(b))..lat.iter().fold(0.0f64, |a, &b| a.max(b));
        assert!(spread.start < lo + 0.1 && spread.end > hi - 0.1, "{spread:?}");
    }

    /// The latencies and the clock offset draw from streams of their own:
    /// with them set to zero, the measurements are the same, only the times
    /// change.
    #[test]
    fn timing_does_not_change_the_measurements() {
        let real = SimConfig::new();
        let mut ideal = real.clone();
        ideal.camera_latency_s = [0.0, 0.0];
        ideal.camera_time_offset_s = 0.0;
        ideal.gnss.latency_s = [0.0, 0.0];
        let a = Dataset::generate("figure8", 9, Some(8.0), &real).unwrap();
        let b = Dataset::generate("figure8", 9, Some(8.0), &ideal).unwrap();
        assert_eq!(a.imu, b.imu);
        for (fa, fb) in a.frames.iter().zip(&b.frames) {
            assert_eq!(fa.features, fb.features);
            assert_eq!(fa.t_exposure_s, fb.t_exposure_s);
            assert_eq!((fb.t_s, fb.t_delivered_s), (fb.t_exposure_s, fb.t_exposure_s));
        }
        for (ea, eb) in a.gnss.iter().zip(&b.gnss) {
            assert_eq!(ea.sats, eb.sats);
            assert_eq!(eb.t_delivered_s, eb.t_s);
            assert!(ea.t_delivered_s > ea.t_s);
        }
    }
}
