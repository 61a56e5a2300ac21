//! [`Outbound`] → MAVLink messages: one function per message kind, so that
//! each outbound message's fields and units are read in one place.

use mavlink::dialects::ardupilotmega as apm;
use nalgebra::Vector3;

use super::Outbound;

/// [`Outbound`] → MAVLink message. (`SET_GPS_GLOBAL_ORIGIN` is deprecated
/// in favour of `MAV_CMD_DO_SET_GLOBAL_ORIGIN`, but it is what ArduPilot 4.x
/// takes.)
pub(super) fn encode(out: &Outbound, target_system: u8, target_component: u8) -> apm::MavMessage {
    match out {
        Outbound::Heartbeat { initialised, degraded } => heartbeat(*initialised, *degraded),
        Outbound::StatusText { severity, text } => status_text(*severity, text),
        Outbound::SetMessageInterval {
            message_id,
            interval_us,
        } => set_message_interval(*message_id, *interval_us, target_system, target_component),
        Outbound::TimesyncRequest { ts1_ns } => timesync_request(*ts1_ns, target_system, target_component),
        Outbound::VisionPositionEstimate {
            t_us,
            p_ned_m,
            rpy_rad,
            covariance,
            reset_counter,
        } => vision_position_estimate(*t_us, p_ned_m, rpy_rad, covariance, *reset_counter),
        Outbound::Odometry {
            t_us,
            p_ned_m,
            q_wxyz,
            v_body_mps,
            w_body_radps,
            pose_covariance,
            velocity_covariance,
            reset_counter,
        } => odometry(
            *t_us,
            p_ned_m,
            q_wxyz,
            v_body_mps,
            w_body_radps,
            pose_covariance,
            velocity_covariance,
            *reset_counter,
        ),
        Outbound::SetGpsGlobalOrigin {
            lat_deg,
            lon_deg,
            alt_m,
        } => set_gps_global_origin(*lat_deg, *lon_deg, *alt_m, target_system),
    }
}

/// `HEARTBEAT` of an onboard controller: standby until initialised, then
/// active, or critical while degraded.
fn heartbeat(initialised: bool, degraded: bool) -> apm::MavMessage {
    apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: apm::MavType::MAV_TYPE_ONBOARD_CONTROLLER,
        autopilot: apm::MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: apm::MavModeFlag::empty(),
        system_status: match (initialised, degraded) {
            (false, _) => apm::MavState::MAV_STATE_STANDBY,
            (true, false) => apm::MavState::MAV_STATE_ACTIVE,
            (true, true) => apm::MavState::MAV_STATE_CRITICAL,
        },
        mavlink_version: 3,
    })
}

/// `STATUSTEXT`, the text cut at a character boundary within 50 bytes.
fn status_text(severity: u8, text: &str) -> apm::MavMessage {
    let mut end = text.len().min(50);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    apm::MavMessage::STATUSTEXT(apm::STATUSTEXT_DATA {
        severity: mav_severity(severity),
        text: text[..end].into(),
        id: 0,
        chunk_seq: 0,
    })
}

/// An RFC-5424 severity (0 emergency … 7 debug); above 7 is debug.
fn mav_severity(severity: u8) -> apm::MavSeverity {
    match severity {
        0 => apm::MavSeverity::MAV_SEVERITY_EMERGENCY,
        1 => apm::MavSeverity::MAV_SEVERITY_ALERT,
        2 => apm::MavSeverity::MAV_SEVERITY_CRITICAL,
        3 => apm::MavSeverity::MAV_SEVERITY_ERROR,
        4 => apm::MavSeverity::MAV_SEVERITY_WARNING,
        5 => apm::MavSeverity::MAV_SEVERITY_NOTICE,
        6 => apm::MavSeverity::MAV_SEVERITY_INFO,
        _ => apm::MavSeverity::MAV_SEVERITY_DEBUG,
    }
}

/// `COMMAND_LONG` `MAV_CMD_SET_MESSAGE_INTERVAL`: stream `message_id` every
/// `interval_us`.
fn set_message_interval(message_id: u32, interval_us: f32, target_system: u8, target_component: u8) -> apm::MavMessage {
    apm::MavMessage::COMMAND_LONG(apm::COMMAND_LONG_DATA {
        param1: message_id as f32,
        param2: interval_us,
        param3: 0.0,
        param4: 0.0,
        param5: 0.0,
        param6: 0.0,
        param7: 0.0,
        command: apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
        target_system,
        target_component,
        confirmation: 0,
    })
}

/// `TIMESYNC` request: our time `ts1_ns`, `tc1` 0.
fn timesync_request(ts1_ns: i64, target_system: u8, target_component: u8) -> apm::MavMessage {
    apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
        tc1: 0,
        ts1: ts1_ns,
        target_system,
        target_component,
    })
}

/// `VISION_POSITION_ESTIMATE`: position (NED, m), roll, pitch, yaw (rad)
/// and the upper triangle of their covariance.
fn vision_position_estimate(
    t_us: u64,
    p_ned_m: &Vector3<f64>,
    rpy_rad: &Vector3<f64>,
    covariance: &[f32; 21],
    reset_counter: u8,
) -> apm::MavMessage {
    apm::MavMessage::VISION_POSITION_ESTIMATE(apm::VISION_POSITION_ESTIMATE_DATA {
        usec: t_us,
        x: p_ned_m.x as f32,
        y: p_ned_m.y as f32,
        z: p_ned_m.z as f32,
        roll: rpy_rad.x as f32,
        pitch: rpy_rad.y as f32,
        yaw: rpy_rad.z as f32,
        covariance: *covariance,
        reset_counter,
    })
}

/// `ODOMETRY` of a VIO estimator: pose in the local FRD frame, velocity and
/// rate in the body FRD frame, with their covariances.
#[allow(clippy::too_many_arguments)] // the fields of `Outbound::Odometry`
fn odometry(
    t_us: u64,
    p_ned_m: &Vector3<f64>,
    q_wxyz: &[f32; 4],
    v_body_mps: &Vector3<f64>,
    w_body_radps: &Vector3<f64>,
    pose_covariance: &[f32; 21],
    velocity_covariance: &[f32; 21],
    reset_counter: u8,
) -> apm::MavMessage {
    apm::MavMessage::ODOMETRY(apm::ODOMETRY_DATA {
        time_usec: t_us,
        x: p_ned_m.x as f32,
        y: p_ned_m.y as f32,
        z: p_ned_m.z as f32,
        q: *q_wxyz,
        vx: v_body_mps.x as f32,
        vy: v_body_mps.y as f32,
        vz: v_body_mps.z as f32,
        rollspeed: w_body_radps.x as f32,
        pitchspeed: w_body_radps.y as f32,
        yawspeed: w_body_radps.z as f32,
        pose_covariance: *pose_covariance,
        velocity_covariance: *velocity_covariance,
        frame_id: apm::MavFrame::MAV_FRAME_LOCAL_FRD,
        child_frame_id: apm::MavFrame::MAV_FRAME_BODY_FRD,
        reset_counter,
        estimator_type: apm::MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO,
        quality: 100,
    })
}

/// `SET_GPS_GLOBAL_ORIGIN` (deprecated, but what ArduPilot 4.x takes):
/// degrees and metres to 1e-7 deg and mm.
#[allow(deprecated)]
fn set_gps_global_origin(lat_deg: f64, lon_deg: f64, alt_m: f64, target_system: u8) -> apm::MavMessage {
    apm::MavMessage::SET_GPS_GLOBAL_ORIGIN(apm::SET_GPS_GLOBAL_ORIGIN_DATA {
        latitude: (lat_deg * 1e7).round() as i32,
        longitude: (lon_deg * 1e7).round() as i32,
        altitude: (alt_m * 1000.0).round() as i32,
        target_system,
        time_usec: 0,
    })
}
