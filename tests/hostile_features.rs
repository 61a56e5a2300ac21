//! Hostile neighbours of the feature socket, against the real daemon over
//! real sockets: a client that connects first and never writes is dropped
//! after `features.idle_timeout_s` and the front end waiting behind it is
//! served; a filter that never saw a frame shows `camera_stale`; the daemon
//! refuses a socket directory another user could tamper with; and a socket
//! swapped in by someone else is left alone at shutdown.
mod common;

use std::io::{Read, Write};
use std::os::unix::fs::{FileTypeExt, PermissionsExt};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::Path;
use std::time::{Duration, Instant};

use common::autopilot::{line, MavPeer};

/// Waits (up to 2 s) for the daemon's socket to appear.
async fn wait_for_socket(path: &str) {
    for _ in 0..100 {
        if Path::new(path).exists() {
            return;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    panic!("the daemon's feature socket {path} never appeared");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_client_is_dropped_and_the_front_end_behind_it_is_served() {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, _port) = common::loopback_config(dir.path());
    cfg.features.idle_timeout_s = 0.5;
    let (stop_tx, daemon) = common::spawn_daemon(cfg.clone());
    wait_for_socket(&cfg.features.socket).await;

    // The squatter connects first and never writes.
    let mut squatter = UnixStream::connect(&cfg.features.socket).unwrap();
    let connected = Instant::now();
    tokio::time::sleep(Duration::from_millis(100)).await;
    // The real front end connects behind it (it waits in the backlog), writes
    // its frames and closes: they wait in its socket buffer until it is served.
    {
        let mut front = UnixStream::connect(&cfg.features.socket).unwrap();
        for i in 0..5 {
            front
                .write_all(line(1.0 + 0.05 * i as f64, "[1,300.0,200.0]").as_bytes())
                .unwrap();
        }
    }
    // The squatter sees its connection closed by the daemon, after the idle
    // timeout and not long after.
    squatter.set_read_timeout(Some(Duration::from_secs(3))).unwrap();
    let mut buf = [0u8; 16];
    let n = tokio::task::spawn_blocking(move || squatter.read(&mut buf))
        .await
        .unwrap()
        .expect("the daemon closes the silent client's connection within 3 s");
    let dropped_after = connected.elapsed();
    assert_eq!(n, 0, "end of stream for the dropped client");
    assert!(
        dropped_after >= Duration::from_millis(450) && dropped_after < Duration::from_secs(2),
        "dropped after {dropped_after:?}, idle_timeout_s = 0.5"
    );
    tokio::time::sleep(Duration::from_millis(200)).await;

    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    let c = |k: &str| summary.counters.get(k).copied().unwrap_or(0);
    eprintln!("{:#?}", summary.counters);
    assert_eq!(c("feature_idle_dropped"), 1, "the squatter, and only it");
    assert_eq!(c("feature_connections"), 2, "the squatter, then the front end");
    assert_eq!(c("feature_frames"), 5, "every frame of the front end behind it");
    assert_eq!(c("feature_disconnects"), 1, "the front end left by itself");
    assert!(!Path::new(&cfg.features.socket).exists(), "our socket is removed");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_writer_is_kept_while_it_writes_and_dropped_when_it_stops() {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, _port) = common::loopback_config(dir.path());
    cfg.features.idle_timeout_s = 0.3;
    let (stop_tx, daemon) = common::spawn_daemon(cfg.clone());
    wait_for_socket(&cfg.features.socket).await;
    let mut front = UnixStream::connect(&cfg.features.socket).unwrap();
    // 0.9 s of frames every 0.1 s: three idle timeouts, never idle.
    for i in 0..9 {
        front
            .write_all(line(1.0 + 0.1 * i as f64, "[1,300.0,200.0]").as_bytes())
            .unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // Then lines that are all rejected: not frames, so it goes idle anyway.
    // (A write after the daemon dropped it fails: the connection is gone.)
    let mut writes_failed = false;
    for _ in 0..6 {
        if front.write_all(b"not a frame\n").is_err() {
            writes_failed = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    writes_failed |= front.write_all(b"not a frame\n").is_err();
    assert!(writes_failed, "the daemon closed the connection");
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    let c = |k: &str| summary.counters.get(k).copied().unwrap_or(0);
    eprintln!("{:#?}", summary.counters);
    assert_eq!(c("feature_frames"), 9);
    assert_eq!(c("feature_connections"), 1);
    assert_eq!(c("feature_idle_dropped"), 1, "dropped once its frames stopped");
    assert!(c("feature_line_syntax") >= 2, "its rejected lines are counted");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_filter_that_never_saw_a_frame_is_camera_stale() {
    let dir = tempfile::tempdir().unwrap();
    let (cfg, port) = common::loopback_config(dir.path());
    let (stop_tx, daemon) = common::spawn_daemon(cfg.clone());
    wait_for_socket(&cfg.features.socket).await;
    // A squatter holds the socket: no frame ever arrives.
    let _squatter = UnixStream::connect(&cfg.features.socket).unwrap();

    let mut p = MavPeer::new(port, 1, 1).await;
    p.hello().await;
    // A static second initialises the filter; then 1.5 s more of IMU and
    // not one camera frame.
    let mut t = 10.0;
    let mut texts = Vec::new();
    let mut vpe = 0;
    for i in 0..300 {
        p.imu(t).await;
        t += 0.01;
        tokio::time::sleep(Duration::from_micros(300)).await;
        if i % 50 == 49 {
            let got = p.drain_for(Duration::from_millis(50)).await;
            texts.extend(got.texts);
            vpe += got.estimates;
        }
    }
    let got = p.drain_for(Duration::from_millis(50)).await;
    texts.extend(got.texts);
    vpe += got.estimates;
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    let c = |k: &str| summary.counters.get(k).copied().unwrap_or(0);
    eprintln!("STATUSTEXTs: {texts:?}");
    assert!(vpe > 10, "the filter ran ({vpe} estimates)");
    assert_eq!(c("init_static"), 1);
    assert_eq!(c("feature_frames"), 0);
    assert!(
        texts
            .iter()
            .any(|s| s.starts_with("cmsckf degraded:") && s.contains("camera_stale")),
        "no camera_stale in {texts:?}"
    );
}

/// `dir`'s socket config, run in-process and as the binary: both refuse to
/// start with an error naming `features.socket` and containing `problem`,
/// and no socket is made.
async fn refuses(dir: &Path, socket_dir: &Path, problem: &str) {
    let (mut cfg, _port) = common::loopback_config(socket_dir);
    let (_stop_tx, daemon) = common::spawn_daemon(cfg.clone());
    let r = tokio::time::timeout(Duration::from_secs(3), daemon)
        .await
        .expect("the daemon returns at once")
        .unwrap();
    let e = r.expect_err("the daemon must refuse this socket directory").to_string();
    assert!(e.contains("features.socket"), "{e}");
    assert!(e.contains(problem), "{e}");
    assert!(!Path::new(&cfg.features.socket).exists(), "no socket made: {e}");

    // The binary exits non-zero with the same message.
    cfg.mavlink.address = format!("udpin:127.0.0.1:{}", free_port());
    let (status, stderr) = tokio::task::spawn_blocking({
        let (cfg, dir) = (cfg.clone(), dir.to_path_buf());
        move || common::run_daemon_binary_expecting_exit(&cfg, &dir, Duration::from_secs(5))
    })
    .await
    .unwrap()
    .expect("cmsckf run exits instead of starting");
    assert!(!status.success(), "{stderr}");
    assert!(
        stderr.contains("features.socket") && stderr.contains(problem),
        "{stderr}"
    );
}

fn free_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_socket_directory_others_can_write_is_refused() {
    let top = tempfile::tempdir().unwrap();
    for (name, mode) in [("group", 0o770), ("world", 0o777), ("sticky", 0o1777)] {
        let d = top.path().join(name);
        std::fs::create_dir(&d).unwrap();
        std::fs::set_permissions(&d, std::fs::Permissions::from_mode(mode)).unwrap();
        refuses(top.path(), &d, "writable by group or others").await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_symlinked_socket_directory_is_refused() {
    let top = tempfile::tempdir().unwrap();
    // The other user's directory, and our path to it through a symlink.
    let theirs = top.path().join("theirs");
    std::fs::create_dir(&theirs).unwrap();
    std::fs::set_permissions(&theirs, std::fs::Permissions::from_mode(0o700)).unwrap();
    let link = top.path().join("run");
    std::os::unix::fs::symlink(&theirs, &link).unwrap();
    refuses(top.path(), &link, "is a symlink").await;
    // A real directory reached through a symlinked parent is refused too.
    let sub = theirs.join("cmsckf");
    std::fs::create_dir(&sub).unwrap();
    std::fs::set_permissions(&sub, std::fs::Permissions::from_mode(0o700)).unwrap();
    refuses(top.path(), &link.join("cmsckf"), "through a symlink").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_socket_swapped_by_someone_else_is_left_at_shutdown() {
    let dir = tempfile::tempdir().unwrap();
    let (cfg, _port) = common::loopback_config(dir.path());
    let (stop_tx, daemon) = common::spawn_daemon(cfg.clone());
    wait_for_socket(&cfg.features.socket).await;
    // Someone removes the daemon's socket and binds their own in its place.
    std::fs::remove_file(&cfg.features.socket).unwrap();
    let theirs = UnixListener::bind(&cfg.features.socket).unwrap();
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    let c = |k: &str| summary.counters.get(k).copied().unwrap_or(0);
    let meta = std::fs::symlink_metadata(&cfg.features.socket).expect("their socket is still there");
    assert!(meta.file_type().is_socket());
    assert!(
        UnixStream::connect(&cfg.features.socket).is_ok(),
        "their socket still works"
    );
    drop(theirs);
    assert_eq!(c("feature_socket_replaced"), 1);
}
