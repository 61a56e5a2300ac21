//! Outbound: [`Outbound`] values become MAVLink messages (a long
//! STATUSTEXT becomes its MAVLink 2 chunks), with SI units scaled as each
//! message defines.

use std::sync::atomic::{AtomicU16, Ordering};

use mavlink::dialects::ardupilotmega as apm;
use mavlink::MavHeader;
use nalgebra::Vector3;

use crate::io::messages::Outbound;

/// Encodes an [`Outbound`] as MAVLink 2 frames, numbered from `seq` (one
/// frame, or a long STATUSTEXT's chunks; for tests and fuzz seeds).
pub fn encode_bytes(out: &Outbound, seq: u8) -> Vec<u8> {
    let mut buf = Vec::new();
    for (k, msg) in encode(out, 1, 1).iter().enumerate() {
        let h = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: seq.wrapping_add(k as u8),
        };
        let _ = mavlink::write_versioned_msg(&mut buf, mavlink::MavlinkVersion::V2, h, msg);
    }
    buf
}

/// [`Outbound`] → MAVLink messages: one, a long STATUSTEXT's chunks, or
/// the origin in both its forms with a request to read it back.
pub(super) fn encode(out: &Outbound, target_system: u8, target_component: u8) -> Vec<apm::MavMessage> {
    let one = match out {
        Outbound::StatusText { severity, text } => return status_text(*severity, text),
        Outbound::Heartbeat { initialised, degraded } => heartbeat(*initialised, *degraded),
        Outbound::SetMessageInterval {
            message_id,
            interval_us,
        } => set_message_interval(*message_id, *interval_us, target_system, target_component),
        Outbound::ParamRequestRead { name } => apm::MavMessage::PARAM_REQUEST_READ(apm::PARAM_REQUEST_READ_DATA {
            // -1: by name.
            param_index: -1,
            target_system,
            target_component,
            param_id: (*name).into(),
        }),
        Outbound::RequestMessage { message_id } => apm::MavMessage::COMMAND_LONG(apm::COMMAND_LONG_DATA {
            target_system,
            target_component,
            command: apm::MavCmd::MAV_CMD_REQUEST_MESSAGE,
            param1: *message_id as f32,
            ..Default::default()
        }),
        Outbound::TimesyncRequest { ts1_ns } => timesync_request(*ts1_ns, target_system, target_component),
        Outbound::TimesyncReply { tc1_ns, ts1_ns } => apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
            tc1: *tc1_ns,
            ts1: *ts1_ns,
            target_system,
            target_component,
        }),
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
            quality,
            frame_ned,
        } => odometry(
            *t_us,
            p_ned_m,
            q_wxyz,
            v_body_mps,
            w_body_radps,
            pose_covariance,
            velocity_covariance,
            *reset_counter,
            *quality,
            *frame_ned,
        ),
        Outbound::VisionSpeedEstimate {
            t_us,
            v_ned_mps,
            covariance,
            reset_counter,
        } => vision_speed_estimate(*t_us, v_ned_mps, covariance, *reset_counter),
        Outbound::SetGpsGlobalOrigin {
            lat_deg,
            lon_deg,
            alt_m,
        } => return set_origin(*lat_deg, *lon_deg, *alt_m, target_system, target_component),
    };
    vec![one]
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

/// Bytes of text in one `STATUSTEXT`.
const STATUSTEXT_LEN: usize = 50;
/// Most `STATUSTEXT` messages one text is sent as; a longer text is cut,
/// ending with [`STATUSTEXT_CUT`].
const STATUSTEXT_MAX_CHUNKS: usize = 4;
const STATUSTEXT_CUT: &str = "…";

/// The id of the next chunked `STATUSTEXT`: 1, 2, … 65535, 1, … (never 0,
/// which marks a text sent whole).
fn next_status_text_id() -> u16 {
    static NEXT: AtomicU16 = AtomicU16::new(0);
    loop {
        let id = NEXT.fetch_add(1, Ordering::Relaxed).wrapping_add(1);
        if id != 0 {
            return id;
        }
    }
}

/// The largest character boundary of `s` at or before byte `n`.
fn floor_char_boundary(s: &str, n: usize) -> usize {
    let mut end = n.min(s.len());
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    end
}

/// The pieces `text` is sent as, MAVLink 2's chunked `STATUSTEXT`
/// (common.xml): up to 50 bytes, one piece (sent with `id` 0). Longer, up
/// to [`STATUSTEXT_MAX_CHUNKS`] pieces of one `id`, where a NUL in a piece
/// marks the last: each but the last fills its 50 bytes, cut at a
/// character boundary so that every piece is valid UTF-8 on its own (a
/// character that would straddle the cut moves to the next piece, and the
/// 1–3 bytes it leaves are padded with spaces, since a NUL there would end
/// the text); the last is shorter than 50 bytes, or is an empty piece
/// after a text that fills its last piece exactly. A text that does not
/// fit is cut at a character boundary and ends with "…".
fn status_text_pieces(text: &str) -> Vec<String> {
    if text.len() <= STATUSTEXT_LEN {
        return vec![text.to_string()];
    }
    let mut pieces = Vec::new();
    let mut rest = text;
    while !rest.is_empty() {
        if pieces.len() == STATUSTEXT_MAX_CHUNKS - 1 && rest.len() >= STATUSTEXT_LEN {
            // The last piece allowed: it must hold its NUL.
            let keep = floor_char_boundary(rest, STATUSTEXT_LEN - 1 - STATUSTEXT_CUT.len());
            pieces.push(format!("{}{STATUSTEXT_CUT}", &rest[..keep]));
            return pieces;
        }
        let cut = floor_char_boundary(rest, STATUSTEXT_LEN);
        let mut piece = rest[..cut].to_string();
        rest = &rest[cut..];
        if !rest.is_empty() {
            while piece.len() < STATUSTEXT_LEN {
                piece.push(' ');
            }
        }
        pieces.push(piece);
    }
    if pieces.last().is_some_and(|p| p.len() == STATUSTEXT_LEN) {
        // Exactly filled: an empty piece (all NUL) ends the text.
        pieces.push(String::new());
    }
    pieces
}

/// `STATUSTEXT`: the text whole (`id` 0), or in chunks of one new `id`
/// with `chunk_seq` 0, 1, … (see [`status_text_pieces`]).
fn status_text(severity: u8, text: &str) -> Vec<apm::MavMessage> {
    let pieces = status_text_pieces(text);
    let id = if pieces.len() > 1 { next_status_text_id() } else { 0 };
    pieces
        .iter()
        .enumerate()
        .map(|(k, piece)| {
            apm::MavMessage::STATUSTEXT(apm::STATUSTEXT_DATA {
                severity: mav_severity(severity),
                text: piece.as_str().into(),
                id,
                chunk_seq: k as u8,
            })
        })
        .collect()
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

/// `VISION_SPEED_ESTIMATE`: velocity (NED, m/s) and its 3×3 covariance,
/// row-major.
fn vision_speed_estimate(
    t_us: u64,
    v_ned_mps: &Vector3<f64>,
    covariance: &[f32; 9],
    reset_counter: u8,
) -> apm::MavMessage {
    apm::MavMessage::VISION_SPEED_ESTIMATE(apm::VISION_SPEED_ESTIMATE_DATA {
        usec: t_us,
        x: v_ned_mps.x as f32,
        y: v_ned_mps.y as f32,
        z: v_ned_mps.z as f32,
        covariance: *covariance,
        reset_counter,
    })
}

/// `ODOMETRY` of a VIO estimator: pose in the local FRD frame (our NED
/// coordinates: what ArduPilot takes), velocity and rate in the body FRD
/// frame, with their covariances, and the quality.
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
    quality: i8,
    frame_ned: bool,
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
        frame_id: if frame_ned {
            apm::MavFrame::MAV_FRAME_LOCAL_NED
        } else {
            apm::MavFrame::MAV_FRAME_LOCAL_FRD
        },
        child_frame_id: apm::MavFrame::MAV_FRAME_BODY_FRD,
        reset_counter,
        estimator_type: apm::MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO,
        quality,
    })
}

/// The EKF origin (altitude above mean sea level), in both forms an
/// autopilot may know: `SET_GPS_GLOBAL_ORIGIN` (deprecated, what ArduPilot
/// 4.x and PX4 take: 1e-7 deg and mm) and `MAV_CMD_DO_SET_GLOBAL_ORIGIN`
/// as `COMMAND_INT` (ArduPilot 4.7 takes it; as `COMMAND_LONG` its float
/// parameters would round the position by decimetres, and ArduPilot
/// refuses it), then `MAV_CMD_REQUEST_MESSAGE` for `GPS_GLOBAL_ORIGIN`, so
/// the origin the autopilot took comes back. An autopilot sets its origin
/// once: the second form is refused (ACK FAILED) and changes nothing.
#[allow(deprecated)]
fn set_origin(lat_deg: f64, lon_deg: f64, alt_m: f64, target_system: u8, target_component: u8) -> Vec<apm::MavMessage> {
    let (lat_e7, lon_e7) = ((lat_deg * 1e7).round() as i32, (lon_deg * 1e7).round() as i32);
    vec![
        apm::MavMessage::SET_GPS_GLOBAL_ORIGIN(apm::SET_GPS_GLOBAL_ORIGIN_DATA {
            latitude: lat_e7,
            longitude: lon_e7,
            altitude: (alt_m * 1000.0).round() as i32,
            target_system,
            time_usec: 0,
        }),
        apm::MavMessage::COMMAND_INT(apm::COMMAND_INT_DATA {
            target_system,
            target_component,
            frame: apm::MavFrame::MAV_FRAME_GLOBAL,
            command: apm::MavCmd::MAV_CMD_DO_SET_GLOBAL_ORIGIN,
            x: lat_e7,
            y: lon_e7,
            z: alt_m as f32,
            ..Default::default()
        }),
        apm::MavMessage::COMMAND_LONG(apm::COMMAND_LONG_DATA {
            target_system,
            target_component,
            command: apm::MavCmd::MAV_CMD_REQUEST_MESSAGE,
            param1: 49.0, // GPS_GLOBAL_ORIGIN
            ..Default::default()
        }),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames(out: &Outbound) -> Vec<apm::MavMessage> {
        let bytes = encode_bytes(out, 7);
        let mut r = mavlink::MavlinkReader::new(&bytes[..]);
        let mut v = Vec::new();
        while let Ok((_, m)) = r.read_any_message::<apm::MavMessage>() {
            v.push(m);
        }
        v
    }

    /// A receiver that reassembles as common.xml says (as pymavlink's and
    /// MAVProxy's do): `id` 0 is a whole text; otherwise chunks of one `id`
    /// in `chunk_seq` order until one holds a NUL. Returns the texts and
    /// the chunks' `(id, chunk_seq)`.
    fn reassemble(msgs: &[apm::MavMessage]) -> (Vec<String>, Vec<(u16, u8)>) {
        let mut texts = Vec::new();
        let mut seen = Vec::new();
        let mut open: Option<(u16, Vec<u8>)> = None;
        for m in msgs {
            let apm::MavMessage::STATUSTEXT(st) = m else {
                panic!("not a STATUSTEXT: {m:?}")
            };
            seen.push((st.id, st.chunk_seq));
            let bytes: [u8; 50] = st.text.into();
            let end = bytes.iter().position(|&b| b == 0);
            let text = &bytes[..end.unwrap_or(50)];
            // Each chunk is valid UTF-8 on its own.
            assert!(std::str::from_utf8(text).is_ok(), "{text:?}");
            if st.id == 0 {
                texts.push(String::from_utf8(text.to_vec()).unwrap());
                continue;
            }
            let (id, mut acc) = open.take().unwrap_or((st.id, Vec::new()));
            assert_eq!(id, st.id, "chunks of two texts interleaved");
            acc.extend_from_slice(text);
            if end.is_some() {
                texts.push(String::from_utf8(acc).unwrap());
            } else {
                open = Some((id, acc));
            }
        }
        assert!(open.is_none(), "a text was left unterminated");
        (texts, seen)
    }

    fn sent_text(text: &str) -> (String, Vec<(u16, u8)>) {
        let (texts, seen) = reassemble(&frames(&Outbound::StatusText {
            severity: 4,
            text: text.to_string(),
        }));
        assert_eq!(texts.len(), 1, "{texts:?}");
        (texts[0].clone(), seen)
    }

    /// Chunk ids and sequence numbers: `[(0, 0)]` for a whole text, else
    /// one non-zero id with 0, 1, … .
    fn chunked(seen: &[(u16, u8)], n: usize) {
        assert_eq!(seen.len(), n, "{seen:?}");
        assert!(seen.iter().all(|&(id, _)| id != 0 && id == seen[0].0), "{seen:?}");
        assert!(seen.iter().enumerate().all(|(k, &(_, c))| c as usize == k), "{seen:?}");
    }

    #[test]
    fn status_text_is_chunked_as_mavlink_2_says() {
        // Short, and exactly 50 bytes: one message, id 0.
        assert_eq!(sent_text("cmsckf: nominal"), ("cmsckf: nominal".into(), vec![(0, 0)]));
        let t50 = "x".repeat(50);
        assert_eq!(sent_text(&t50), (t50.clone(), vec![(0, 0)]));
        // 51 and 120 bytes: 2 and 3 chunks of one non-zero id.
        let t51 = format!("{}y", "x".repeat(50));
        let (got, seen) = sent_text(&t51);
        assert_eq!(got, t51);
        chunked(&seen, 2);
        let t120: String = (0..120).map(|k| (b'a' + (k % 26) as u8) as char).collect();
        let (got, seen) = sent_text(&t120);
        assert_eq!(got, t120);
        chunked(&seen, 3);
        // An exact multiple of 50: an empty chunk ends it.
        let t100 = "z".repeat(100);
        let (got, seen) = sent_text(&t100);
        assert_eq!(got, t100);
        chunked(&seen, 3);
        // Two long texts have two ids.
        let (_, again) = sent_text(&t51);
        assert_ne!(again[0].0, seen[0].0);
    }

    #[test]
    fn status_text_chunks_cut_at_character_boundaries() {
        // "é" (2 bytes) and "€" (3 bytes) across byte 50: each moves to the
        // next chunk, and the chunk it leaves is padded with spaces (a NUL
        // would end the text there).
        for (head, ch) in [(49, "é"), (48, "€"), (47, "€"), (50, "é")] {
            let text = format!("{}{ch}{}", "a".repeat(head), "b".repeat(10));
            let (got, seen) = sent_text(&text);
            chunked(&seen, 2);
            let pad = 50 - head.min(50);
            let pad = if head + ch.len() <= 50 { 0 } else { pad };
            assert_eq!(
                got,
                format!("{}{}{ch}{}", "a".repeat(head), " ".repeat(pad), "b".repeat(10))
            );
        }
    }

    #[test]
    fn an_over_long_status_text_is_cut_with_an_ellipsis() {
        let text: String = "cmsckf degraded: imu_gap,camera_stale,gnss_stale,input_rejected ".repeat(8);
        let (got, seen) = sent_text(&text);
        chunked(&seen, STATUSTEXT_MAX_CHUNKS);
        assert!(got.ends_with('…') && got.len() < 200, "{got}");
        assert!(text.starts_with(got.trim_end_matches('…')), "{got}");
        // Exactly 200 bytes does not fit either (it would need a fifth,
        // empty chunk); 199 does.
        let (got, seen) = sent_text(&"q".repeat(200));
        chunked(&seen, 4);
        assert!(got.ends_with('…'));
        let (got, seen) = sent_text(&"q".repeat(199));
        chunked(&seen, 4);
        assert_eq!(got, "q".repeat(199));
        // Multibyte near the cut: still valid UTF-8 (checked in reassemble).
        let (got, _) = sent_text(&"ü".repeat(150));
        assert!(got.ends_with('…'));
    }

    #[test]
    fn odometry_and_speed_estimate_carry_their_fields() {
        let odo = Outbound::Odometry {
            t_us: 5,
            p_ned_m: Vector3::new(1.0, 2.0, 3.0),
            q_wxyz: [1.0, 0.0, 0.0, 0.0],
            v_body_mps: Vector3::new(0.5, 0.0, 0.0),
            w_body_radps: Vector3::new(0.0, 0.0, 0.25),
            pose_covariance: [0.1; 21],
            velocity_covariance: [0.01; 21],
            reset_counter: 3,
            quality: -1,
            frame_ned: false,
        };
        let [apm::MavMessage::ODOMETRY(d)] = &frames(&odo)[..] else {
            panic!("not one ODOMETRY")
        };
        assert_eq!((d.quality, d.reset_counter, d.yawspeed, d.vx), (-1, 3, 0.25, 0.5));
        assert_eq!(d.estimator_type, apm::MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO);
        assert_eq!(
            (d.frame_id, d.child_frame_id),
            (apm::MavFrame::MAV_FRAME_LOCAL_FRD, apm::MavFrame::MAV_FRAME_BODY_FRD)
        );
        assert!(d.velocity_covariance.iter().all(|c| *c == 0.01));
        let vse = Outbound::VisionSpeedEstimate {
            t_us: 5,
            v_ned_mps: Vector3::new(1.0, -2.0, 0.5),
            covariance: [0.04; 9],
            reset_counter: 3,
        };
        let [apm::MavMessage::VISION_SPEED_ESTIMATE(d)] = &frames(&vse)[..] else {
            panic!("not one VISION_SPEED_ESTIMATE")
        };
        assert_eq!((d.usec, d.x, d.y, d.z, d.reset_counter), (5, 1.0, -2.0, 0.5, 3));
        assert_eq!(d.covariance, [0.04; 9]);
        // Towards PX4: LOCAL_NED (our world frame is north-referenced).
        let Outbound::Odometry { .. } = odo else { unreachable!() };
        let mut px4 = odo.clone();
        if let Outbound::Odometry { frame_ned, .. } = &mut px4 {
            *frame_ned = true;
        }
        let [apm::MavMessage::ODOMETRY(d)] = &frames(&px4)[..] else {
            panic!("not one ODOMETRY")
        };
        assert_eq!(d.frame_id, apm::MavFrame::MAV_FRAME_LOCAL_NED);
    }
}
