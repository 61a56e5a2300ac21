//! The `cmsckf-frontend` binary against a hostile camera: a frame stamped
//! `u64::MAX`, a camera clock that restarts, bytes that are not a frame, a
//! frame of the wrong size, a camera process that exits and comes back, one
//! that freezes, and a daemon that is not there yet. The front-end must
//! deliver the good frames after each, keep running, and stop on SIGTERM
//! with the count of each.
//!
//! The test plays the camera process (the socket the front-end reads
//! `image_wire` frames from) and the daemon (the feature socket it writes
//! protocol lines to), over real Unix sockets.

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use cmsckf_models::image_wire::FrameHeader;

/// EuRoC's cam0 size, the repository's default camera model.
const W: u32 = 752;
const H: u32 = 480;

/// One `image_wire` frame of a `w × h` checkerboard stamped `t_us`.
fn frame(t_us: u64, w: u32, h: u32) -> Vec<u8> {
    let mut b = FrameHeader {
        t_us,
        width: w,
        height: h,
    }
    .encode()
    .to_vec();
    b.extend((0..h).flat_map(|y| (0..w).map(move |x| if (x / 16 + y / 16) % 2 == 0 { 40u8 } else { 200 })));
    b
}

/// The daemon's side: every line the front-end writes, as its `t_us`.
fn daemon(listener: UnixListener) -> mpsc::Receiver<u64> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for conn in listener.incoming() {
            let Ok(conn) = conn else { return };
            for line in BufReader::new(conn).lines() {
                let Ok(line) = line else { break };
                let v: serde_json::Value = serde_json::from_str(&line).expect("a protocol line is JSON");
                if tx.send(v["t_us"].as_u64().expect("t_us")).is_err() {
                    return;
                }
            }
        }
    });
    rx
}

/// Waits for the front-end to deliver `t_us` (skipping what came before).
fn delivered(rx: &mpsc::Receiver<u64>, t_us: u64) -> bool {
    let deadline = Instant::now() + Duration::from_secs(10);
    while let Some(left) = deadline.checked_duration_since(Instant::now()) {
        match rx.recv_timeout(left) {
            Ok(t) if t == t_us => return true,
            Ok(_) => {}
            Err(_) => return false,
        }
    }
    false
}

fn accept(listener: &UnixListener) -> UnixStream {
    listener.set_nonblocking(false).unwrap();
    let (s, _) = listener.accept().unwrap();
    s
}

fn spawn_frontend(dir: &Path) -> Child {
    Command::new(env!("CARGO_BIN_EXE_cmsckf-frontend"))
        .arg("--camera-socket")
        .arg(dir.join("cam.sock"))
        .arg("--socket")
        .arg(dir.join("features.sock"))
        .arg("--config")
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/default.toml"))
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

#[test]
fn the_frontend_outlives_a_hostile_camera_and_a_late_daemon() {
    let dir = tempfile::tempdir().unwrap();
    let camera = UnixListener::bind(dir.path().join("cam.sock")).unwrap();
    let mut fe = spawn_frontend(dir.path());
    let mut cam = accept(&camera);

    // The daemon is not there yet: frames are dropped, the front-end waits.
    for k in 0..3u64 {
        cam.write_all(&frame(700_000 + k * 50_000, W, H)).unwrap();
    }
    std::thread::sleep(Duration::from_millis(300));
    assert!(
        fe.try_wait().unwrap().is_none(),
        "the front-end gave up without its daemon"
    );
    let lines = daemon(UnixListener::bind(dir.path().join("features.sock")).unwrap());
    cam.write_all(&frame(1_000_000, W, H)).unwrap();
    assert!(delivered(&lines, 1_000_000), "a daemon that came late is fed");

    // One frame stamped u64::MAX: dropped, and the next ones go through.
    cam.write_all(&frame(u64::MAX, W, H)).unwrap();
    cam.write_all(&frame(1_050_000, W, H)).unwrap();
    assert!(delivered(&lines, 1_050_000), "a far-future stamp blinded the front-end");

    // Bytes that are not a frame (a writer that lost its framing), then a
    // frame: found again.
    cam.write_all(&[0x5a; 1000]).unwrap();
    cam.write_all(&frame(1_100_000, W, H)).unwrap();
    assert!(delivered(&lines, 1_100_000), "bytes that are not a frame stopped it");

    // A frame of another size than the camera model's: skipped.
    cam.write_all(&frame(1_150_000, 640, 480)).unwrap();
    cam.write_all(&frame(1_200_000, W, H)).unwrap();
    assert!(delivered(&lines, 1_200_000), "a wrong-size frame stopped it");

    // The camera's clock restarts near 0: followed after five steady frames.
    for k in 0..7u64 {
        cam.write_all(&frame(10_000 + k * 50_000, W, H)).unwrap();
    }
    assert!(
        delivered(&lines, 10_000 + 6 * 50_000),
        "a restarted camera clock blinded it"
    );

    // The camera process exits, and a new one comes up: connected again.
    drop(cam);
    let mut cam = accept(&camera);
    cam.write_all(&frame(2_000_000, W, H)).unwrap();
    assert!(
        delivered(&lines, 2_000_000),
        "a restarted camera process was not reconnected"
    );

    // The camera freezes (connected, silent): after 2 s the front-end takes
    // it as lost and connects again.
    let frozen_at = Instant::now();
    let mut cam2 = accept(&camera);
    assert!(frozen_at.elapsed() >= Duration::from_millis(1500));
    drop(cam);
    cam2.write_all(&frame(2_500_000, W, H)).unwrap();
    assert!(delivered(&lines, 2_500_000), "a frozen camera was not reconnected");
    assert!(fe.try_wait().unwrap().is_none(), "still running");

    // SIGTERM stops it, and its report counts what it met.
    // SAFETY: kill(2) on our own child's pid.
    unsafe { libc::kill(fe.id() as libc::pid_t, libc::SIGTERM) };
    let deadline = Instant::now() + Duration::from_secs(5);
    while fe.try_wait().unwrap().is_none() {
        assert!(Instant::now() < deadline, "SIGTERM did not stop it");
        std::thread::sleep(Duration::from_millis(20));
    }
    let mut err = String::new();
    std::io::Read::read_to_string(&mut fe.stderr.take().unwrap(), &mut err).unwrap();
    eprintln!("{err}");
    for said in [
        "the daemon's socket",
        "out of order",
        "not an image frame",
        "640x480",
        "clock restarted",
        "camera lost",
        "no frame for 2 s",
    ] {
        assert!(err.contains(said), "the front-end did not say '{said}'");
    }
}
