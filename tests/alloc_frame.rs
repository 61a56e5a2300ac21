//! Allocations on the filter's camera-frame path, counted: a counting global
//! allocator watches `process_frame` over 100 frames of a warmed-up filter
//! (racetrack, compressed mode, 100 features a frame; the frames' IMU fed
//! between them, uncounted). Issue 43's target is none per frame; the
//! figure today is printed, and the test holds it from growing
//! (docs/performance.md, "The real-time path").

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering};

use cmsckf::config::Config;
use cmsckf::estimator::frontend::Normaliser;
use cmsckf::estimator::{ImuMeas, Mode};
use cmsckf::eval::{sim_config_for, Runner};
use cmsckf_models::feature_wire::PixelFeature;
use cmsckf_sitl::dataset::Dataset;

struct Counting;
static ALLOCS: AtomicU64 = AtomicU64::new(0);
static BYTES: AtomicU64 = AtomicU64::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        BYTES.fetch_add(l.size() as u64, Ordering::Relaxed);
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        BYTES.fetch_add(n as u64, Ordering::Relaxed);
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn camera_frames_allocate_within_todays_count() {
    let cfg = Config::default();
    let ds = Dataset::generate("racetrack", 1, Some(20.0), &sim_config_for(&cfg)).unwrap();
    let mut run = Runner::new(&ds, &cfg, Mode::Compressed, 1);
    let k0 = ds.frames.iter().position(|f| f.t_s >= 10.0).unwrap();
    for k in 0..k0 {
        run.step_frame(k);
    }
    let mut est = run.est;
    let normaliser = Normaliser::new(&cfg.camera);
    let mut obs = Vec::new();
    let mut imu = ds.imu.iter().position(|m| m.t_s > est.time_s()).unwrap();
    let (mut allocs, mut bytes, mut tracks) = (0, 0, 0);
    let frames = 100;
    for f in &ds.frames[k0..k0 + frames] {
        while imu < ds.imu.len() && ds.imu[imu.saturating_sub(1)].t_s <= f.t_delivered_s {
            let m = &ds.imu[imu];
            let _ = est.add_imu(ImuMeas {
                t_s: m.t_s,
                accel_mps2: m.accel_mps2,
                gyro_radps: m.gyro_radps,
            });
            imu += 1;
        }
        normaliser.normalise_into(
            f.features
                .iter()
                .map(|o| PixelFeature::new(o.landmark_id, o.u_px, o.v_px)),
            &mut obs,
        );
        let (a0, b0) = (ALLOCS.load(Ordering::Relaxed), BYTES.load(Ordering::Relaxed));
        let rep = est.process_frame(f.t_s, &obs).unwrap();
        allocs += ALLOCS.load(Ordering::Relaxed) - a0;
        bytes += BYTES.load(Ordering::Relaxed) - b0;
        tracks += rep.tracks_used;
    }
    let per_frame = allocs as f64 / frames as f64;
    eprintln!(
        "{frames} frames ({tracks} tracks used): {allocs} allocations, {per_frame:.0} a frame, {:.0} kB a frame",
        bytes as f64 / frames as f64 / 1e3
    );
    assert!(tracks > 100, "{tracks} tracks used");
    assert!(est.check_health().is_ok());
    assert!(per_frame <= MAX_PER_FRAME, "{per_frame:.0} allocations a frame");
}

/// Today's count (101 a frame, 2.0 MB) with a margin for another CPU's
/// round-off taking other tracks: the ratchet to lower as allocations go.
const MAX_PER_FRAME: f64 = 125.0;
