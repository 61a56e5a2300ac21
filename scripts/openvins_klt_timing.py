#!/usr/bin/env python3
"""OpenVINS's KLT tracker, as its OpenCV calls, timed on frames the SITL renders.

Why this exists: issue 22 asks how the front-end's speed compares with
OpenVINS's KLT tracker. OpenVINS itself needs ROS or its own C++ build with
OpenCV's headers, which this project's set-up does not install; what its
`TrackKLT::feed_monocular` spends its time in is OpenCV, so this replays that
function's OpenCV calls, in its order and with its default settings
(`config/euroc_mav/estimator_config.yaml`, `TrackKLT.h`), on the same frames
the front-end's bench tracks:

- `equalizeHist` (histogram_method HISTOGRAM);
- `buildOpticalFlowPyramid`, 15x15 window, 5 levels;
- the top-up: FAST (threshold 20, non-max suppression) in the cells of a 5x5
  grid that hold fewer than half their share, at most share + 1 a cell, the
  best first, none within `min_px_dist` (10 px) of a feature, then
  `cornerSubPix` (5x5, 20 iterations, 0.001);
- `calcOpticalFlowPyrLK` from the last frame's pyramid, initial flow, 30
  iterations or 0.01 px, no backward check;
- `undistortPoints` and `findFundamentalMat` (RANSAC, 2 px over the focal
  length, 0.999).

OpenCV runs on one thread (`setNumThreads(1)`), as the front-end's bench
does. Two figures are printed: the time inside OpenCV's calls alone (what the
C++ tracker spends, less its bookkeeping) and the whole loop, Python's
bookkeeping included (an upper bound). OpenCV's Python binding takes images,
not pyramids, so `calcOpticalFlowPyrLK` builds both pyramids again inside the
call, which OpenVINS does not: that work is timed on its own and taken off
both figures. Usage:

    pip install opencv-python-headless numpy
    printf '[camera]\nrate_hz = 20.0\n' > /tmp/sim-20hz.toml
    cargo run --release -p cmsckf-sitl -- render --scenario racetrack --duration-s 20 \
        --config /tmp/sim-20hz.toml --out /tmp/race20
    python3 scripts/openvins_klt_timing.py /tmp/race20 --from-s 10 --features 150
"""

import argparse
import pathlib
import time

import cv2
import numpy as np

# The camera the SITL renders with (models/src/sensors.rs: CameraConfig's
# default, EuRoC cam0's): pinhole with radial-tangential distortion.
K = np.array([[458.654, 0.0, 367.215], [0.0, 457.296, 248.375], [0.0, 0.0, 1.0]])
D = np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05])


class Clock:
    """Sums the time spent inside OpenCV's calls."""

    def __init__(self):
        self.inside_s = 0.0
        self.by_call = {}

    def __call__(self, f, *args, **kw):
        t0 = time.perf_counter()
        out = f(*args, **kw)
        dt = time.perf_counter() - t0
        self.inside_s += dt
        self.by_call[f.__name__] = self.by_call.get(f.__name__, 0.0) + dt
        return out


def detect(clock, img, pts, n_features, fast_threshold=20, grid=(5, 5), min_px_dist=10):
    """OpenVINS's perform_detection_monocular: the features kept (bounds,
    one per min_px_dist cell) and new FAST corners in the needy cells."""
    h, w = img.shape
    close = np.zeros((h // min_px_dist, w // min_px_dist), np.uint8)
    cells = np.zeros((grid[1], grid[0]), np.int32)
    size_x, size_y = w / grid[0], h / grid[1]
    mask = np.zeros_like(img)
    kept = []
    edge = 10
    for p in pts:
        x, y = int(p[0]), int(p[1])
        if x < edge or x >= w - edge or y < edge or y >= h - edge:
            continue
        xc, yc = int(p[0] / min_px_dist), int(p[1] / min_px_dist)
        if xc >= close.shape[1] or yc >= close.shape[0] or close[yc, xc]:
            continue
        close[yc, xc] = 1
        cells[int(p[1] / size_y), int(p[0] / size_x)] += 1
        if x - min_px_dist >= 0 and x + min_px_dist < w and y - min_px_dist >= 0 and y + min_px_dist < h:
            mask[y - min_px_dist : y + min_px_dist + 1, x - min_px_dist : x + min_px_dist + 1] = 255
        kept.append(p)
    needed = n_features - len(kept)
    if needed < min(20, int(0.5 * n_features)):
        return kept
    per_cell = int(n_features / (grid[0] * grid[1])) + 1
    required = max(1, int(0.5 * per_cell))
    cw, ch = w // grid[0], h // grid[1]
    fast = cv2.FastFeatureDetector_create(fast_threshold, True)
    new = []
    for gx in range(grid[0]):
        for gy in range(grid[1]):
            if cells[gy, gx] >= required:
                continue
            x0, y0 = gx * cw, gy * ch
            kps = clock(fast.detect, img[y0 : y0 + ch, x0 : x0 + cw])
            kps = sorted(kps, key=lambda k: -k.response)[:per_cell]
            for k in kps:
                x, y = k.pt[0] + x0, k.pt[1] + y0
                if mask[int(y), int(x)] > 127:
                    continue
                new.append((x, y))
    if new:
        refined = np.array(new, np.float32).reshape(-1, 1, 2)
        crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 20, 0.001)
        refined = clock(cv2.cornerSubPix, img, refined, (5, 5), (-1, -1), crit)
        for q in refined.reshape(-1, 2):
            xc, yc = int(q[0] / min_px_dist), int(q[1] / min_px_dist)
            if xc < 0 or yc < 0 or xc >= close.shape[1] or yc >= close.shape[0] or close[yc, xc]:
                continue
            close[yc, xc] = 1
            kept.append((float(q[0]), float(q[1])))
    return kept


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("frames", type=pathlib.Path, help="a folder of <t_us>.pgm frames (cmsckf-sitl render --out)")
    ap.add_argument("--from-s", type=float, default=0.0, help="skip the frames before this time (s)")
    ap.add_argument("--features", type=int, default=150, help="num_pts (OpenVINS's default is 200)")
    ap.add_argument("--passes", type=int, default=3, help="times the sequence is tracked (the first is a warm-up)")
    a = ap.parse_args()
    cv2.setNumThreads(1)
    files = sorted(a.frames.glob("*.pgm"))
    frames = [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files if int(f.stem) >= a.from_s * 1e6]
    if len(frames) < 2:
        raise SystemExit(f"{a.frames}: fewer than two frames")
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
    thr = 2.0 / max(K[0, 0], K[1, 1])
    results = []
    for _ in range(a.passes):
        clock = Clock()
        pts, last_pyr, tracked, rebuilt_s = [], None, 0, 0.0
        t0 = time.perf_counter()
        for img in frames:
            eq = clock(cv2.equalizeHist, img)
            _, pyr = clock(cv2.buildOpticalFlowPyramid, eq, (15, 15), 5)
            if last_pyr is None or not pts:
                pts = detect(clock, eq, [], a.features)
                last_pyr = pyr
                continue
            pts = detect(clock, last_pyr[0], pts, a.features)
            if len(pts) < 10:
                pts, last_pyr = [], pyr
                continue
            p0 = np.array(pts, np.float32).reshape(-1, 1, 2)
            p1, st, _ = clock(
                cv2.calcOpticalFlowPyrLK, last_pyr[0], pyr[0], p0, p0.copy(),
                winSize=(15, 15), maxLevel=5, criteria=crit, flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
            )
            # OpenVINS passes both pyramids to calcOpticalFlowPyrLK; the
            # Python binding takes images only, so OpenCV builds them again
            # inside the call (the last frame's with its derivatives). That
            # work, timed on its own, is taken off the figure below.
            t_re = time.perf_counter()
            cv2.buildOpticalFlowPyramid(last_pyr[0], (15, 15), 5, withDerivatives=True)
            cv2.buildOpticalFlowPyramid(pyr[0], (15, 15), 5, withDerivatives=False)
            rebuilt_s += time.perf_counter() - t_re
            n0 = clock(cv2.undistortPoints, p0, K, D)
            n1 = clock(cv2.undistortPoints, p1, K, D)
            _, inl = clock(cv2.findFundamentalMat, n0, n1, cv2.FM_RANSAC, thr, 0.999)
            ok = st.ravel().astype(bool)
            if inl is not None:
                ok &= inl.ravel().astype(bool)
            h, w = img.shape
            q = p1.reshape(-1, 2)
            ok &= (q[:, 0] >= 0) & (q[:, 1] >= 0) & (q[:, 0] < w) & (q[:, 1] < h)
            pts = [tuple(map(float, v)) for v in q[ok]]
            tracked += len(pts)
            last_pyr = pyr
        total = time.perf_counter() - t0 - rebuilt_s
        results.append((total, clock, tracked, rebuilt_s))
    n = len(frames)
    for k, (total, clock, tracked, rebuilt_s) in enumerate(results[1:], 1):
        parts = ", ".join(f"{name} {1e3 * t / n:.2f}" for name, t in sorted(clock.by_call.items(), key=lambda x: -x[1]))
        print(
            f"pass {k}: {n} frames of {frames[0].shape[1]}x{frames[0].shape[0]}, num_pts {a.features}: "
            f"{1e3 * (clock.inside_s - rebuilt_s) / n:.2f} ms a frame inside OpenCV as OpenVINS calls it "
            f"({1e3 * clock.inside_s / n:.2f} ms: {parts}; less {1e3 * rebuilt_s / n:.2f} ms of the pyramids "
            f"calcOpticalFlowPyrLK builds again from images), "
            f"{1e3 * total / n:.2f} ms with the Python loop; {tracked / (n - 1):.0f} tracked a frame"
        )


if __name__ == "__main__":
    main()
