#!/usr/bin/env python3
"""A camera that is not V4L2, served to cmsckf-frontend on its camera socket.

Runs a camera command that writes raw frames to its standard output, takes
each frame's luma, stamps it with CLOCK_MONOTONIC at arrival less the
camera's latency, and serves it as an image_wire frame (docs/design.md,
"Camera images"; models/src/image_wire.rs) on a Unix socket that
`cmsckf-frontend --camera-socket PATH` connects to. Run the daemon with
`features.clock = "monotonic"`. Python's standard library only.

    # Raspberry Pi (libcamera's rpicam-vid, I420):
    scripts/camera-socket.py --socket /run/cmsckf-camera.sock --width 752 --height 480 \\
        --format i420 --latency-ms 30 -- \\
        rpicam-vid -t 0 -n --codec yuv420 --width 752 --height 480 --framerate 20 -o -
    # Any GStreamer source (libcamerasrc; nvarguscamerasrc ! nvvidconv on a Jetson):
    scripts/camera-socket.py --socket /run/cmsckf-camera.sock --width 752 --height 480 \\
        --format grey -- gst-launch-1.0 -q libcamerasrc ! \\
        video/x-raw,width=752,height=480,framerate=20/1 ! videoconvert ! \\
        video/x-raw,format=GRAY8 ! fdsink fd=1

One front-end at a time; a frame finds no reader, or a reader that is not
taking them, is dropped and counted (never queued: the newest frame is the
one worth tracking). The camera command ending or a short read ends this
process with status 1 and a reason (systemd or the user restarts it; the
front-end waits and connects again). SIGTERM ends it with status 0.

The stamp is the arrival time less --latency-ms: measure the camera's
latency (exposure to pipe) once, or estimate it with the daemon's time
offset (`camera.t_d_s`).
"""

import argparse
import os
import select
import signal
import socket
import struct
import subprocess
import sys
import time

MAGIC = b"CMSKIMG1"
MAX_SIDE_PX = 8192

# Bytes per frame, and where the luma plane is in it, per pixel format.
FORMATS = {
    "grey": lambda w, h: (w * h, None),  # 8-bit grey (GRAY8)
    "i420": lambda w, h: (w * h + 2 * ((w + 1) // 2) * ((h + 1) // 2), None),  # planar Y, U, V
    "nv12": lambda w, h: (w * h + 2 * ((w + 1) // 2) * ((h + 1) // 2), None),  # planar Y, packed UV
    "yuyv": lambda w, h: (2 * w * h, "yuyv"),  # packed Y0 U Y1 V
}


def luma(frame, fmt, w, h):
    """The frame's w*h grey bytes."""
    if fmt == "yuyv":
        return frame[0 : 2 * w * h : 2]
    return frame[: w * h]


def read_exactly(stream, n):
    """n bytes, or fewer at the stream's end."""
    chunks, got = [], 0
    while got < n:
        b = stream.read(n - got)
        if not b:
            break
        chunks.append(b)
        got += len(b)
    return b"".join(chunks)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--socket", required=True, help="the Unix socket cmsckf-frontend --camera-socket connects to")
    p.add_argument("--width", type=int, required=True, help="frame width (px): the config's camera.width")
    p.add_argument("--height", type=int, required=True, help="frame height (px): the config's camera.height")
    p.add_argument("--format", choices=sorted(FORMATS), required=True, help="the command's pixel format")
    p.add_argument("--latency-ms", type=float, default=0.0, help="exposure to arrival (ms), taken off the stamp")
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- then the camera command")
    a = p.parse_args()
    cmd = a.command[1:] if a.command[:1] == ["--"] else a.command
    if not cmd:
        p.error("no camera command: give it after --")
    if not (1 <= a.width <= MAX_SIDE_PX and 1 <= a.height <= MAX_SIDE_PX):
        p.error(f"--width and --height must each be 1..={MAX_SIDE_PX}")
    if a.latency_ms < 0 or a.latency_ms != a.latency_ms:
        p.error("--latency-ms must be a number >= 0")
    frame_bytes, _ = FORMATS[a.format](a.width, a.height)
    latency_us = int(a.latency_ms * 1000)

    if os.path.exists(a.socket):
        os.unlink(a.socket)  # a stale socket from an earlier run
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(a.socket)
    server.listen(1)
    server.setblocking(False)

    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    camera = subprocess.Popen(cmd, stdout=subprocess.PIPE, bufsize=0)
    client = None
    counts = {"frames": 0, "served": 0, "no_reader": 0, "reader_slow": 0, "readers": 0}
    last_report = time.monotonic()
    status, reason = 0, "stopped"
    try:
        while not stop:
            raw = read_exactly(camera.stdout, frame_bytes)
            t_us = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000 - latency_us
            if len(raw) < frame_bytes:
                if not stop:
                    try:
                        code = camera.wait(timeout=1)
                    except subprocess.TimeoutExpired:
                        code = "none yet: its output closed"
                    status = 1
                    reason = f"the camera command ended (exit status {code}) after {len(raw)} of a frame's {frame_bytes} bytes"
                break
            counts["frames"] += 1
            # A front-end that came (or came back) since the last frame.
            try:
                conn, _ = server.accept()
                if client is not None:
                    client.close()
                client = conn
                client.setblocking(True)
                client.settimeout(0.5)
                counts["readers"] += 1
            except BlockingIOError:
                pass
            if client is None:
                counts["no_reader"] += 1
                continue
            # A reader that cannot take a whole frame now is not waited for.
            _, writable, _ = select.select([], [client], [], 0)
            if not writable:
                counts["reader_slow"] += 1
                continue
            header = MAGIC + struct.pack("<QII", max(t_us, 0), a.width, a.height)
            try:
                client.sendall(header + luma(raw, a.format, a.width, a.height))
                counts["served"] += 1
            except OSError:
                client.close()
                client = None
            if time.monotonic() - last_report > 10:
                last_report = time.monotonic()
                print(f"camera-socket: {counts}", file=sys.stderr, flush=True)
    finally:
        if camera.poll() is None:
            camera.terminate()
            try:
                camera.wait(timeout=2)
            except subprocess.TimeoutExpired:
                camera.kill()
        if client is not None:
            client.close()
        server.close()
        if os.path.exists(a.socket):
            os.unlink(a.socket)
        print(f"camera-socket: {reason}; {counts}", file=sys.stderr, flush=True)
    return status


if __name__ == "__main__":
    sys.exit(main())
