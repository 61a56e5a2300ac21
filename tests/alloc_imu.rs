//! The IMU hot path allocates nothing: a counting global allocator watches
//! 1000 samples go through `add_imu` + `propagate_to` on a warmed-up filter.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering};

use cmsckf::config::Config;
use cmsckf::estimator::ImuMeas;
use cmsckf::estimator::Mode;
use cmsckf::eval::{sim_config_for, Runner};
use cmsckf_sitl::dataset::Dataset;

struct Counting;
static ALLOCS: AtomicU64 = AtomicU64::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn imu_samples_do_not_allocate() {
    let cfg = Config::default();
    let ds = Dataset::generate("racetrack", 1, Some(8.0), &sim_config_for(&cfg)).unwrap();
    let mut run = Runner::new(&ds, &cfg, Mode::Compressed, 1);
    let k = ds.frames.iter().position(|f| f.t_s >= 6.0).unwrap();
    for i in 0..k {
        run.step_frame(i);
    }
    let mut est = run.est;
    let m = ds.imu[ds.imu.len() / 2];
    let mut t = est.time_s();
    let mut step = |est: &mut cmsckf::estimator::Estimator| {
        t += 0.01;
        let _ = est.add_imu(ImuMeas {
            t_s: t,
            accel_mps2: m.accel_mps2,
            gyro_radps: m.gyro_radps,
        });
        est.propagate_to(t);
        let _ = est.predict(t);
    };
    // Warm up once (buffers reach their size), then count.
    for _ in 0..10 {
        step(&mut est);
    }
    let before = ALLOCS.load(Ordering::Relaxed);
    for _ in 0..1000 {
        step(&mut est);
    }
    let n = ALLOCS.load(Ordering::Relaxed) - before;
    assert_eq!(n, 0, "{n} allocations in 1000 IMU samples");
    assert!(est.check_health().is_ok());
}
