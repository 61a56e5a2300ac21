//! GNSS as a drone carries it, end to end: the rover's receiver is wired to
//! the companion (its RTCM3 on a TCP port, `gnss.source = "stream"`), and a
//! base station 2.5 km away reaches the vehicle as a ground station injects
//! it, in `GPS_RTCM_DATA` from system 255 with its MT1005. The simulated sky
//! is a real one's: broadcast orbit and clock errors (0.6 m per satellite),
//! a troposphere the model misses by 5 %, and a daytime ionosphere that a
//! single-frequency receiver without broadcast parameters cannot model. The
//! same flight is flown three times, with GNSS off, with the rover's own
//! codes (single point), and with differential codes against the base, and
//! the absolute position error of each is reported.

mod common;

use std::time::Duration;

use cmsckf::config::{Config, GnssSource};
use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::serve::{serve, Report, ServeOptions};

#[derive(Clone, Copy, Debug, PartialEq)]
enum Gnss {
    Off,
    SinglePoint,
    Differential,
}

/// Flies `seed`'s racetrack at 10× with the daemon in-process: the SITL's
/// report and the daemon's counters.
async fn fly(seed: u64, mode: Gnss) -> (Report, std::collections::BTreeMap<String, u64>) {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, port) = common::loopback_config(dir.path());
    let mut sim = eval::sim_config_for(&cfg);
    sim.gnss.ionosphere = true;
    sim.gnss.base.enabled = true;
    let rx_port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    configure(&mut cfg, &sim, mode, rx_port);
    let (stop_tx, daemon) = common::spawn_daemon(cfg.clone());
    for _ in 0..100 {
        if std::path::Path::new(&cfg.features.socket).exists() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let ds = Dataset::generate("racetrack", seed, Some(60.0), &sim).unwrap();
    let report = serve(
        &ServeOptions {
            mavlink: format!("udpout:127.0.0.1:{port}"),
            feature_socket: cfg.features.socket.clone().into(),
            speedup: 10.0,
            faults: Vec::new(),
            gnss_stream: Some(format!("127.0.0.1:{rx_port}")),
            camera_socket: None,
        },
        &ds,
    )
    .await
    .unwrap();
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    (report, summary.counters)
}

/// The daemon's GNSS settings for `mode`: the receiver on its own TCP port,
/// the ionosphere handled as a single-frequency receiver must (`auto`:
/// inflated variance), the antenna's lever arm as measured.
fn configure(cfg: &mut Config, sim: &cmsckf_sitl::config::SimConfig, mode: Gnss, rx_port: u16) {
    cfg.gnss.p_A_in_B_m = sim.gnss.p_A_in_B_m;
    cfg.gnss.iono = cmsckf::gnss::IonoMode::Auto;
    cfg.gnss.source = GnssSource::Stream;
    cfg.gnss.stream = format!("tcp:127.0.0.1:{rx_port}");
    cfg.gnss.dgnss = mode == Gnss::Differential;
    if mode == Gnss::Off {
        cfg.gnss.source = GnssSource::Off;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn differential_gnss_from_a_base_on_the_link() {
    let mut rows = Vec::new();
    for seed in [1, 2] {
        let mut ate = Vec::new();
        for mode in [Gnss::Off, Gnss::SinglePoint, Gnss::Differential] {
            let (report, c) = fly(seed, mode).await;
            let n = |k: &str| c.get(k).copied().unwrap_or(0);
            eprintln!(
                "seed {seed} {mode:?}: ATE {:.3} m (4-DoF {:.3} m), resets {}, epochs {}, differential {}, \
                 base MSMs {}, rover MSMs from the receiver {}",
                report.ate_m,
                report.ate_aligned_m,
                report.reset_count,
                n("gnss_epochs"),
                n("gnss_dgnss_epochs"),
                n("gnss_base_msm_from_ground_station"),
                n("gnss_rover_msm_from_receiver"),
            );
            assert_eq!(report.reset_count, 0, "{mode:?}");
            match mode {
                Gnss::Off => assert_eq!(n("gnss_epochs"), 0),
                Gnss::SinglePoint => {
                    assert!(n("gnss_epochs") >= 50, "the receiver's stream was read");
                    assert_eq!(n("gnss_dgnss_epochs"), 0);
                    assert!(
                        n("gnss_base_msm_from_ground_station") >= 50,
                        "the base is on the link, kept apart"
                    );
                }
                Gnss::Differential => {
                    assert!(n("gnss_rover_msm_from_receiver") >= 50);
                    assert!(
                        n("gnss_dgnss_epochs") as f64 >= 0.9 * n("gnss_epochs") as f64,
                        "differential epochs {} of {}",
                        n("gnss_dgnss_epochs"),
                        n("gnss_epochs")
                    );
                }
            }
            ate.push(report.ate_m);
        }
        rows.push((seed, ate));
    }
    eprintln!("| seed | GNSS off | single point | differential |");
    for (seed, a) in &rows {
        eprintln!("| {seed} | {:.3} | {:.3} | {:.3} |", a[0], a[1], a[2]);
    }
    for (seed, a) in &rows {
        assert!(
            a[2] < a[1],
            "seed {seed}: differential {:.3} m vs single point {:.3} m",
            a[2],
            a[1]
        );
        assert!(
            a[2] < a[0],
            "seed {seed}: differential {:.3} m vs no GNSS {:.3} m",
            a[2],
            a[0]
        );
    }
}
