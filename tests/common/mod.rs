//! Shared set-up of the integration tests that run the daemon in-process.
#![allow(dead_code)]

pub mod autopilot;
pub mod flights;
pub mod gnss_flights;
pub mod harness;
pub mod python;
pub mod sitl;

#[allow(unused_imports)]
pub use python::python_with;

/// Runs `tests/read_mcap.py`, the independent reader of our logs (PyPI
/// `mcap`, and `jsonschema` for `--validate`), with `args` in the tests'
/// Python; its output, whatever its exit.
pub fn read_mcap<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> std::process::Output {
    let validate = args.iter().any(|a| a.as_ref() == "--validate");
    let python = python_with(if validate { &["mcap", "jsonschema"] } else { &["mcap"] });
    std::process::Command::new(python)
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/read_mcap.py"))
        .args(args)
        .output()
        .expect("the tests' Python")
}

use cmsckf::config::Config;

/// A config on a free loopback UDP port, a socket in `dir`, and no log.
pub fn loopback_config(dir: &std::path::Path) -> (Config, u16) {
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut cfg = Config::default();
    cfg.mavlink.address = format!("udpin:127.0.0.1:{port}");
    cfg.features.socket = dir.join("f.sock").display().to_string();
    cfg.log.path = String::new();
    // The SITL autopilot relays its receiver's RTCM in GPS_RTCM_DATA as
    // station 7: the rover's, by its id.
    cfg.gnss.rover_station_id = cmsckf_sitl::serve::ROVER_STATION_ID;
    (cfg, port)
}

/// Starts `cmsckf::daemon::run` on the current runtime; send on the returned
/// channel to stop it.
pub fn spawn_daemon(
    cfg: Config,
) -> (
    tokio::sync::oneshot::Sender<()>,
    tokio::task::JoinHandle<Result<cmsckf::daemon::RunSummary, cmsckf::daemon::DaemonError>>,
) {
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let h = tokio::spawn(cmsckf::daemon::run(cfg, async move {
        let _ = stop_rx.await;
    }));
    (stop_tx, h)
}

/// `cmsckf run` on `cfg`, written to `dir/cmsckf.toml`: the command, to
/// spawn with its environment and output set.
pub fn run_command(cfg: &Config, dir: &std::path::Path) -> std::process::Command {
    let cfg_path = dir.join("cmsckf.toml");
    std::fs::write(&cfg_path, toml::to_string(cfg).unwrap()).unwrap();
    let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_cmsckf"));
    c.args(["run", "--config"]).arg(&cfg_path);
    c
}

/// Writes `cfg` to `dir` and starts the `cmsckf run` binary on it, waiting
/// until its feature socket exists.
pub fn spawn_daemon_binary(cfg: &Config, dir: &std::path::Path) -> std::process::Child {
    let child = run_command(cfg, dir)
        .env("RUST_LOG", "error")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    for _ in 0..100 {
        if std::path::Path::new(&cfg.features.socket).exists() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    child
}

/// Writes `cfg` to `dir` and runs the `cmsckf run` binary on it, expecting
/// it to refuse to start: its exit status and its standard error, or `None`
/// (after killing it) if it is still running after `timeout`.
pub fn run_daemon_binary_expecting_exit(
    cfg: &Config,
    dir: &std::path::Path,
    timeout: std::time::Duration,
) -> Option<(std::process::ExitStatus, String)> {
    use std::io::Read;
    let mut child = run_command(cfg, dir)
        .env("RUST_LOG", "error")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if started.elapsed() > timeout {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    let mut stderr = String::new();
    if let Some(mut e) = child.stderr.take() {
        let _ = e.read_to_string(&mut stderr);
    }
    Some((status, stderr))
}

/// As [`spawn_daemon_binary`], with the daemon's journal (`RUST_LOG`
/// `filter`) written to `stderr_path`.
pub fn spawn_daemon_binary_journal(
    cfg: &Config,
    dir: &std::path::Path,
    filter: &str,
    stderr_path: &std::path::Path,
) -> std::process::Child {
    let child = run_command(cfg, dir)
        .env("RUST_LOG", filter)
        .env("NO_COLOR", "1")
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(stderr_path).unwrap())
        .spawn()
        .unwrap();
    for _ in 0..100 {
        if std::path::Path::new(&cfg.features.socket).exists() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    child
}

/// A fusion loop's context for driving `cmsckf::daemon::Fusion` directly,
/// and the receiver of what it sends to the autopilot.
pub fn fusion_ctx() -> (
    cmsckf::daemon::Ctx,
    tokio::sync::mpsc::Receiver<cmsckf::io::messages::Outbound>,
) {
    let (out_tx, out_rx) = tokio::sync::mpsc::channel(1 << 16);
    let ctx = cmsckf::daemon::Ctx {
        counters: cmsckf::counters::Counters::default(),
        out: out_tx,
        status: Default::default(),
        mono_offset_us: std::sync::Arc::new(std::sync::atomic::AtomicI64::new(i64::MIN)),
        start: std::time::Instant::now(),
    };
    (ctx, out_rx)
}

/// A fusion loop for `cfg`, driven directly, that has heard the autopilot's
/// `ATTITUDE` (level, heading `yaw` rad): what a start needs first. With its
/// context and the receiver of what it sends.
pub fn level_fusion(
    cfg: cmsckf::config::Config,
    yaw: f64,
) -> (
    cmsckf::daemon::Fusion,
    cmsckf::daemon::Ctx,
    tokio::sync::mpsc::Receiver<cmsckf::io::messages::Outbound>,
) {
    let (ctx, out_rx) = fusion_ctx();
    let mut f = cmsckf::daemon::Fusion::new(cfg, None);
    f.handle(
        cmsckf::daemon::FusionMsg::Attitude {
            roll: 0.0,
            pitch: 0.0,
            yaw,
        },
        &ctx,
    );
    (f, ctx, out_rx)
}

/// Opens `page` in headless Chromium and returns how many plots its script
/// drew (the `data-plots-ready` it sets on `<body>`); `None` (and a note)
/// when no Chromium is installed.
#[allow(dead_code)]
pub fn chromium_plots_drawn(page: &std::path::Path) -> Option<usize> {
    let browser = ["chromium", "chromium-browser"].into_iter().find(|b| {
        std::process::Command::new(b)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    });
    let Some(browser) = browser else {
        eprintln!("no Chromium: the report's script was not run (apt-get install chromium)");
        return None;
    };
    let profile = tempfile::tempdir().unwrap();
    let out = std::process::Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--dump-dom",
        ])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg(format!("file://{}", page.display()))
        .output()
        .unwrap();
    let dom = String::from_utf8_lossy(&out.stdout);
    let at = dom.find("data-plots-ready=\"")? + "data-plots-ready=\"".len();
    dom[at..].split('"').next()?.parse().ok()
}
