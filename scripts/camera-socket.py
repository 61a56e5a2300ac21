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

One front-end at a time, kept until it goes (another that connects meanwhile
is refused and counted). Writing never waits: a frame that finds no reader,
or a reader still taking the previous frame, is dropped and counted, never
queued, and the camera is read on time whatever the reader does. The
socket is made mode 0660 (--mode). The camera command ending, or a short
read, ends this process with status 1 and a reason (systemd or the user
restarts it; the front-end waits and connects again). SIGTERM or SIGINT
ends it with status 0, at once, whatever it is waiting on; the camera
command is stopped and the socket removed either way.

The stamp is the arrival time less --latency-ms: measure the camera's
latency (exposure to pipe) once, or estimate it with the daemon's time
offset (`camera.t_d_s`).
"""

import argparse
import errno
import os
import select
import signal
import socket
import stat
import struct
import subprocess
import sys
import time

MAGIC = b"CMSKIMG1"
MAX_SIDE_PX = 8192
MAX_LATENCY_MS = 10_000.0


def frame_bytes_of(fmt, w, h):
    """Bytes of one frame of the command's pixel format."""
    chroma = 2 * ((w + 1) // 2) * ((h + 1) // 2)
    return {"grey": w * h, "i420": w * h + chroma, "nv12": w * h + chroma, "yuyv": 2 * w * h}[fmt]


def luma(frame, fmt, w, h):
    """The frame's w*h grey bytes (the Y plane, or every other byte of YUYV)."""
    if fmt == "yuyv":
        return frame[0 : 2 * w * h : 2]
    return frame[: w * h]


class Stop(Exception):
    """SIGTERM or SIGINT: raised from the handler, so a blocked wait ends."""


def on_signal(*_):
    raise Stop()


def say(text):
    """A line on stderr; a closed stderr never stops the camera."""
    try:
        print(f"camera-socket: {text}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def claim(path):
    """Removes a stale socket at path; refuses anything else there."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode):
        raise SystemExit(f"camera-socket: {path} exists and is not a socket: not removing it")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.connect(path)
    except OSError:
        os.unlink(path)  # nobody listens: a stale socket from an earlier run
        return
    finally:
        probe.close()
    raise SystemExit(f"camera-socket: another camera serves {path} already")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--socket", required=True, help="the Unix socket cmsckf-frontend --camera-socket connects to")
    p.add_argument("--width", type=int, required=True, help="frame width (px): the config's camera.width")
    p.add_argument("--height", type=int, required=True, help="frame height (px): the config's camera.height")
    p.add_argument("--format", choices=["grey", "i420", "nv12", "yuyv"], required=True, help="the command's pixel format")
    p.add_argument("--latency-ms", type=float, default=0.0, help="exposure to arrival (ms), taken off the stamp")
    p.add_argument("--mode", default="0660", help="the socket's mode, octal (0660: the owner and its group)")
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- then the camera command")
    a = p.parse_args()
    cmd = a.command[1:] if a.command[:1] == ["--"] else a.command
    if not cmd:
        p.error("no camera command: give it after --")
    if not (1 <= a.width <= MAX_SIDE_PX and 1 <= a.height <= MAX_SIDE_PX):
        p.error(f"--width and --height must each be 1..={MAX_SIDE_PX}")
    if not (0.0 <= a.latency_ms <= MAX_LATENCY_MS):
        p.error(f"--latency-ms must be a number in 0..={MAX_LATENCY_MS:.0f}")
    try:
        mode = int(a.mode, 8)
    except ValueError:
        p.error("--mode must be octal, e.g. 0660")
    frame_bytes = frame_bytes_of(a.format, a.width, a.height)
    latency_us = int(a.latency_ms * 1000)

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGPIPE, signal.SIG_IGN)
    counts = {"frames": 0, "served": 0, "no_reader": 0, "reader_slow": 0, "readers": 0, "refused": 0}
    server = camera = client = None
    ours = None
    status, reason = 0, "stopped"
    try:
        claim(a.socket)
        server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            server.bind(a.socket)
            os.chmod(a.socket, mode)
        except OSError as e:
            raise SystemExit(f"camera-socket: cannot serve on {a.socket}: {e.strerror}")
        ours = os.lstat(a.socket).st_ino
        server.listen(4)
        server.setblocking(False)
        try:
            camera = subprocess.Popen(cmd, stdout=subprocess.PIPE, bufsize=0)
        except OSError as e:
            raise SystemExit(f"camera-socket: cannot start the camera command {cmd[0]}: {e.strerror}")
        cam_fd = camera.stdout.fileno()
        raw = bytearray()
        pending = memoryview(b"")  # what is left of the frame being sent
        last_report = time.monotonic()
        while True:
            readers = [cam_fd, server]
            writers = [client] if client is not None and len(pending) else []
            r, w, _ = select.select(readers, writers, [], 1.0)
            if server in r:
                conn, _ = server.accept()
                if client is None:
                    client = conn
                    client.setblocking(False)
                    counts["readers"] += 1
                    say("a front-end connected")
                else:
                    conn.close()  # one reader at a time: the first keeps it
                    counts["refused"] += 1
            if w:
                try:
                    n = client.send(pending)
                    pending = pending[n:]
                except BlockingIOError:
                    pass
                except OSError:
                    client.close()
                    client, pending = None, memoryview(b"")
                    say("the front-end went away")
            if cam_fd in r:
                chunk = os.read(cam_fd, frame_bytes - len(raw))
                if not chunk:
                    try:
                        code = camera.wait(timeout=1)
                    except subprocess.TimeoutExpired:
                        code = "none yet: its output closed"
                    status = 1
                    reason = f"the camera command ended (exit status {code}) after {len(raw)} of a frame's {frame_bytes} bytes"
                    break
                raw += chunk
                if len(raw) < frame_bytes:
                    continue
                t_us = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000 - latency_us
                counts["frames"] += 1
                frame, raw = bytes(raw), bytearray()
                if client is None:
                    counts["no_reader"] += 1
                elif len(pending):
                    counts["reader_slow"] += 1
                else:
                    header = MAGIC + struct.pack("<QII", max(t_us, 0), a.width, a.height)
                    pending = memoryview(header + luma(frame, a.format, a.width, a.height))
                    counts["served"] += 1
            if time.monotonic() - last_report > 10:
                last_report = time.monotonic()
                say(str(counts))
    except Stop:
        status, reason = 0, "stopped by a signal"
    except SystemExit as e:
        status, reason = 1, str(e).removeprefix("camera-socket: ")
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if camera is not None and camera.poll() is None:
            camera.terminate()
            try:
                camera.wait(timeout=2)
            except subprocess.TimeoutExpired:
                camera.kill()
        if client is not None:
            client.close()
        if server is not None:
            server.close()
        try:
            if ours is not None and os.lstat(a.socket).st_ino == ours:
                os.unlink(a.socket)  # only our own socket, never a successor's
        except OSError:
            pass
        say(f"{reason}; {counts}")
    return status


if __name__ == "__main__":
    sys.exit(main())
