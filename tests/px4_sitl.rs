//! PX4's own SITL (SIH physics, quadrotor X, airframe 10040) flown on the
//! daemon's output, with cmsckf as EKF2's only position, velocity, height
//! and yaw source (`EKF2_EV_CTRL = 15`, `EKF2_HGT_REF = 3`, no GPS, no
//! compass, no range finder, no barometer: asserted through the values PX4
//! reports, and EKF2's ESTIMATOR_STATUS, which never shows a terrain
//! estimate from SIH's range finder). The camera is the one a drone carries: SIH's ground truth
//! (`HIL_STATE_QUATERNION`) rendered as images of a textured world built
//! around the route, tracked by the real front-end (`cmsckf-frontend`'s
//! tracker) into the daemon's socket, each track scored against its world
//! point. The test plays the ground station: stand, offboard, arm, take off
//! to 5 m, a 10 m box, a hover, land. It asserts that EKF2 fuses the
//! estimates from start to landing, that PX4 kept our time stamps (its time
//! synchronisation converged on our TIMESYNC replies, and the
//! external-vision delay it measures is our latency, not zero), that PX4's
//! LOCAL_POSITION_NED stays near the truth in each phase (the bounds'
//! comment gives what was measured against what the issue asks), and that
//! the filter restarts at most twice, each said.
//!
//! The SITL is a test fixture beside the project, never in it: the test
//! finds it through `CMSCKF_PX4_SITL` (a folder holding `bin/px4` with its
//! `bin/px4-*` links and the ROMFS `etc/`; `.ci/run` sets it) and skips,
//! saying why, when it is absent.

mod common;

use std::collections::VecDeque;
use std::io::Write;
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use cmsckf_models::geodesy::llh_to_ecef;
use cmsckf_models::geoid;
use common::sitl::{free_udp_port, interpolate_at, Errors, FlightDir, Gcs, RenderedCamera, Scoring, Truth};
use mavlink::dialects::ardupilotmega as apm;
use mavlink::Message;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// Where SIH puts the vehicle (`SIH_LOC_LAT0`, `SIH_LOC_LON0`, and
/// `SIH_LOC_H0` above mean sea level): Zürich.
const HOME: [f64; 3] = [47.3977432, 8.5455942, 489.4];
/// Seconds of standing after EKF2 fuses the estimates, before arming.
const STAND_S: f64 = 12.0;
/// Seconds of hover over the start before landing.
const HOVER_S: f64 = 8.0;
/// The box's corners in PX4's local NED frame (m).
const BOX: [[f32; 3]; 5] = [
    [0.0, 0.0, -5.0],
    [10.0, 0.0, -5.0],
    [10.0, 10.0, -5.0],
    [0.0, 10.0, -5.0],
    [0.0, 0.0, -5.0],
];
/// The route's horizontal points every 0.5 m (north, east; m), the world's
/// blocks kept clear of them: the take-off's spot and the box.
fn route_points() -> Vec<[f64; 2]> {
    let mut points = Vec::new();
    for leg in BOX.windows(2) {
        let (a, b) = (leg[0].map(f64::from), leg[1].map(f64::from));
        let n = ((b[0] - a[0]).hypot(b[1] - a[1]) / 0.5).ceil().max(1.0) as usize;
        for k in 0..n {
            let f = k as f64 / n as f64;
            points.push([a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f]);
        }
    }
    points.push([f64::from(BOX[0][0]), f64::from(BOX[0][1])]);
    points
}

/// The whole flight must end within this (wall clock, SIH runs at 1×).
const BUDGET: Duration = Duration::from_secs(200);
/// `ESTIMATOR_STATUS.flags`: EKF2's horizontal velocity and relative
/// horizontal position are valid, which without GPS or optical flow means
/// it fuses our positions.
const EKF_VEL_HORIZ: u16 = 0x02;
const EKF_POS_HORIZ_REL: u16 = 0x08;
const EKF_POS_VERT_ABS: u16 = 0x20;
/// `ESTIMATOR_STATUS.flags` bit 6: EKF2 has a terrain estimate, which it
/// makes only from a range finder or optical flow, neither ours.
const EKF_POS_VERT_AGL: u16 = 0x40;

/// The fixture's folder, or why the test cannot run.
fn fixture() -> Result<PathBuf, String> {
    let dir = std::env::var_os("CMSCKF_PX4_SITL")
        .ok_or("CMSCKF_PX4_SITL is not set (a folder with PX4's SITL: bin/px4, its bin/px4-* links and etc/)")?;
    let dir = PathBuf::from(dir);
    for f in ["bin/px4", "bin/px4-listener", "etc/init.d-posix/rcS"] {
        if !dir.join(f).is_file() {
            return Err(format!(
                "{} has no {f} (copy the fixture with `cp -a`: bin/px4-* are links to bin/px4)",
                dir.display()
            ));
        }
    }
    Ok(dir)
}

/// A PX4 instance whose UDP ports are all free: `px4 -i N` listens on
/// 18570+N (ground station) and 14580+N (onboard), and sends the onboard
/// link to 14540+N, where the daemon listens.
fn free_instance() -> u16 {
    (0..10)
        .find(|n| {
            [18570, 14580, 14540, 14280, 13030, 19450]
                .iter()
                .all(|p| UdpSocket::bind(("127.0.0.1", p + n)).is_ok())
        })
        .expect("no PX4 instance 0-9 has its UDP ports free")
}

/// PX4's SITL, killed when dropped.
struct Sitl(Child);

impl Drop for Sitl {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// PX4's parameters for external vision as its only position, height and
/// yaw source (docs/setup-px4.md gives each one's reason). rcS applies
/// each `PX4_PARAM_<NAME>` with `param set` on start.
const PARAMS: [(&str, &str); 10] = [
    ("EKF2_EV_CTRL", "15"),
    ("EKF2_HGT_REF", "3"),
    // Ours the only height: SIH has a range finder that reads the truth
    // (`send_dist_snsr`: the height over its flat ground, no noise) and a
    // barometer, and by default EKF2 fuses both beside ours: the range
    // finder into its terrain estimate (ESTIMATOR_STATUS bit 6, in every
    // flight until these were set) and into its height when low and slow,
    // the barometer with an offset it learns. The daemon says either one
    // in the log (`daemon/nav_params.rs`).
    ("EKF2_RNG_CTRL", "0"),
    ("EKF2_BARO_CTRL", "0"),
    ("EKF2_GPS_CTRL", "0"),
    ("SENS_EN_GPSSIM", "0"),
    ("EKF2_MAG_TYPE", "5"),
    // EKF2's IMU noise as SIH's IMU has it in flight (0.07 rad/s and
    // 0.87 m/s² per 250 Hz sample, averaged over EKF2's ~100 Hz step),
    // as cmsckf's own `imu.*_noise_density` are set below: with the
    // defaults (0.015, 0.35) EKF2 trusts its IMU over our velocity.
    ("EKF2_GYR_NOISE", "0.045"),
    ("EKF2_ACC_NOISE", "0.55"),
    // No ULog: a test's folder is deleted after it.
    ("SDLOG_MODE", "-1"),
];

/// Starts PX4 instance `n` in `dir` (its parameters, dataman and logs go
/// there), headless, with SIH.
fn start_sitl(fixture: &Path, dir: &Path, n: u16) -> Sitl {
    let mut cmd = Command::new(fixture.join("bin/px4"));
    cmd.current_dir(dir)
        .env("PX4_SYS_AUTOSTART", "10040")
        .env("PX4_SIM_MODEL", "sihsim_quadx")
        .env("PX4_SIMULATOR", "sihsim");
    for (k, v) in PARAMS {
        cmd.env(format!("PX4_PARAM_{k}"), v);
    }
    let child = cmd
        .arg("-d")
        .arg("-i")
        .arg(n.to_string())
        .arg("-w")
        .arg(dir)
        .arg(fixture.join("etc"))
        .stdout(std::fs::File::create(dir.join("px4.out")).unwrap())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    Sitl(child)
}

/// One uORB topic as PX4's shell client prints it (`px4-listener`), as
/// (field, value) pairs; empty when PX4 does not answer.
fn listen(fixture: &Path, n: u16, topic: &str) -> Vec<(String, String)> {
    let out = Command::new(fixture.join("bin/px4-listener"))
        .args(["--instance", &n.to_string(), topic])
        .output();
    let Ok(out) = out else { return Vec::new() };
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
        .collect()
}

/// A listener field's leading number (`timestamp: 123 (4 us ago)` → 123).
fn field(fields: &[(String, String)], name: &str) -> Option<f64> {
    let (_, v) = fields.iter().find(|(k, _)| k == name)?;
    v.split_whitespace().next()?.parse().ok()
}

#[derive(Clone, Copy, Debug, PartialEq, PartialOrd)]
enum Phase {
    WaitEkf,
    Stand,
    Arm,
    TakeOff,
    Box(usize),
    Hover,
    Land,
    Done,
}

/// PX4's custom mode for OFFBOARD (main mode 6) in MAV_CMD_DO_SET_MODE.
const PX4_MAIN_MODE_OFFBOARD: f32 = 6.0;

#[test]
fn px4_flies_on_cmsckf_alone() {
    let fixture = match fixture() {
        Ok(f) => f,
        Err(why) => {
            eprintln!("skipped: {why}");
            return;
        }
    };
    // CMSCKF_KEEP_TEST_LOGS=1 keeps the flight log, PX4's files and the
    // truth for `cmsckf review` after the run (the folder is printed).
    let mut flight_dir = FlightDir::new();
    let dir = flight_dir.path.clone();
    let n = free_instance();
    // PX4's MAV_SYS_ID is its instance + 1.
    let system_id = (n + 1) as u8;

    // The daemon: PX4's onboard link on its usual port, the origin from the
    // config (VIO only). `output.set_gps_origin` is on as a user beside
    // ArduPilot would have it: towards PX4 the daemon withholds it (PX4
    // keeps its altitude across a new origin: its local heights would move
    // by the origin's 489 m).
    let (mut cfg, _) = common::loopback_config(dir.as_path());
    cfg.mavlink.address = format!("udpin:127.0.0.1:{}", 14540 + n);
    cfg.mavlink.system_id = system_id;
    // SIH's IMU runs at 250 Hz: all of it, as on a real PX4 at its
    // IMU_INTEG_RATE (docs/setup-px4.md).
    cfg.mavlink.imu_rate_hz = 250.0;
    // The sensors as the daemon is told of them beside SIH, from the file a
    // user (and `cmsckf evaluate --config`, which flies them in the
    // simulator) reads them from: the camera 30° below the body's nose at
    // 20 Hz, SIH's IMU noise (config/px4-sih.toml says why each; the
    // config's tests check that it reads back 30° down). In
    // twelve flights at 2026-12-07, the mounts mostly alternating (SIH
    // draws the same noise at the same instant of each flight, so only the
    // camera differed), the box's max was 0.32-0.65 m (median 0.49) at 30°
    // against 0.53-0.65 m (median 0.62) looking level, the hover 0.17-0.57
    // m against 0.21-0.54 m; at 45° every touchdown failed
    // (docs/setup-px4.md, "The camera's mount"). Those flights were over a
    // ground with no detail finer than 0.2 m; the renderer's ground now has
    // some down to centimetres ("The lift-off over a textured ground").
    let px4 = cmsckf::config::Config::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("config/px4-sih.toml"))
        .expect("config/px4-sih.toml");
    cfg.camera.rate_hz = px4.camera.rate_hz;
    cfg.camera.q_B_C_xyzw = px4.camera.q_B_C_xyzw;
    cfg.imu.accel_noise_density = px4.imu.accel_noise_density;
    cfg.imu.gyro_noise_density = px4.imu.gyro_noise_density;
    cfg.gnss.source = cmsckf::config::GnssSource::Off;
    cfg.gnss.origin_llh = vec![HOME[0], HOME[1], geoid::ellipsoid_from_msl(HOME[0], HOME[1], HOME[2])];
    cfg.output.set_gps_origin = true;
    // EKF2's heading is ours alone (`EKF2_EV_CTRL` bit 3, no GPS, no
    // compass): the daemon reads that from EKF2's parameters, and with
    // `output.position_covariance = "auto"` (the default) sends our
    // position's covariance given our yaw (estimator README eq. O2,
    // docs/setup-px4.md), checked below.
    assert_eq!(cfg.output.position_covariance, cmsckf::config::PositionCovariance::Auto);
    // The origin is where the vehicle stands: its start's position in our
    // frame is known to centimetres. PX4 has no position of its own (its
    // GPS_RAW_INT fix is SIH's, not fused), so the daemon starts at PX4's
    // local position with this sigma; the default, 3 m, is a start whose
    // place nothing knows, and PX4 then weighs our positions as 3 m noise
    // for the whole flight (hover 0.41-0.58 m against 0.18-0.42 m).
    cfg.init.sigma_position_autopilot_m = 0.05;
    cfg.log.path = dir.as_path().join("flight.mcap").display().to_string();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let _guard = rt.enter();
    let (stop_daemon, daemon) = common::spawn_daemon(cfg.clone());
    let started = Instant::now();
    let _sitl = start_sitl(&fixture, dir.as_path(), n);

    // The ground station on a port of its own: PX4 answers whoever speaks
    // to its ground-station port.
    let mut gcs = Gcs::bind(free_udp_port());
    gcs.target_system = system_id;
    gcs.peer = Some(SocketAddr::from(([127, 0, 0, 1], 18570 + n)));

    // The camera: SIH's truth (its HIL_STATE_QUATERNION) rendered as
    // images of a world built around the box, and tracked by the real
    // front-end.
    let mut camera = RenderedCamera::new(&cfg, &route_points(), 1, flight_dir.kept_file("tracks.csv"));
    let mut truth = Truth::new(HOME);
    // The truth over the whole flight (t, NED position), for the checks of
    // our own estimate and of the review's barometer row at the end.
    let mut truth_ned: VecDeque<(f64, Vector3<f64>)> = VecDeque::new();

    let mut phase = Phase::WaitEkf;
    let mut phase_since = Instant::now();
    let mut last_cmd = Instant::now() - Duration::from_secs(10);
    let mut last_setpoint = Instant::now();
    let mut imu_t_s = None::<f64>;
    let mut streams_asked = Instant::now() - Duration::from_secs(10);
    let mut accepted_after_s = None::<f64>;
    let mut armed = false;
    let mut land_acked = false;
    let (mut standing, mut climbing, mut boxing) = (Errors::default(), Errors::default(), Errors::default());
    let (mut hovering, mut landing) = (Errors::default(), Errors::default());
    let mut local = None::<(f64, Vector3<f64>)>;
    let mut scoring = Scoring::new();
    let mut truth_yaw = None::<f64>;
    let mut yaw_err_max_deg = 0.0f64;
    // The same at the end of the standing, once the compass's readings
    // since the start have been averaged (estimator README eq. H1).
    let mut yaw_err_last_deg = f64::NAN;
    // ESTIMATOR_STATUS from EKF2's acceptance to the landing: how many
    // reports, how many without our position fused, the largest ratios.
    let (mut ekf_reports, mut ekf_not_fusing) = (0usize, 0usize);
    let (mut ekf_pos_ratio_max, mut ekf_flags_flying) = (0.0f32, None::<u16>);
    let (mut ekf_terrain_reports, mut ekf_rejected_reports) = (0usize, 0usize);
    // PX4's time synchronisation and its EV delay, read while flying.
    let mut timesync = Vec::new();
    let mut listened = false;
    let mut visual_odometry = Vec::new();
    let mut texts = Vec::new();

    let mut next_print = Instant::now();
    let mut seen = std::collections::BTreeMap::new();
    while phase != Phase::Done && started.elapsed() < BUDGET {
        if Instant::now() >= next_print {
            next_print += Duration::from_secs(2);
            // PX4 learns the ground station from its messages.
            gcs.send(&apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
                mavtype: apm::MavType::MAV_TYPE_GCS,
                autopilot: apm::MavAutopilot::MAV_AUTOPILOT_INVALID,
                ..Default::default()
            }));
            if let (Some((t, p)), Some(p_true)) = (local, local.and_then(|(t, _)| truth.at(t))) {
                eprintln!(
                    "[{:6.1} s] t {t:.1} EKF2 {:.2?} truth {:.2?}",
                    started.elapsed().as_secs_f64(),
                    p.as_slice(),
                    p_true.as_slice()
                );
            }
        }
        for (h, msg) in gcs.recv() {
            if h.system_id != u32::from(system_id) {
                continue;
            }
            *seen.entry(msg.message_id()).or_insert(0usize) += 1;
            match msg {
                apm::MavMessage::HIGHRES_IMU(m) if h.component_id == 1 => imu_t_s = Some(m.time_usec as f64 * 1e-6),
                // SIH's truth. Its time_usec is not filled in (0): it is
                // paired with the HIGHRES_IMU before it, both streamed at
                // 250 Hz on this link.
                apm::MavMessage::HIL_STATE_QUATERNION(s) => {
                    let Some(t_s) = imu_t_s else { continue };
                    let r = llh_to_ecef(
                        (s.lat as f64 * 1e-7).to_radians(),
                        (s.lon as f64 * 1e-7).to_radians(),
                        s.alt as f64 * 1e-3,
                    );
                    let v_true = Vector3::new(s.vx as f64, s.vy as f64, s.vz as f64) * 0.01;
                    let p = truth.push(t_s, truth.frame.to_ned(&r), v_true);
                    truth_ned.push_back((t_s, p));
                    let [w, x, y, z] = s.attitude_quaternion.map(|c| c as f64);
                    if let Some(f) = flight_dir.truth_csv.as_mut() {
                        writeln!(
                            f,
                            "{t_s},{},{},{},{w},{x},{y},{z},{},{},{}",
                            p.x, p.y, p.z, v_true.x, v_true.y, v_true.z
                        )
                        .unwrap();
                    }
                    let q = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
                    truth_yaw = Some(q.euler_angles().2);
                    camera.see(t_s, p, v_true, q);
                }
                apm::MavMessage::LOCAL_POSITION_NED(l) => {
                    let t_s = l.time_boot_ms as f64 * 1e-3;
                    let p = Vector3::new(l.x as f64, l.y as f64, l.z as f64);
                    local = Some((t_s, p));
                    // Scored once the truth of its instant has come.
                    scoring.push(t_s, p, phase);
                }
                apm::MavMessage::ESTIMATOR_STATUS(e) => {
                    let flags = e.flags.bits();
                    let fusing = flags & (EKF_VEL_HORIZ | EKF_POS_HORIZ_REL | EKF_POS_VERT_ABS)
                        == EKF_VEL_HORIZ | EKF_POS_HORIZ_REL | EKF_POS_VERT_ABS;
                    if fusing && accepted_after_s.is_none() {
                        accepted_after_s = Some(started.elapsed().as_secs_f64());
                        eprintln!(
                            "[{:6.1} s] EKF2 fuses our estimates: flags {flags:#x}",
                            started.elapsed().as_secs_f64()
                        );
                    }
                    if phase > Phase::WaitEkf && phase < Phase::Done {
                        ekf_reports += 1;
                        ekf_not_fusing += usize::from(!fusing);
                        ekf_terrain_reports += usize::from(flags & EKF_POS_VERT_AGL != 0);
                        ekf_pos_ratio_max = ekf_pos_ratio_max.max(e.pos_horiz_ratio).max(e.pos_vert_ratio);
                        ekf_rejected_reports += usize::from(e.pos_horiz_ratio.max(e.pos_vert_ratio) > 1.0);
                        if matches!(phase, Phase::Box(_)) {
                            ekf_flags_flying = Some(flags);
                        }
                    }
                }
                apm::MavMessage::STATUSTEXT(t) => {
                    let text = String::from_utf8_lossy(t.text.as_slice())
                        .trim_end_matches('\0')
                        .to_string();
                    eprintln!("[{:6.1} s] {text}", started.elapsed().as_secs_f64());
                    texts.push(text);
                }
                // EKF2's yaw is ours (EKF2_EV_CTRL bit 3, no compass): its
                // error against the truth while the vehicle stands.
                apm::MavMessage::ATTITUDE(a) if phase == Phase::Stand => {
                    if let Some(y) = truth_yaw {
                        let d = a.yaw as f64 - y;
                        yaw_err_last_deg = d.sin().atan2(d.cos()).abs().to_degrees();
                        yaw_err_max_deg = yaw_err_max_deg.max(yaw_err_last_deg);
                    }
                }
                apm::MavMessage::HEARTBEAT(hb) if h.component_id == 1 => {
                    armed = hb.base_mode.bits() & 0x80 != 0;
                }
                apm::MavMessage::COMMAND_ACK(a) => {
                    land_acked |=
                        a.command == apm::MavCmd::MAV_CMD_NAV_LAND && a.result == apm::MavResult::MAV_RESULT_ACCEPTED;
                }
                _ => {}
            }
        }
        scoring.score(&truth, |at_phase, e| match at_phase {
            Phase::Stand | Phase::Arm => standing.add(e),
            Phase::TakeOff => climbing.add(e),
            Phase::Box(_) => boxing.add(e),
            Phase::Hover => hovering.add(e),
            Phase::Land => landing.add(e),
            _ => {}
        });
        if streams_asked.elapsed() > Duration::from_secs(2) {
            // The truth and its clock at SIH's own 250 Hz, so that each
            // HIL_STATE_QUATERNION follows the HIGHRES_IMU of its own step
            // (at 50 Hz each the two streams drift against each other, and
            // a pose 0-20 ms from its stamp, varying, made the camera
            // disagree with the IMU: 2-8 % of scale in our estimates),
            // EKF2's position at 20 Hz, its status at 5 Hz; asked again
            // until each comes.
            for (id, hz) in [(105, 250.0), (115, 250.0), (32, 20.0), (30, 10.0), (230, 5.0)] {
                if !seen.contains_key(&id) {
                    gcs.stream(id, hz);
                }
            }
            streams_asked = Instant::now();
        }
        let since = phase_since.elapsed();
        let resend = last_cmd.elapsed() > Duration::from_secs(1);
        // Offboard needs a setpoint stream (over 2 Hz) before and while in
        // it: 20 Hz from arming to the landing.
        // The take-off's target from the start (PX4 lifts off 1.7 s after
        // arming). Armed, SIH's IMU is noisy whether it stands or flies:
        // through SCALED_IMU 0.36, 1.17 and 1.06 m/s² per 250 Hz sample
        // (0.07 disarmed), white, so its velocity random-walks 0.067 m/s/√s
        // vertically; its mean on the ground is gravity to within that
        // noise (-9.75 and -9.95 m/s² in two flights, ±0.05 from noise).
        let target = match phase {
            Phase::Arm => Some(BOX[0]),
            Phase::TakeOff => Some(BOX[0]),
            Phase::Box(k) => Some(BOX[k]),
            Phase::Hover => Some(BOX[BOX.len() - 1]),
            _ => None,
        };
        if let Some(target) = target {
            if last_setpoint.elapsed() > Duration::from_millis(50) {
                gcs.goto(target);
                last_setpoint = Instant::now();
            }
        }
        let next = match phase {
            Phase::WaitEkf => accepted_after_s.map(|_| Phase::Stand),
            Phase::Stand => (since.as_secs_f64() > STAND_S).then_some(Phase::Arm),
            Phase::Arm => {
                // A second of setpoints first, as PX4 asks before OFFBOARD.
                if resend && since > Duration::from_secs(1) {
                    gcs.command(
                        apm::MavCmd::MAV_CMD_DO_SET_MODE,
                        [1.0, PX4_MAIN_MODE_OFFBOARD, 0.0, 0.0, 0.0, 0.0, 0.0],
                    );
                    gcs.command(
                        apm::MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
                        [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                    );
                    last_cmd = Instant::now();
                }
                armed.then_some(Phase::TakeOff)
            }
            Phase::TakeOff => local.is_some_and(|(_, p)| p.z < -4.7).then_some(Phase::Box(1)),
            Phase::Box(k) => {
                let target = BOX[k];
                let there = local.is_some_and(|(_, p)| {
                    (p - Vector3::new(target[0] as f64, target[1] as f64, target[2] as f64)).norm() < 0.4
                });
                there.then_some(if k + 1 < BOX.len() {
                    Phase::Box(k + 1)
                } else {
                    Phase::Hover
                })
            }
            // A hover: the camera all but still, the vehicle not quite.
            // PX4's clock synchronisation and EV delay are read here, in
            // flight.
            Phase::Hover => {
                if !listened && since > Duration::from_secs(2) {
                    listened = true;
                    timesync = listen(&fixture, n, "timesync_status");
                    visual_odometry = listen(&fixture, n, "vehicle_visual_odometry");
                }
                (since.as_secs_f64() > HOVER_S).then_some(Phase::Land)
            }
            Phase::Land => {
                if resend && !land_acked {
                    gcs.command(apm::MavCmd::MAV_CMD_NAV_LAND, [0.0; 7]);
                    last_cmd = Instant::now();
                }
                (!armed && since > Duration::from_secs(2)).then_some(Phase::Done)
            }
            Phase::Done => None,
        };
        if let Some(next) = next {
            eprintln!("[{:6.1} s] phase {next:?}", started.elapsed().as_secs_f64());
            phase = next;
            phase_since = Instant::now();
            last_cmd = Instant::now() - Duration::from_secs(10);
        }
    }
    let finished = phase == Phase::Done;
    eprintln!("ground station received (message id: count): {seen:?}");
    let queue_full = camera.queue_full;
    let front = camera.finish().expect("the rendered camera's front-end ran");
    eprintln!(
        "the rendered camera: {} frames rendered at {:.1} ms a frame, tracked at {:.1} ms, scored at {:.1} ms, \
         {} poses skipped behind, {} not queued, {} frames not delivered; {} positions scored against their world point, {} beyond 3 σ, {} out of view; \
         tracks {:?}",
        front.frames,
        front.rendering_ms / front.frames.max(1) as f64,
        front.tracking_ms / front.frames.max(1) as f64,
        front.scoring_ms / front.frames.max(1) as f64,
        front.skipped,
        queue_full,
        front.frames_not_delivered,
        front.scored,
        front.beyond_3_sigma,
        front.unseen,
        front.tracks
    );
    let _ = stop_daemon.send(());
    let summary = rt.block_on(daemon).unwrap().expect("daemon ran");
    let c = |k: &str| summary.counters.get(k).copied().unwrap_or(0);
    eprintln!(
        "EKF2 fused the estimates {:.1} s after start; standing: max {:.3} m, RMS {:.3} m ({} samples); \
         take-off: max {:.3} m, RMS {:.3} m ({} samples); box: max {:.3} m, RMS {:.3} m ({} samples); \
         hover: max {:.3} m, RMS {:.3} m ({} samples); \
         descent and landing: max {:.3} m, RMS {:.3} m ({} samples); filter restarts {}, initialisations {}",
        accepted_after_s.unwrap_or(f64::NAN),
        standing.max_m,
        standing.rms_m(),
        standing.n,
        climbing.max_m,
        climbing.rms_m(),
        climbing.n,
        boxing.max_m,
        boxing.rms_m(),
        boxing.n,
        hovering.max_m,
        hovering.rms_m(),
        hovering.n,
        landing.max_m,
        landing.rms_m(),
        landing.n,
        c("filter_reset"),
        c("init_static") + c("init_in_flight"),
    );
    eprintln!("daemon counters: {:?}", summary.counters);
    eprintln!(
        "yaw error standing (EKF2's, ours): max {yaw_err_max_deg:.2}°, {yaw_err_last_deg:.2}° at its end; \
         the compass's mean conditioned the yaw {} times",
        c("compass_yaw_conditioned")
    );
    eprintln!(
        "ESTIMATOR_STATUS from acceptance to landing: {ekf_reports} reports, {ekf_not_fusing} without our \
         position, largest position test ratio {ekf_pos_ratio_max:.3}, flags flying {ekf_flags_flying:#x?}"
    );
    eprintln!("PX4 timesync_status in the hover: {timesync:?}");
    eprintln!("PX4 vehicle_visual_odometry in the hover: {visual_odometry:?}");
    assert!(finished, "flight did not finish within {BUDGET:?}: stuck in {phase:?}");
    assert!(accepted_after_s.is_some(), "EKF2 never fused our estimates");
    // The camera kept up: at 30 Hz, 1671-1837 frames a flight, at most 3
    // skipped for lateness in a release build, but 11-22 % in the tests'
    // own build on a loaded machine; at 20 Hz (above), 1153-1228 frames
    // with 6 and 24 skipped. The bound is a share of the frames, 15 %, so
    // that a slow machine fails on the flight's accuracy, if at all, not on
    // the renderer's pace. Every line was delivered, and the tracker's own
    // error (the lens's offset from its calibration aside) fits the σ the
    // daemon weighs it with: 0.28-0.44 % of positions beyond 3 σ measured,
    // a position whose world point is out of view counted as beyond.
    assert!(
        front.frames > 800
            && front.frames_not_delivered == 0
            && ((front.skipped + queue_full) as f64) < 0.15 * (front.frames + front.skipped) as f64,
        "the rendered camera: {front:?}, {queue_full} not queued"
    );
    let wrong = front.beyond_3_sigma + front.unseen;
    assert!(
        front.scored > 50_000 && (wrong as f64) < 0.02 * (front.scored + front.unseen) as f64,
        "tracked positions beyond 3 σ or out of view: {wrong} of {}",
        front.scored + front.unseen
    );
    assert!(
        ekf_reports > 100 && ekf_not_fusing == 0,
        "EKF2 stopped fusing our estimates: {ekf_not_fusing} of {ekf_reports} reports"
    );
    // EKF2 rejected our position in no more than 15 % of its reports. With
    // its height ours alone, 8 flights of 11 at 2026-12-07 had none
    // (largest ratio 0.30-0.75); one had 2 of 276 (ratio 1.04: our
    // position corrected by 0.45 m across the box's end, where the
    // covariance sent given our yaw said less); two, one of them in CI,
    // had 27 and 29 (ratio 2: our height corrected by 1 m after a lift-off
    // whose first updates were confidently wrong, and PX4 flew 2-3.2 m off
    // for 6 s on its own IMU). Those are our estimate's defects, said in
    // docs/setup-px4.md, and the issue stays open on them; this bound, and
    // those below, hold what was measured so that a worse failure shows.
    assert!(
        (ekf_rejected_reports as f64) <= 0.15 * ekf_reports as f64,
        "EKF2 rejected our position in {ekf_rejected_reports} of {ekf_reports} reports (largest ratio \
         {ekf_pos_ratio_max})"
    );
    assert_eq!(
        ekf_terrain_reports, 0,
        "EKF2 made a terrain estimate of its own (from SIH's range finder)"
    );
    assert!(
        standing.n > 100 && climbing.n > 20 && boxing.n > 100 && hovering.n > 50 && landing.n > 50,
        "too few samples: {standing:?} {climbing:?} {boxing:?} {hovering:?} {landing:?}"
    );
    // The issue asks for 0 restarts. 5 flights of 6 have none; in the
    // sixth, PX4 began the first leg with the nose going 44° down in 0.4 s
    // (2.9 rad/s, its default 45° tilt limit), the tracks spanning the pitch
    // failed to triangulate (157 bad depths against 50-94), and the
    // divergence monitor restarted the filter twice, its error then inside
    // its σ (docs/setup-px4.md). So up to 2 here, each said.
    let restarts = c("filter_reset") + c("imu_gap_restart");
    if restarts > 0 {
        eprintln!("NOTE: the filter restarted {restarts} time(s): {:?}", summary.counters);
    }
    assert!(restarts <= 2, "the filter restarted: {:?}", summary.counters);
    // The issue asks for 0.5 m throughout; these bounds are what the
    // flights measured held, with room, not that. With the barometer fused
    // (estimator README §3g), release and CI builds, 2026-12-08, nine
    // flights: standing 0.020-0.029 m; in eight, take-off 0.20-0.85 m, box
    // 0.36-0.58 m, hover 0.12-0.47 m, descent and landing 0.14-0.27 m; in
    // one, flown before a height reset raised the window's heights with the
    // body's, the tracks pulled our height back 0.6 m off after it and
    // PX4's box was 1.41 m off, its hover 1.22 m (that flight's log replayed
    // with the reset as it is: our box 0.53 m, hover 0.13 m). Before the
    // barometer, thirteen flights had the box 0.42-3.19 m, the hover up to
    // 1.03 m. What is left: the lift-off's first updates are still
    // confidently wrong for a second, and the box's error is across the
    // ground, inside our σ (docs/setup-px4.md, "The barometer").
    assert!(standing.max_m < 0.15, "standing error {standing:?}");
    assert!(climbing.max_m < 2.5, "take-off error {climbing:?}");
    assert!(boxing.max_m < 1.5, "box error {boxing:?}");
    assert!(hovering.max_m < 1.0, "hover error {hovering:?}");
    assert!(landing.max_m < 1.5, "descent and landing error {landing:?}");
    assert!(yaw_err_max_deg < 3.0, "yaw {yaw_err_max_deg}° off while standing");
    // SIH's magnetometer scatters 1.7-2.9° a (100 ms) reading: the start's
    // mean of 10 was 0.6-1.7° off; the mean of the 85-110 readings while
    // standing, 0.16-0.45° (the filter's; EKF2's 0.04-0.29°) (docs/setup-px4.md).
    assert!(
        c("compass_yaw_conditioned") >= 5,
        "the compass's mean never conditioned the yaw"
    );
    assert!(
        yaw_err_last_deg < 1.0,
        "yaw {yaw_err_last_deg}° off at the end of the standing"
    );
    assert_eq!(
        (c("gps_origin_withheld"), c("gps_origin_sent")),
        (1, 0),
        "our origin must not reach PX4"
    );
    // EKF2's navigation parameters read over MAVLink (`daemon/nav_params.rs`):
    // all eight came, and none of them drops or misweighs our estimates.
    assert!(
        c("autopilot_param_value") >= 8 && c("autopilot_param_unanswered") == 0,
        "EKF2's parameters were not read: {:?}",
        summary.counters
    );
    assert_eq!(c("autopilot_param_misconfigured"), 0, "{:?}", summary.counters);

    // PX4 kept our stamps: its time synchronisation converged on our
    // replies, to an offset of about zero (we answer in its own boot
    // clock), and the EV sample it fuses is older than its arrival by our
    // latency. Unconverged, PX4 stamps each estimate with its arrival. Our
    // replies are read from a clock mapped through our own TIMESYNC, so a
    // loaded machine's scheduling delays show in the offset: 2-3 ms on a
    // quiet one, 7 ms with two other processes busy beside it, 26 ms in a
    // run at 2026-12-06 23:23 when this machine rendered the camera's
    // frames at 38.8 ms each (unconverged, it would be the whole latency
    // and the EV delay zero, which the next check refuses).
    let offset_us = field(&timesync, "estimated_offset");
    assert!(
        offset_us.is_some_and(|o| o.abs() < 35_000.0),
        "PX4's time synchronisation: {timesync:?}"
    );
    // SIH runs PX4's clock in 4 ms lockstep steps, and our estimate is
    // stamped with the IMU sample it was propagated to, which arrived in the
    // step the estimate is answered in: the sample's age PX4 measures is
    // its offset's error, a few ms (26 ms in the loaded run above), never
    // the zero of an arrival stamp.
    let delay_ms = field(&visual_odometry, "timestamp")
        .zip(field(&visual_odometry, "timestamp_sample"))
        .map(|(arrived, sample)| (arrived - sample) * 1e-3);
    eprintln!("PX4's EV delay (arrival - our stamp): {delay_ms:?} ms; timesync offset {offset_us:?} µs");
    assert!(
        delay_ms.is_some_and(|d| d != 0.0 && d.abs() < 35.0),
        "EV stamps not kept: {visual_odometry:?}"
    );

    // Acceptance logged: PX4's ESTIMATOR_STATUS, which the daemon asks for
    // on its own link, is in the log and in the review.
    let review = cmsckf::review::review(Path::new(&cfg.log.path), None, None, None).unwrap();
    eprintln!(
        "EKF2 test ratios of our position in the log: {} reports, max horizontal {:?}, vertical {:?}, {} over 1",
        review.autopilot_ratio_reports,
        review.autopilot_pos_horiz_ratio_max,
        review.autopilot_pos_vert_ratio_max,
        review.autopilot_rejected_reports
    );
    assert_eq!(review.resets, restarts, "the review's restarts");
    // At 5 Hz when the daemon's request comes before PX4's first report, at
    // PX4's own 1 Hz otherwise (docs/setup-px4.md, Streams).
    assert!(
        review.autopilot_ratio_reports > 40,
        "ESTIMATOR_STATUS is not in the log"
    );
    // The daemon's own stream of them, as the review reads it from the log:
    // the same bound as the ground station's above.
    assert!(
        review.autopilot_rejected_reports as f64 <= 0.15 * review.autopilot_ratio_reports as f64,
        "EKF2 rejected our position in {} of {} reports in the log",
        review.autopilot_rejected_reports,
        review.autopilot_ratio_reports
    );
    // EKF2's own height sources off, as PX4 itself reported them (the
    // terrain check above sees the range finder only, not the barometer).
    for name in ["EKF2_RNG_CTRL", "EKF2_BARO_CTRL"] {
        assert_eq!(
            review.autopilot_params.get(name),
            Some(&Some(0.0)),
            "{name} as PX4 reported it: {:?}",
            review.autopilot_params
        );
    }
    // Our position's covariance reached PX4 given our yaw (estimator README
    // eq. O2): never more than the filter's on any axis, and away from the
    // start the turn's share taken out. The smallest horizontal σ sent over
    // the filter's was 0.20-0.21 in five flights at 2026-12-06, the last
    // with this check (0.204 over 1720 estimates); 1.0 in a flight that sent
    // the whole covariance.
    let bytes = std::fs::read(&cfg.log.path).unwrap();
    let (mut records, mut over, mut min_share) = (0usize, 0usize, f64::INFINITY);
    // Our height's error against the truth, from its first value: the
    // drift the review's barometer row should show.
    let (mut first_height_err, mut drift_max) = (None::<f64>, 0.0f64);
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        if m.channel.topic != "/output/vision_position_estimate" {
            continue;
        }
        let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        let entry = |key: &str, k: usize| v[key][k].as_f64().unwrap_or(f64::NAN);
        records += 1;
        let t_s = v["usec"].as_f64().unwrap_or(f64::NAN) * 1e-6;
        if let Some(p) = interpolate_at(&truth_ned, t_s) {
            let err = p.z - entry("p_ned_m", 2);
            let first = *first_height_err.get_or_insert(err);
            drift_max = drift_max.max((err - first).abs());
        }
        for k in [0, 6, 11] {
            over += usize::from(entry("pose_covariance_sent", k) > entry("covariance", k) * (1.0 + 1e-6));
        }
        for k in [0, 6] {
            let whole = entry("covariance", k);
            if whole > 1e-4 {
                min_share = min_share.min((entry("pose_covariance_sent", k) / whole).sqrt());
            }
        }
    }
    eprintln!(
        "position σ sent to PX4 over the filter's: smallest {min_share:.3} over {records} estimates, {over} axes above"
    );
    assert!(
        records > 1000 && over == 0 && min_share < 0.5,
        "the covariance sent is not the position's given our yaw: {records} estimates, {over} axes above the \
         filter's, smallest horizontal share {min_share}"
    );
    // Our own estimate is honest (`/filter/state` against the truth): at
    // most a fifth of the estimates from the take-off on beyond 3 σ on an
    // axis. Flights of this test before the barometer was fused had 24-67 %
    // in six of eleven (the lift-off's first updates confidently wrong);
    // with it, ten kept flights replayed had 0-3.2 %, and the two flights
    // with this check 0 of 338 and 0 of 346 (docs/setup-px4.md, "The
    // barometer").
    let (mut scored, mut beyond, mut nees_sum) = (0usize, 0usize, 0.0f64);
    let takeoff_s = truth_ned
        .iter()
        .find(|(_, p)| p.z < -0.1)
        .map_or(f64::INFINITY, |(t, _)| *t);
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        if m.channel.topic != "/filter/state" {
            continue;
        }
        let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        let t_s = v["t_s"].as_f64().unwrap_or(f64::NAN);
        let Some(p) = interpolate_at(&truth_ned, t_s).filter(|_| t_s >= takeoff_s) else {
            continue;
        };
        let z: Vec<f64> = (0..3)
            .map(|k| {
                (v["p_B_in_W"][k].as_f64().unwrap_or(f64::NAN) - p[k]) / v["sigma_p_m"][k].as_f64().unwrap_or(f64::NAN)
            })
            .collect();
        scored += 1;
        // A NaN (no σ) counts as beyond.
        beyond += usize::from(z.iter().any(|e| e.is_nan() || e.abs() > 3.0));
        nees_sum += z.iter().map(|e| e * e).sum::<f64>() / 3.0;
    }
    eprintln!(
        "our estimate from the take-off: {beyond} of {scored} beyond 3 σ on an axis, position NEES per axis {:.2}",
        nees_sum / scored.max(1) as f64
    );
    // 10 Hz from the take-off to the landing, less a restart or two.
    assert!(
        scored > 150,
        "too few of our estimates scored from the take-off: {scored}"
    );
    assert!(
        (beyond as f64) <= 0.2 * scored as f64,
        "our estimate was confidently wrong: {beyond} of {scored} beyond 3 σ"
    );
    // The autopilot's barometer in the log (`SCALED_PRESSURE`), fused as
    // our height's reference (estimator README §3g), and the review's row
    // that sets our height beside it: SIH's barometer reads its truth
    // (about 0.1 m a reading, no drift), so the largest gap it shows is
    // our height's largest drift, to the 1 s bins' averaging, which takes
    // up to a fifth off a fast climb's peak (kept flights at 2026-12-07,
    // before it was fused: 0.14 against 0.09 m, 0.46 against 0.55 m, 1.45
    // against 1.71 m).
    let baro = review.barometer_gap.expect("the barometer is not in the log");
    eprintln!("our height against the barometer: {baro:?}; against the truth, largest drift {drift_max:.2} m");
    assert!(c("pressure") > 300, "SCALED_PRESSURE readings: {:?}", summary.counters);
    assert!(
        c("baro_updates") > 300,
        "barometer readings fused: {:?}",
        summary.counters
    );
    assert_eq!(c("baro_late") + c("baro_time_off"), 0, "{:?}", summary.counters);
    assert!(
        baro.bins > 40 && !baro.stopped_at_reboot && (baro.max_abs_m - drift_max).abs() < 0.1 + 0.2 * drift_max,
        "the review's barometer row ({baro:?}) is not our height's drift ({drift_max:.2} m)"
    );
    let page = dir.as_path().join("review.html");
    cmsckf::review::review_html(Path::new(&cfg.log.path), &page, None).unwrap();
    let page = std::fs::read_to_string(&page).unwrap();
    assert!(page.contains(">armed<"), "the timeline has the arming");
    assert!(
        page.contains("mode OFFBOARD (0x60000)") && page.contains("mode AUTO.LAND (0x6040000)"),
        "the timeline names PX4's modes"
    );
}
