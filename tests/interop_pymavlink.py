#!/usr/bin/env python3
"""Interoperability with an independent MAVLink implementation (pymavlink).

Plays the autopilot against a running cmsckf daemon: sends HEARTBEAT,
ATTITUDE, LOCAL_POSITION_NED and a static stream of HIGHRES_IMU built by
pymavlink, and decodes the daemon's estimates with pymavlink. MODE is the
daemon's `output.message`:
- `odometry`: ODOMETRY only (no VISION_POSITION_ESTIMATE): finite pose and
  velocity covariances, a quality in -1..100, a VIO estimator, FRD frames;
- `vision_position_estimate`: VISION_POSITION_ESTIMATE, each with a
  VISION_SPEED_ESTIMATE, and no ODOMETRY: finite covariances.
Both: reset_counter 0 and the autopilot's yaw. Prints a JSON summary; exits
1 on failure.

Usage: interop_pymavlink.py PORT [SECONDS] [MODE]
"""
import json
import math
import sys
import time

from pymavlink import mavutil

ESTIMATES = ["VISION_POSITION_ESTIMATE", "VISION_SPEED_ESTIMATE", "ODOMETRY"]


def finite(values, n):
    return len(values) == n and all(math.isfinite(c) for c in values)


def yaw_of(msg):
    if msg.get_type() == "VISION_POSITION_ESTIMATE":
        return msg.yaw
    w, x, y, z = msg.q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def main() -> int:
    port = int(sys.argv[1])
    seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 3.0
    mode = sys.argv[3] if len(sys.argv) > 3 else "odometry"
    m = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=1, source_component=1, dialect="ardupilotmega"
    )
    m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_QUADROTOR, mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4)
    t_us = 30_000_000
    start = time.time()
    got = {k: [] for k in ESTIMATES}
    last_slow = 0.0
    while time.time() - start < seconds:
        now = time.time() - start
        if now - last_slow >= 0.1:
            last_slow = now
            m.mav.attitude_send(t_us // 1000, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0)
            m.mav.local_position_ned_send(t_us // 1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        m.mav.highres_imu_send(t_us, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0, 0, 20.0, 0x3F, 0)
        t_us += 10_000
        while True:
            msg = m.recv_match(type=ESTIMATES, blocking=False)
            if msg is None:
                break
            got[msg.get_type()].append(msg)
        time.sleep(0.002)
    vpe, speed, odo = got["VISION_POSITION_ESTIMATE"], got["VISION_SPEED_ESTIMATE"], got["ODOMETRY"]
    if mode == "odometry":
        est = odo
        one_source = not vpe and not speed
        cov_ok = bool(odo) and all(
            finite(o.pose_covariance, 21) and o.pose_covariance[0] > 0 and finite(o.velocity_covariance, 21)
            and o.velocity_covariance[0] > 0
            for o in odo
        )
        fields_ok = all(
            -1 <= o.quality <= 100
            and o.estimator_type == mavutil.mavlink.MAV_ESTIMATOR_TYPE_VIO
            and o.frame_id == mavutil.mavlink.MAV_FRAME_LOCAL_FRD
            and o.child_frame_id == mavutil.mavlink.MAV_FRAME_BODY_FRD
            for o in odo
        )
    else:
        est = vpe
        one_source = not odo
        cov_ok = bool(vpe) and all(finite(v.covariance, 21) and v.covariance[0] > 0 for v in vpe)
        cov_ok = cov_ok and all(finite(s.covariance, 9) and s.covariance[0] > 0 for s in speed)
        # One speed estimate per position estimate (the last may be in flight).
        fields_ok = abs(len(speed) - len(vpe)) <= 1 and all(
            s.usec == v.usec for s, v in zip(speed, vpe)
        )
    last = est[-1] if est else None
    out = {
        "mode": mode,
        "estimates_received": len(est),
        "vpe_received": len(vpe),
        "speed_received": len(speed),
        "odometry_received": len(odo),
        "qualities": sorted({o.quality for o in odo}),
        "one_source": one_source,
        "covariance_ok": cov_ok,
        "fields_ok": fields_ok,
        "reset_counter": last.reset_counter if last else None,
        "last_yaw": yaw_of(last) if last else None,
    }
    print(json.dumps(out))
    ok = last is not None and one_source and cov_ok and fields_ok
    return 0 if ok and last.reset_counter == 0 and abs(yaw_of(last) - 0.3) < 0.05 else 1


if __name__ == "__main__":
    sys.exit(main())
