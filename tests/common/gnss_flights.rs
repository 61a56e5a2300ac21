//! One GNSS flight with a base station on the link, flown against the
//! daemon in-process: the SITL autopilot serves the racetrack at 10× with
//! the simulator's ionosphere and a base 2.5 km away injected by a ground
//! station, and the rover's receiver either wired to the companion (its own
//! TCP port) or relayed by the autopilot. The differential and
//! hostile-base tests fly it under their settings and faults.

use std::collections::BTreeMap;
use std::time::Duration;

use cmsckf::config::{Config, GnssSource};
use cmsckf::eval;
use cmsckf_sitl::config::SimConfig;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::serve::{serve, Fault, Report, ServeOptions};

/// How the daemon takes GNSS.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gnss {
    Off,
    SinglePoint,
    Differential,
}

/// Where the rover's receiver is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RoverOn {
    /// Wired to the companion: its RTCM on a TCP port.
    Stream,
    /// Relayed by the autopilot in `GPS_RTCM_DATA` as station 7.
    Link,
}

/// One flight's settings.
pub struct GnssFlight {
    pub seed: u64,
    pub duration_s: f64,
    pub rover: RoverOn,
    pub faults: Vec<Fault>,
    /// Changes to the simulator after the defaults (base on, ionosphere on).
    pub sim: fn(&mut SimConfig),
    /// Changes to the daemon's config after the mode's.
    pub cfg: fn(&mut Config),
}

impl GnssFlight {
    pub fn new(seed: u64) -> Self {
        GnssFlight {
            seed,
            duration_s: 60.0,
            rover: RoverOn::Stream,
            faults: Vec::new(),
            sim: |_| {},
            cfg: |_| {},
        }
    }

    /// Flies it with GNSS taken as `mode`: the SITL's report and the
    /// daemon's counters.
    pub async fn fly(&self, mode: Gnss) -> (Report, BTreeMap<String, u64>) {
        let dir = tempfile::tempdir().unwrap();
        let (mut cfg, port) = super::loopback_config(dir.path());
        let mut sim = eval::sim_config_for(&cfg);
        sim.gnss.ionosphere = true;
        sim.gnss.base.enabled = true;
        (self.sim)(&mut sim);
        let rx_port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        cfg.gnss.p_A_in_B_m = sim.gnss.p_A_in_B_m;
        cfg.gnss.iono = cmsckf::gnss::IonoMode::Auto;
        cfg.gnss.dgnss = mode == Gnss::Differential;
        cfg.gnss.source = match (mode, self.rover) {
            (Gnss::Off, _) => GnssSource::Off,
            (_, RoverOn::Stream) => GnssSource::Stream,
            (_, RoverOn::Link) => GnssSource::Mavlink,
        };
        cfg.gnss.stream = format!("tcp:127.0.0.1:{rx_port}");
        (self.cfg)(&mut cfg);
        let (stop_tx, daemon) = super::spawn_daemon(cfg.clone());
        for _ in 0..100 {
            if std::path::Path::new(&cfg.features.socket).exists() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        let ds = Dataset::generate("racetrack", self.seed, Some(self.duration_s), &sim).unwrap();
        let report = serve(
            &ServeOptions {
                mavlink: format!("udpout:127.0.0.1:{port}"),
                feature_socket: cfg.features.socket.clone().into(),
                speedup: 10.0,
                faults: self.faults.clone(),
                gnss_stream: (self.rover == RoverOn::Stream).then(|| format!("127.0.0.1:{rx_port}")),
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
}

/// A counter's value (0 when never raised).
pub fn count(c: &BTreeMap<String, u64>, name: &str) -> u64 {
    c.get(name).copied().unwrap_or(0)
}
