#!/usr/bin/env python3
"""Interoperability with an independent MAVLink implementation (pymavlink).

Plays the autopilot against a running cmsckf daemon: sends HEARTBEAT,
ATTITUDE, LOCAL_POSITION_NED and a static stream of HIGHRES_IMU built by
pymavlink, and decodes the daemon's VISION_POSITION_ESTIMATE with pymavlink,
checking its covariance and reset_counter. Prints a JSON summary; exits 1 on
failure.

Usage: interop_pymavlink.py PORT [SECONDS]
"""
import json
import math
import sys
import time

from pymavlink import mavutil


def main() -> int:
    port = int(sys.argv[1])
    seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 3.0
    m = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=1, source_component=1, dialect="ardupilotmega"
    )
    m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_QUADROTOR, mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4)
    t_us = 30_000_000
    start = time.time()
    vpe = []
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
            msg = m.recv_match(type="VISION_POSITION_ESTIMATE", blocking=False)
            if msg is None:
                break
            vpe.append(msg)
        time.sleep(0.002)
    cov_ok = bool(vpe) and all(
        len(v.covariance) == 21 and all(math.isfinite(c) for c in v.covariance) and v.covariance[0] > 0 for v in vpe
    )
    last = vpe[-1] if vpe else None
    out = {
        "vpe_received": len(vpe),
        "covariance_ok": cov_ok,
        "reset_counter": last.reset_counter if last else None,
        "last_usec": last.usec if last else None,
        "last_yaw": last.yaw if last else None,
    }
    print(json.dumps(out))
    return 0 if cov_ok and last.reset_counter == 0 and abs(last.yaw - 0.3) < 0.05 else 1


if __name__ == "__main__":
    sys.exit(main())
