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
