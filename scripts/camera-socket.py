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

A VOXL's camera server publishes under ModalAI's MPA (libmodal-pipe) instead:

    scripts/camera-socket.py --socket /run/cmsckf-camera.sock --mpa /run/mpa/tracking

asks the camera server's pipe directory for a pipe of its own (a client
name written to its `request` FIFO), reads each frame's packed 40-byte
camera_image_metadata_t (magic 0x564F584C, "VOXL") and its image, keeps the
luma of RAW8, STEREO_RAW8 (the left image), NV12, NV21 and YUV420 frames
(others are counted and skipped), and stamps it with the frame's own
timestamp_ns, CLOCK_MONOTONIC at the start of exposure, plus half the
exposure. A camera server that goes away is asked again every second; a
stream that loses its place is resynchronised on the next magic number.
--width and --height, if given, must match the frames (others are counted
and skipped).
"""

import argparse
import errno
import os
import random
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

# ModalAI's MPA camera pipes (libmodal-pipe): each frame is a packed
# camera_image_metadata_t, then size_bytes of image.
MPA_MAGIC = 0x564F584C  # "VOXL"
MPA_META = struct.Struct("<Iqihhiiihhhh")  # magic, timestamp_ns, frame_id, width, height,
# size_bytes, stride, exposure_ns, gain, format, framerate, reserved: 40 bytes
MPA_LUMA_FORMATS = {0: "raw8", 1: "nv12", 2: "stereo_raw8", 6: "nv21", 9: "yuv420"}
MPA_MAX_FRAME_BYTES = 64 << 20
MPA_RETRY_S = 1.0


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


class MpaCamera:
    """A camera server's MPA pipe directory, read as one of its clients."""

    def __init__(self, pipe_dir, counts):
        self.dir = pipe_dir
        self.counts = counts
        self.fd = None
        self.path = None
        self.buf = bytearray()
        self.next_try = 0.0

    def connect(self):
        """One attempt, at most every MPA_RETRY_S: write a fresh client name
        to the server's request FIFO and open the FIFO it makes for it."""
        now = time.monotonic()
        if self.fd is not None or now < self.next_try:
            return
        self.next_try = now + MPA_RETRY_S
        name = f"cmsckf{os.getpid()}-{random.randrange(10**8):08d}"
        path = os.path.join(self.dir, name)
        try:
            req = os.open(os.path.join(self.dir, "request"), os.O_WRONLY | os.O_NONBLOCK)
        except OSError:
            return  # no camera server yet (ENOENT), or none reading its requests (ENXIO)
        try:
            os.write(req, name.encode() + b"\0")
        except OSError:
            return
        finally:
            os.close(req)
        deadline = now + 1.0
        while not os.path.exists(path):
            if time.monotonic() > deadline:
                return
            time.sleep(0.005)
        try:
            self.fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        except OSError:
            return
        self.path, self.buf = path, bytearray()
        self.counts["mpa_connects"] += 1
        say(f"reading the camera server's pipe {self.dir} as {name}")

    def drop(self, why, again=True):
        if self.fd is not None:
            os.close(self.fd)
        if self.path is not None:
            try:
                os.unlink(self.path)
            except OSError:
                pass
        self.fd, self.path, self.buf = None, None, bytearray()
        say(f"{why}; asking again every {MPA_RETRY_S:.0f} s" if again else why)

    def frames(self):
        """Reads what the pipe holds: the whole frames in it, as
        (t_us, width, height, luma bytes)."""
        try:
            chunk = os.read(self.fd, 1 << 20)
        except BlockingIOError:
            return []
        except OSError as e:
            self.drop(f"the camera server's pipe failed: {e.strerror}")
            return []
        if not chunk:
            self.drop("the camera server closed its pipe")
            return []
        self.buf += chunk
        out = []
        magic = struct.pack("<I", MPA_MAGIC)
        while len(self.buf) >= MPA_META.size:
            magic_no, t_ns, _, w, h, size, stride, exposure_ns, _, fmt, _, _ = MPA_META.unpack_from(self.buf)
            if magic_no != MPA_MAGIC:
                i = self.buf.find(magic, 1)
                self.counts["mpa_resync"] += 1
                del self.buf[: i if i > 0 else len(self.buf) - len(magic) + 1]
                continue
            if not 0 < size <= MPA_MAX_FRAME_BYTES:
                self.drop(f"a frame of {size} bytes in the camera server's pipe")
                return out
            if len(self.buf) < MPA_META.size + size:
                break
            image = bytes(self.buf[MPA_META.size : MPA_META.size + size])
            del self.buf[: MPA_META.size + size]
            stride = stride if stride > 0 else w
            if (
                fmt not in MPA_LUMA_FORMATS
                or not (1 <= w <= MAX_SIDE_PX and 1 <= h <= MAX_SIDE_PX)
                or stride < w
                or stride * h > size
                or t_ns < 0
            ):
                self.counts["mpa_unusable"] += 1
                continue
            y = image[: stride * h]
            if stride != w:
                y = b"".join(y[r * stride : r * stride + w] for r in range(h))
            out.append(((t_ns + max(exposure_ns, 0) // 2) // 1000, w, h, y))
        return out


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
    p.add_argument("--width", type=int, help="frame width (px): the config's camera.width")
    p.add_argument("--height", type=int, help="frame height (px): the config's camera.height")
    p.add_argument("--format", choices=["grey", "i420", "nv12", "yuyv"], help="the command's pixel format")
    p.add_argument("--mpa", metavar="PIPE_DIR", help="read a VOXL camera server's MPA pipe (e.g. /run/mpa/tracking) instead of a command")
    p.add_argument("--latency-ms", type=float, default=0.0, help="exposure to arrival (ms), taken off the stamp")
    p.add_argument("--mode", default="0660", help="the socket's mode, octal (0660: the owner and its group)")
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- then the camera command")
    a = p.parse_args()
    cmd = a.command[1:] if a.command[:1] == ["--"] else a.command
    if a.mpa is None and not cmd:
        p.error("no camera command: give it after --, or --mpa PIPE_DIR")
    if a.mpa is not None and cmd:
        p.error("--mpa reads a camera server's pipe: give no command with it")
    if a.mpa is None and (a.width is None or a.height is None or a.format is None):
        p.error("a camera command needs --width, --height and --format")
    for side in (a.width, a.height):
        if side is not None and not 1 <= side <= MAX_SIDE_PX:
            p.error(f"--width and --height must each be 1..={MAX_SIDE_PX}")
    if not (0.0 <= a.latency_ms <= MAX_LATENCY_MS):
        p.error(f"--latency-ms must be a number in 0..={MAX_LATENCY_MS:.0f}")
    try:
        mode = int(a.mode, 8)
    except ValueError:
        p.error("--mode must be octal, e.g. 0660")
    frame_bytes = frame_bytes_of(a.format, a.width, a.height) if a.mpa is None else 0
    latency_us = int(a.latency_ms * 1000)

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGPIPE, signal.SIG_IGN)
    counts = {"frames": 0, "served": 0, "no_reader": 0, "reader_slow": 0, "readers": 0, "refused": 0}
    if a.mpa is not None:
        counts.update({"mpa_connects": 0, "mpa_resync": 0, "mpa_unusable": 0, "wrong_size": 0})
    server = camera = client = mpa = None
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
        if a.mpa is None:
            try:
                camera = subprocess.Popen(cmd, stdout=subprocess.PIPE, bufsize=0)
            except OSError as e:
                raise SystemExit(f"camera-socket: cannot start the camera command {cmd[0]}: {e.strerror}")
            cam_fd = camera.stdout.fileno()
        else:
            mpa = MpaCamera(a.mpa, counts)
            cam_fd = None
        raw = bytearray()
        pending = memoryview(b"")  # what is left of the frame being sent
        last_report = time.monotonic()

        def offer(t_us, w, h, grey):
            """Serves one frame's luma, unless no front-end takes it now."""
            nonlocal pending
            counts["frames"] += 1
            if client is None:
                counts["no_reader"] += 1
            elif len(pending):
                counts["reader_slow"] += 1
            else:
                header = MAGIC + struct.pack("<QII", max(t_us, 0), w, h)
                pending = memoryview(header + grey)
                counts["served"] += 1

        while True:
            if mpa is not None:
                mpa.connect()
                cam_fd = mpa.fd
            readers = [server] + ([cam_fd] if cam_fd is not None else [])
            writers = [client] if client is not None and len(pending) else []
            r, w, _ = select.select(readers, writers, [], 0.5 if mpa is not None else 1.0)
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
            if mpa is not None and cam_fd is not None and cam_fd in r:
                for t_us, fw, fh, grey in mpa.frames():
                    if (a.width or fw, a.height or fh) != (fw, fh):
                        counts["wrong_size"] += 1
                        continue
                    offer(t_us, fw, fh, grey)
            elif cam_fd is not None and cam_fd in r:
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
                frame, raw = bytes(raw), bytearray()
                offer(t_us, a.width, a.height, luma(frame, a.format, a.width, a.height))
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
        if mpa is not None and mpa.fd is not None:
            mpa.drop("left the camera server's pipe", again=False)
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
