//! Camera feature tracks over a landmark field, like a KLT front end.
//!
//! The landmark field grows around the flown path: whenever fewer than
//! `per_frame` landmarks are visible, new ones are spawned at random pixels and
//! depths in view (as OpenVINS's simulator does), and they stay in the map. So
//! a place flown again shows the same landmarks. Tracks end at random and when
//! landmarks leave the view; a landmark that comes back is re-identified with
//! its old `landmark_id` with probability `reid_prob`, or gets a fresh id.
//! Outliers (wrong ids, gross pixel errors) are injected at `outlier_prob`.
//!
//! Everything is deterministic for a given seed: containers are ordered
//! (`BTreeMap`, `Vec`), never hashed.
//!
//! A frame carries three times, because a real camera is off-clock and late:
//! it is exposed at `t_exposure_s` (IMU clock; the features are rendered from
//! the truth then), stamped `t_s` by the camera's own clock, and delivered to
//! the host at `t_delivered_s` (IMU clock). [`FeatureSim::frame`] makes an
//! ideal camera's frame (all three equal); [`CameraFrame::stamped`] applies a
//! clock offset and a delivery latency, as [`crate::dataset`] does.

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Vector2, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;

use crate::config::FeatureSimConfig;
use crate::trajectory::TruthSample;
use cmsckf_models::camera::Camera;

/// One feature observation: `(landmark_id, u_px, v_px)`, distorted pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FeatureObs {
    pub landmark_id: u64,
    pub u_px: f64,
    pub v_px: f64,
}

/// One camera frame of feature observations.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraFrame {
    /// The frame's stamp by the camera's clock (s): `t_exposure_s − t_d`
    /// for the true camera–IMU offset `t_d` (`t_imu = t_cam + t_d`). This is
    /// what the front end reports.
    pub t_s: f64,
    /// When the frame was exposed, on the IMU clock (s): the instant whose
    /// truth the features are projected from.
    pub t_exposure_s: f64,
    /// When the frame reaches the host, on the IMU clock (s): after the
    /// exposure by the camera's latency.
    pub t_delivered_s: f64,
    pub features: Vec<FeatureObs>,
}

impl CameraFrame {
    /// This frame as a real camera delivers it: stamped by a clock
    /// `time_offset_s` (`t_d`) behind the IMU's and delivered `latency_s`
    /// after its exposure.
    pub fn stamped(mut self, time_offset_s: f64, latency_s: f64) -> Self {
        self.t_s = self.t_exposure_s - time_offset_s;
        self.t_delivered_s = self.t_exposure_s + latency_s;
        self
    }
}

/// A landmark of the simulated world.
#[derive(Clone, Debug)]
pub struct Landmark {
    pub p_in_W: Vector3<f64>,
    /// The id the front end last reported it under.
    id: Option<u64>,
}

impl Landmark {
    /// The id the front end last reported it under (none if never seen).
    pub fn id(&self) -> Option<u64> {
        self.id
    }
}

/// Size of a cell of the spatial index (m).
const CELL_M: f64 = 20.0;

/// Statistics of the generated tracks.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrackStats {
    pub frames: usize,
    pub observations: usize,
    pub landmarks: usize,
    pub reidentified: usize,
    pub new_ids: usize,
    pub outliers: usize,
}

/// The stateful front-end simulator.
pub struct FeatureSim {
    cfg: FeatureSimConfig,
    cam: Camera,
    pixel_noise_px: f64,
    landmarks: Vec<Landmark>,
    grid: BTreeMap<(i64, i64, i64), Vec<usize>>,
    /// Landmarks whose track is alive after the previous frame.
    live: std::collections::BTreeSet<usize>,
    next_id: u64,
    pub stats: TrackStats,
}

impl FeatureSim {
    pub fn new(cfg: &FeatureSimConfig, cam: Camera, pixel_noise_px: f64) -> Self {
        Self {
            cfg: cfg.clone(),
            cam,
            pixel_noise_px,
            landmarks: Vec::new(),
            grid: BTreeMap::new(),
            live: Default::default(),
            next_id: 1,
            stats: TrackStats::default(),
        }
    }

    pub fn landmarks(&self) -> &[Landmark] {
        &self.landmarks
    }

    fn cell(p: &Vector3<f64>) -> (i64, i64, i64) {
        (
            (p.x / CELL_M).floor() as i64,
            (p.y / CELL_M).floor() as i64,
            (p.z / CELL_M).floor() as i64,
        )
    }

    fn add_landmark(&mut self, p_in_W: Vector3<f64>) -> usize {
        let idx = self.landmarks.len();
        self.landmarks.push(Landmark { p_in_W, id: None });
        self.grid.entry(Self::cell(&p_in_W)).or_default().push(idx);
        idx
    }

    /// Pose of the camera in the world for a body truth sample.
    pub fn camera_pose(&self, truth: &TruthSample) -> Isometry3<f64> {
        let T_W_B = Isometry3::from_parts(truth.p_B_in_W.into(), truth.q_W_B);
        T_W_B * self.cam.T_B_C
    }

    /// Landmark indices near the camera, in increasing index order.
    fn nearby(&self, p_C_in_W: &Vector3<f64>) -> Vec<usize> {
        let r = (self.cfg.max_range_m / CELL_M).ceil() as i64;
        let c = Self::cell(p_C_in_W);
        let mut out = Vec::new();
        for (_, v) in self
            .grid
            .range((c.0 - r, i64::MIN, i64::MIN)..=(c.0 + r, i64::MAX, i64::MAX))
        {
            out.extend_from_slice(v);
        }
        out.retain(|&i| {
            let d = self.landmarks[i].p_in_W - p_C_in_W;
            let cc = Self::cell(&self.landmarks[i].p_in_W);
            (cc.1 - c.1).abs() <= r && (cc.2 - c.2).abs() <= r && d.norm() <= self.cfg.max_range_m
        });
        out.sort_unstable();
        out
    }

    /// Produces the frame seen from `truth`, as an ideal camera would: its
    /// stamp and delivery equal its exposure time, `truth.t_s`.
    pub fn frame<R: Rng>(&mut self, truth: &TruthSample, rng: &mut R) -> CameraFrame {
        let T_W_C = self.camera_pose(truth);
        let mut selected = self.visible(&T_W_C);
        self.top_up(&mut selected, &T_W_C, rng);
        let mut features = Vec::with_capacity(selected.len());
        let prev_live = std::mem::take(&mut self.live);
        for (i, uv) in selected {
            features.push(self.observe(i, uv, &prev_live, rng));
        }
        self.stats.frames += 1;
        self.stats.observations += features.len();
        self.stats.landmarks = self.landmarks.len();
        CameraFrame {
            t_s: truth.t_s,
            t_exposure_s: truth.t_s,
            t_delivered_s: truth.t_s,
            features,
        }
    }

    /// The landmarks in view from `T_W_C` with their true pixels: continuing
    /// tracks first, then re-detections, at most `per_frame`.
    fn visible(&self, T_W_C: &Isometry3<f64>) -> Vec<(usize, Vector2<f64>)> {
        let T_C_W = T_W_C.inverse();
        let p_C_in_W = T_W_C.translation.vector;
        // Project every nearby landmark.
        let mut visible: Vec<(usize, Vector2<f64>)> = Vec::new();
        for i in self.nearby(&p_C_in_W) {
            let p_in_C = T_C_W * nalgebra::Point3::from(self.landmarks[i].p_in_W);
            if p_in_C.z < 0.5 {
                continue;
            }
            if let Some(uv) = self.cam.project(&p_in_C.coords) {
                if self.cam.in_image(&uv) {
                    visible.push((i, uv));
                }
            }
        }
        // Continuing tracks first, then re-detections, up to per_frame.
        visible.sort_by_key(|(i, _)| (!self.live.contains(i), *i));
        visible.truncate(self.cfg.per_frame);
        visible
    }

    /// Spawns new landmarks at random pixels and depths in view of `T_W_C`
    /// until `selected` holds `per_frame` of them (or the attempts run out).
    fn top_up<R: Rng>(&mut self, selected: &mut Vec<(usize, Vector2<f64>)>, T_W_C: &Isometry3<f64>, rng: &mut R) {
        let mut attempts = 0;
        while selected.len() < self.cfg.per_frame && attempts < 4 * self.cfg.per_frame {
            attempts += 1;
            let uv = Vector2::new(
                rng.random_range(0.0..self.cam.width_px),
                rng.random_range(0.0..self.cam.height_px),
            );
            let depth = rng.random_range(self.cfg.depth_min_m..=self.cfg.depth_max_m);
            let Some(xn) = self.cam.undistort(&uv) else {
                continue;
            };
            let p_in_C = Vector3::new(xn.x, xn.y, 1.0) * depth;
            let p_in_W = T_W_C * nalgebra::Point3::from(p_in_C);
            let idx = self.add_landmark(p_in_W.coords);
            selected.push((idx, uv));
        }
    }

    /// The front end's report of landmark `i` seen at true pixel `uv`: its
    /// track id (kept, re-identified or new), whether the track survives,
    /// pixel noise and, at `outlier_prob`, a wrong id or a wrong pixel.
    fn observe<R: Rng>(
        &mut self,
        i: usize,
        uv: Vector2<f64>,
        prev_live: &std::collections::BTreeSet<usize>,
        rng: &mut R,
    ) -> FeatureObs {
        let lm = &mut self.landmarks[i];
        let id = match (prev_live.contains(&i), lm.id) {
            (true, Some(id)) => id,
            (false, Some(id)) if rng.random::<f64>() < self.cfg.reid_prob => {
                self.stats.reidentified += 1;
                id
            }
            _ => {
                let id = self.next_id;
                self.next_id += 1;
                self.stats.new_ids += 1;
                id
            }
        };
        lm.id = Some(id);
        // The track survives into the next frame unless it is lost.
        if rng.random::<f64>() >= self.cfg.track_loss_prob {
            self.live.insert(i);
        }
        let noise = Vector2::new(
            rng.sample::<f64, _>(StandardNormal),
            rng.sample::<f64, _>(StandardNormal),
        ) * self.pixel_noise_px;
        let mut obs = FeatureObs {
            landmark_id: id,
            u_px: uv.x + noise.x,
            v_px: uv.y + noise.y,
        };
        if rng.random::<f64>() < self.cfg.outlier_prob {
            self.stats.outliers += 1;
            if rng.random::<bool>() {
                obs.landmark_id = rng.random_range(1..self.next_id.max(2));
            } else {
                obs.u_px = rng.random_range(0.0..self.cam.width_px);
                obs.v_px = rng.random_range(0.0..self.cam.height_px);
            }
        }
        obs
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::{racetrack, GustField, RacetrackParams};
    use cmsckf_models::sensors::CameraConfig;
    use rand::SeedableRng;

    #[test]
    fn projected_landmarks_lie_in_the_image_and_reappear() {
        let cc = CameraConfig::default();
        let cam = Camera::from_config(&cc);
        let fc = FeatureSimConfig {
            outlier_prob: 0.0,
            ..Default::default()
        };
        let mut sim = FeatureSim::new(&fc, cam.clone(), 0.0);
        let tr = racetrack(&RacetrackParams::default(), 140.0, 0.0, &GustField::default());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut ids_lap1 = std::collections::BTreeSet::new();
        let mut revisits = 0;
        let lap_s = 992.0 / 15.0;
        for k in 0..(140.0 * 10.0) as usize {
            let t = k as f64 * 0.1;
            let truth = tr.sample(t);
            let f = sim.frame(&truth, &mut rng);
            assert_eq!(f.features.len(), fc.per_frame);
            let T_C_W = sim.camera_pose(&truth).inverse();
            let by_id: BTreeMap<u64, Vector3<f64>> = sim
                .landmarks()
                .iter()
                .filter_map(|l| l.id.map(|id| (id, l.p_in_W)))
                .collect();
            for o in &f.features {
                let uv = Vector2::new(o.u_px, o.v_px);
                assert!(cam.in_image(&uv), "{uv}");
                // Noise-free pixel equals the projection of its landmark.
                let p = T_C_W * nalgebra::Point3::from(by_id[&o.landmark_id]);
                let proj = cam.project(&p.coords).unwrap();
                assert!((proj - uv).norm() < 1e-6);
                if t < lap_s - 10.0 {
                    ids_lap1.insert(o.landmark_id);
                } else if t > lap_s + 5.0 && ids_lap1.contains(&o.landmark_id) {
                    revisits += 1;
                }
            }
        }
        assert!(revisits > 100, "landmarks of lap 1 re-identified in lap 2: {revisits}");
        assert!(sim.stats.reidentified > 0);
    }
}
