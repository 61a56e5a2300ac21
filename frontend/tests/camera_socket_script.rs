//! `scripts/camera-socket.py`, the bridge for cameras that are not V4L2
//! (libcamera's `rpicam-vid`, a GStreamer pipeline): a camera command writes
//! raw I420 frames of a moving texture to its stdout, the script serves
//! them on a camera socket, and the real `cmsckf-frontend` tracks them. The
//! front-end must track features through them on the script's stamps, and
//! the script must say why it ended when the camera did.

use std::io::Read;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Python defining `rows`, a 752×480 texture of 8-px blocks wide enough to
/// move 2 px a frame to the left for `N` frames (`rows[y][2k:2k + W]`), and
/// `chroma`, the grey 4:2:0 chroma of one frame (I420's or NV12's).
macro_rules! texture {
    () => {
        r#"
import random
W, H = 752, 480
rng = random.Random(1)
blocks = [[rng.randrange(256) for _ in range((W + 2 * N) // 8 + 1)] for _ in range(H // 8)]
rows = [bytes(blocks[y // 8][x // 8] for x in range(W + 2 * N)) for y in range(H)]
chroma = bytes([128]) * (W * (H // 2))
"#
    };
}

/// The camera command: 60 I420 frames of 752×480 at 20 Hz, the texture
/// moving 2 px a frame to the left.
const CAMERA: &str = concat!(
    "N = 60\n",
    texture!(),
    r#"
import sys, time
out = sys.stdout.buffer
for k in range(N):
    x0 = 2 * k
    out.write(b"".join(r[x0:x0 + W] for r in rows) + chroma)
    out.flush()
    time.sleep(0.05)
"#
);

#[test]
fn a_pipe_camera_is_served_and_tracked() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("camera.sock");
    let out = dir.path().join("tracks.jsonl");
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/../scripts/camera-socket.py");
    let mut bridge = Command::new("python3")
        .arg(script)
        .arg("--socket")
        .arg(&sock)
        .args([
            "--width",
            "752",
            "--height",
            "480",
            "--format",
            "i420",
            "--latency-ms",
            "20",
            "--",
        ])
        .args(["python3", "-c", CAMERA])
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3 is needed for the tests (Debian: apt install python3)");
    let mut frontend = frontend_on(&sock, &out);

    // The camera's 60 frames take 3 s and more; the bridge ends with them.
    let deadline = Instant::now() + Duration::from_secs(60);
    let bridge_status = loop {
        if let Some(s) = bridge.try_wait().unwrap() {
            break s;
        }
        assert!(Instant::now() < deadline, "the bridge did not end with its camera");
        std::thread::sleep(Duration::from_millis(100));
    };
    let mut said = String::new();
    bridge.stderr.take().unwrap().read_to_string(&mut said).unwrap();
    assert_eq!(bridge_status.code(), Some(1), "a camera that ends is an error: {said}");
    assert!(said.contains("the camera command ended"), "{said}");
    // The front-end connects within its backoff: most of the 60 frames are
    // served, and every frame served is tracked and written.
    let served = count(&said, "served");
    assert!(served >= 40, "{served} of 60 frames served");
    eprintln!("bridge: {said}");
    let lines = tracks_written(&mut frontend, &out, served);
    let t_us: Vec<u64> = lines.iter().map(|v| v["t_us"].as_u64().unwrap()).collect();
    assert!(t_us.windows(2).all(|w| w[1] > w[0]), "stamps not increasing: {t_us:?}");
    let mut dt_ms: Vec<f64> = t_us.windows(2).map(|w| (w[1] - w[0]) as f64 / 1e3).collect();
    dt_ms.sort_by(f64::total_cmp);
    let median_ms = dt_ms[dt_ms.len() / 2];
    assert!(
        (35.0..150.0).contains(&median_ms),
        "frames {median_ms} ms apart, the camera's are 50+"
    );
    // The texture is tracked: the same ids frame after frame, moving left.
    let last = lines[lines.len() - 1]["features"].as_array().unwrap().len();
    assert!(last >= 50, "{last} features in the last frame");
    assert_tracked_moving_left(&lines);
}

/// `cmsckf-frontend` on the camera socket `sock`, writing its tracks to
/// `out` (one JSON line a frame).
fn frontend_on(sock: &std::path::Path, out: &std::path::Path) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_cmsckf-frontend"))
        .arg("--camera-socket")
        .arg(sock)
        .arg("--config")
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/euroc.toml"))
        .arg("--out")
        .arg(out)
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// The bridge's last count of `key` in what it said (`'key': n`).
fn count(said: &str, key: &str) -> usize {
    said.rsplit(&format!("'{key}': "))
        .next()
        .filter(|_| said.contains(&format!("'{key}': ")))
        .and_then(|s| s.split([',', '}']).next())
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or_else(|| panic!("the bridge did not count {key}: {said}"))
}

/// Waits (20 s at most) for the front-end to write a line for each of the
/// `served` frames, stops it with SIGTERM, and gives its lines: exactly
/// one a frame served.
fn tracks_written(frontend: &mut std::process::Child, out: &std::path::Path, served: usize) -> Vec<serde_json::Value> {
    let written = || std::fs::read_to_string(out).map_or(0, |s| s.lines().count());
    let deadline = Instant::now() + Duration::from_secs(20);
    while written() < served && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
    }
    // SIGTERM stops the front-end; each frame's line is already written.
    sigterm(frontend);
    let status = frontend.wait().unwrap();
    eprintln!("front-end: {status}");
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(out)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), served, "frames served and lines written");
    lines
}

/// The texture moving left is tracked: at least 30 features of the last
/// frame kept from the one before, moving left by over a pixel on average.
fn assert_tracked_moving_left(lines: &[serde_json::Value]) {
    let feats = |v: &serde_json::Value| v["features"].as_array().unwrap().clone();
    let (last, prev) = (feats(&lines[lines.len() - 1]), feats(&lines[lines.len() - 2]));
    let moved: Vec<f64> = last
        .iter()
        .filter_map(|f| {
            let p = prev.iter().find(|g| g[0] == f[0])?;
            Some(f[1].as_f64()? - p[1].as_f64()?)
        })
        .collect();
    assert!(
        moved.len() >= 30,
        "{} features kept from one frame to the next",
        moved.len()
    );
    let mean_du = moved.iter().sum::<f64>() / moved.len() as f64;
    assert!(mean_du < -1.0, "the texture moved {mean_du} px a frame, not left");
}

/// Sends SIGTERM, as systemd stops a unit, through libc: a minimal system
/// may have no `kill` program (Debian's minbase lacks procps).
fn sigterm(child: &std::process::Child) {
    let pid = libc::pid_t::try_from(child.id()).expect("a pid fits pid_t");
    // SAFETY: kill(2) takes plain integers; the child is ours and not yet
    // waited for, so its pid is not reused.
    let rc = unsafe { libc::kill(pid, libc::SIGTERM) };
    assert_eq!(rc, 0, "kill({pid}, SIGTERM): {}", std::io::Error::last_os_error());
}

fn bridge(sock: &std::path::Path, camera: &str) -> std::process::Child {
    Command::new("python3")
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/../scripts/camera-socket.py"))
        .arg("--socket")
        .arg(sock)
        .args(["--width", "752", "--height", "480", "--format", "grey", "--"])
        .args(["python3", "-c", camera])
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3")
}

fn wait_for(path: &std::path::Path) {
    let deadline = Instant::now() + Duration::from_secs(10);
    while !path.exists() {
        assert!(Instant::now() < deadline, "{} never came", path.display());
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A reader that connects and never reads must not slow the camera: its
/// frames are dropped and counted, the camera read on time.
#[test]
fn a_reader_that_never_reads_never_stalls_the_camera() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("camera.sock");
    // 40 grey frames at 20 Hz: 2 s.
    let camera = "import sys, time\nf = bytes(752 * 480)\nfor _ in range(40):\n    sys.stdout.buffer.write(f); sys.stdout.buffer.flush(); time.sleep(0.05)\n";
    let started = Instant::now();
    let mut b = bridge(&sock, camera);
    wait_for(&sock);
    let _stuck = std::os::unix::net::UnixStream::connect(&sock).unwrap();
    let status = b.wait().unwrap();
    let took = started.elapsed();
    let mut said = String::new();
    b.stderr.take().unwrap().read_to_string(&mut said).unwrap();
    eprintln!("{said} in {took:?}");
    assert_eq!(status.code(), Some(1), "{said}");
    let slow = count(&said, "reader_slow");
    assert!(slow >= 20, "frames to a stuck reader not dropped: {said}");
    // The camera's own 2 s and start-up, not 0.5 s a frame.
    assert!(took < Duration::from_secs(8), "the camera stalled: {took:?}");
    assert!(!sock.exists(), "the socket was left behind");
}

/// SIGTERM while the camera says nothing ends the bridge at once, with
/// its socket removed and the camera stopped; a path that is not a socket
/// is never removed.
#[test]
fn sigterm_ends_a_bridge_waiting_on_a_silent_camera_and_files_are_never_removed() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("camera.sock");
    let mut b = bridge(&sock, "import time\ntime.sleep(60)\n");
    wait_for(&sock);
    std::thread::sleep(Duration::from_millis(300));
    let t = Instant::now();
    sigterm(&b);
    let status = b.wait().unwrap();
    assert!(t.elapsed() < Duration::from_secs(5), "SIGTERM took {:?}", t.elapsed());
    assert_eq!(status.code(), Some(0));
    assert!(!sock.exists(), "the socket was left behind");

    let file = dir.path().join("notes.txt");
    std::fs::write(&file, "a pilot's notes").unwrap();
    let mut b = bridge(&file, "import time\ntime.sleep(60)\n");
    let status = b.wait().unwrap();
    let mut said = String::new();
    b.stderr.take().unwrap().read_to_string(&mut said).unwrap();
    assert_eq!(status.code(), Some(1), "{said}");
    assert!(said.contains("not a socket"), "{said}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "a pilot's notes");
}

/// A VOXL camera server under ModalAI's MPA, played by a script: a pipe
/// directory with a `request` FIFO; each client writes its name there and
/// reads the FIFO the server makes for it: each frame a packed 40-byte
/// `camera_image_metadata_t` (magic "VOXL"), then the image. 40 NV12
/// frames of a moving texture, exposed 50 ms apart for 4 ms, with a torn
/// write (7 stray bytes) and an H.264 frame among them; then the server
/// goes away.
const MPA_SERVER: &str = concat!(
    "N = 40\n",
    texture!(),
    r#"
import os, struct, sys, time
d = sys.argv[1]
req_path = os.path.join(d, "request")
os.mkfifo(req_path)
req = os.open(req_path, os.O_RDONLY | os.O_NONBLOCK)
name = b""
deadline = time.time() + 30
while not name.endswith(b"\0"):
    assert time.time() < deadline, "no client asked"
    try:
        name += os.read(req, 64)
    except BlockingIOError:
        pass
    time.sleep(0.01)
path = os.path.join(d, name[:-1].decode())
os.mkfifo(path)
out = os.open(path, os.O_WRONLY)
t0 = time.clock_gettime_ns(time.CLOCK_MONOTONIC)
meta = struct.Struct("<Iqihhiiihhhh")
for k in range(N):
    if k == 10:
        os.write(out, b"garbage")
    if k == 20:
        os.write(out, meta.pack(0x564F584C, t0, k, W, H, 100, W, 4_000_000, 100, 3, 20, 0) + bytes(100))
    x0 = 2 * k
    image = b"".join(r[x0:x0 + W] for r in rows) + chroma
    frame = meta.pack(0x564F584C, t0 + k * 50_000_000, k, W, H, len(image), W, 4_000_000, 100, 1, 20, 0) + image
    view = memoryview(frame)
    while view:
        view = view[os.write(out, view):]
    time.sleep(0.05)
os.close(out)
"#
);

#[test]
fn a_voxl_mpa_pipe_is_served_and_tracked() {
    let dir = tempfile::tempdir().unwrap();
    let pipes = dir.path().join("mpa-tracking");
    std::fs::create_dir(&pipes).unwrap();
    let sock = dir.path().join("camera.sock");
    let out = dir.path().join("tracks.jsonl");
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/../scripts/camera-socket.py");
    let mut bridge = Command::new("python3")
        .arg(script)
        .arg("--socket")
        .arg(&sock)
        .arg("--mpa")
        .arg(&pipes)
        .args(["--width", "752", "--height", "480"])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut frontend = frontend_on(&sock, &out);
    // The server starts once the bridge serves and the front-end had time
    // to connect, so that it sees every frame.
    wait_for(&sock);
    std::thread::sleep(Duration::from_millis(500));
    let server = Command::new("python3")
        .args(["-c", MPA_SERVER])
        .arg(&pipes)
        .status()
        .unwrap();
    assert!(server.success(), "the MPA server script failed");
    // The server is gone: the bridge keeps asking, and serves what it read.
    std::thread::sleep(Duration::from_millis(1500));
    sigterm(&bridge);
    let status = bridge.wait().unwrap();
    let mut said = String::new();
    bridge.stderr.take().unwrap().read_to_string(&mut said).unwrap();
    eprintln!("bridge: {said}");
    assert_eq!(status.code(), Some(0), "SIGTERM is a clean stop: {said}");
    assert!(said.contains("the camera server closed its pipe"), "{said}");
    assert_eq!(count(&said, "mpa_connects"), 1, "{said}");
    assert!(count(&said, "mpa_resync") >= 1, "the stray bytes: {said}");
    assert_eq!(count(&said, "mpa_unusable"), 1, "the H.264 frame: {said}");
    let served = count(&said, "served");
    assert!(served >= 35, "{served} of 40 frames served: {said}");
    let lines = tracks_written(&mut frontend, &out, served);
    // The server's own stamps, mid-exposure: exactly 50 ms apart, whatever
    // the pipe's delays.
    let t_us: Vec<u64> = lines.iter().map(|v| v["t_us"].as_u64().unwrap()).collect();
    assert!(
        t_us.windows(2).all(|w| w[1] > w[0] && (w[1] - w[0]) % 50_000 == 0),
        "stamps not the camera's: {t_us:?}"
    );
    assert_tracked_moving_left(&lines);
}
