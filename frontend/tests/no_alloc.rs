//! The tracker's hot path allocates nothing per frame once its buffers have
//! grown and re-identification's store is full: every list it builds is a
//! buffer kept from frame to frame, an anchor is refilled from a lost
//! track's, and a keyframe (and its landmarks' windows) reuses the lists of
//! the one that left the store. Counted by a global allocator that wraps
//! the system's, over the simulator's rendered racetrack (10 s of it played
//! in a loop, as in the tracker's bench: each pass a lap flown again), with
//! re-identification on and its store bounded small, so it fills.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use cmsckf_frontend::image::Gray;
use cmsckf_frontend::reid::ReidParams;
use cmsckf_frontend::tracker::{Tracker, TrackerParams};
use cmsckf_models::camera::Camera;
use cmsckf_sitl::config::SimConfig;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::render::Renderer;

/// The system allocator, counting allocations while `COUNTING` is set.
struct Counting;

static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

// SAFETY: every call is forwarded unchanged to `System`, which upholds the
// `GlobalAlloc` contract; the counter only reads an atomic.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: forwarded with the caller's layout.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: as for `dealloc`, with the caller's new size.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn a_frame_allocates_nothing_once_the_store_is_full() {
    let mut sim = SimConfig::new();
    sim.camera.rate_hz = 20.0;
    let ds = Dataset::generate("racetrack", 1, Some(20.0), &sim).expect("the racetrack generates");
    let mut r = Renderer::for_dataset(&ds);
    let mut poses = Vec::new();
    let frames: Vec<Gray> = ds
        .frames
        .iter()
        .enumerate()
        .filter(|(_, f)| f.t_exposure_s >= 10.0)
        .map(|(k, f)| {
            r.exposure_poses(&ds.trajectory, f.t_exposure_s, &mut poses);
            let mut bytes = Vec::new();
            r.render(&poses, k as u64, &mut bytes);
            Gray::from_u8(r.width(), r.height(), &bytes).expect("a whole frame")
        })
        .collect();
    let prm = TrackerParams {
        reid: Some(ReidParams {
            // 240 frames: more than a lap, so places are recognised and
            // their landmarks looked for.
            max_keyframes: 120,
            ..ReidParams::default()
        }),
        ..TrackerParams::default()
    };
    let mut tracker = Tracker::new(prm, Some(Camera::from_config(&sim.camera)));
    // Warm-up: four laps; buffers grow, the store fills (120 keyframes,
    // one every second frame) and turns over.
    let n = frames.len();
    for k in 0..4 * n {
        tracker.process(&frames[k % n]);
    }
    let before = tracker.stats;
    COUNTING.store(true, Ordering::SeqCst);
    for k in 4 * n..5 * n {
        tracker.process(&frames[k % n]);
    }
    COUNTING.store(false, Ordering::SeqCst);
    let allocations = ALLOCATIONS.load(Ordering::SeqCst);
    let s = tracker.stats;
    eprintln!(
        "a lap of {n} frames: {allocations} allocations; {} detected, {} re-identified, {} found again where a place put them",
        s.detected - before.detected,
        s.reidentified - before.reidentified,
        s.reacquired - before.reacquired
    );
    // The run must exercise what allocated before: detection,
    // re-identification and the places' landmarks.
    assert!(
        s.detected > before.detected && s.reidentified > before.reidentified && s.reacquired > before.reacquired,
        "{s:?}"
    );
    assert_eq!(allocations, 0, "allocations in a lap after the warm-up");
}
