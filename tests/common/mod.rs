//! Shared set-up of the integration tests that run the daemon in-process.
#![allow(dead_code)]

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

/// Writes `cfg` to `dir` and starts the `cmsckf run` binary on it, waiting
/// until its feature socket exists.
pub fn spawn_daemon_binary(cfg: &Config, dir: &std::path::Path) -> std::process::Child {
    let cfg_path = dir.join("cmsckf.toml");
    std::fs::write(&cfg_path, toml::to_string(cfg).unwrap()).unwrap();
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_cmsckf"))
        .args(["run", "--config"])
        .arg(&cfg_path)
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
