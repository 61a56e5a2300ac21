#!/usr/bin/env python3
"""Regenerates the OpenCV reference values in `camera_opencv.rs`.

Run from anywhere:

    python3 -m pip install opencv-python-headless numpy
    python3 models/tests/camera_opencv_values.py

It prints the Rust constants (the blocks between the `// --- generated` lines
of camera_opencv.rs) to stdout and checks them first; paste them over the old
ones. The numbers in camera_opencv.rs were produced by

    Python 3.11.7, numpy 2.4.6,
    opencv-python-headless 5.0.0.93 (cv2.__version__ == "5.0.0")

Everything OpenCV computes here is double precision (CV_64F input in, CV_64F
out), so the values are the library's own result, not a rounding of it.

What each block is:

* projections: cv2.projectPoints (radtan, distCoeffs = [k1, k2, p1, p2, 0])
  and cv2.fisheye.projectPoints (equidistant, D = [k1, k2, k3, k4]), with
  rvec = tvec = 0 so the 3-D point is already in the camera frame;
  - `uv`: the distorted pixel, with the camera's K;
  - `xd`: the distorted normalised point, the same call with K = identity;
  - `duv_dxn`: d(pixel)/d(x/z, y/z), OpenCV's analytic Jacobian: the point
    (x/z, y/z, 1) projected with its d(pixel)/d(tvec) output; with rvec = 0 and
    depth 1, d/dtvec_x = d/dX = d/d(x/z). Checked against central differences
    of cv2's own projections below.
* undistortions: cv2.undistortPoints / cv2.fisheye.undistortPoints with no R
  or P (output in normalised coordinates) and criteria
  (COUNT | EPS, 100 iterations, 1e-14), checked by re-projecting.
"""

import math
import sys

import cv2
import numpy as np

CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
ZERO3 = np.zeros(3)


def kmat(fx, fy, cx, cy):
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


class Radtan:
    def __init__(self, intr, dist):
        self.intr, self.dist = intr, dist
        self.K = kmat(*intr)
        self.D = np.array(list(dist) + [0.0])  # k3 = 0

    def project(self, pts, K=None):
        img, jac = cv2.projectPoints(np.asarray(pts, float).reshape(-1, 1, 3), ZERO3, ZERO3,
                                     self.K if K is None else K, self.D)
        return img.reshape(-1, 2), jac

    def dpix_dt(self, jac):
        # Columns: rvec(3), tvec(3), f(2), c(2), dist(5).
        return jac[:, 3:6]

    def undistort(self, px):
        out = cv2.undistortPoints(np.asarray(px, float).reshape(-1, 1, 2), self.K, self.D, criteria=CRITERIA)
        return out.reshape(-1, 2)

    def formula(self, xn):
        k1, k2, p1, p2 = self.dist
        x, y = xn
        r2 = x * x + y * y
        radial = 1.0 + k1 * r2 + k2 * r2 * r2
        return (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


class Equidistant:
    def __init__(self, intr, dist):
        self.intr, self.dist = intr, dist
        self.K = kmat(*intr)
        self.D = np.array(dist)

    def project(self, pts, K=None):
        img, jac = cv2.fisheye.projectPoints(np.asarray(pts, float).reshape(-1, 1, 3), ZERO3, ZERO3,
                                             self.K if K is None else K, self.D)
        return img.reshape(-1, 2), jac

    def dpix_dt(self, jac):
        # Columns: f(2), c(2), k(4), rvec(3), tvec(3), alpha(1).
        return jac[:, 11:14]

    def undistort(self, px):
        out = cv2.fisheye.undistortPoints(np.asarray(px, float).reshape(-1, 1, 2), self.K, self.D,
                                          criteria=CRITERIA)
        return out.reshape(-1, 2)

    def formula(self, xn):
        k1, k2, k3, k4 = self.dist
        r = math.hypot(*xn)
        if r < 1e-12:
            return tuple(xn)
        th = math.atan(r)
        t2 = th * th
        thd = th * (1.0 + k1 * t2 + k2 * t2 ** 2 + k3 * t2 ** 3 + k4 * t2 ** 4)
        return (xn[0] * thd / r, xn[1] * thd / r)


def to_pixel(cam, xd):
    fx, fy, cx, cy = cam.intr
    return (fx * xd[0] + cx, fy * xd[1] + cy)


def check(cond, what):
    if not cond:
        sys.exit("check failed: " + what)


def projections(cam, pts):
    """Rows (p_in_C, uv, xd, duv_dxn) with every value checked."""
    uv, _ = cam.project(pts)
    xd, _ = cam.project(pts, K=np.eye(3))
    rows = []
    for i, p in enumerate(pts):
        xn = (p[0] / p[2], p[1] / p[2])
        # Analytic Jacobian at (x/z, y/z, 1).
        _, jac = cam.project([[xn[0], xn[1], 1.0]])
        J = cam.dpix_dt(jac)[:, 0:2]
        # Central differences of OpenCV's own projections agree with it.
        h = 1e-6
        Jfd = np.zeros((2, 2))
        for k in range(2):
            a, b = list(xn) + [1.0], list(xn) + [1.0]
            a[k] += h
            b[k] -= h
            Jfd[:, k] = (cam.project([a])[0][0] - cam.project([b])[0][0]) / (2 * h)
        rel = np.abs(J - Jfd).max() / np.abs(J).max()
        check(rel < 1e-7, f"jacobian vs central differences at {p}: {rel}")
        # The documented formula (plain float arithmetic) reproduces OpenCV.
        f = cam.formula(xn)
        check(max(abs(f[0] - xd[i][0]), abs(f[1] - xd[i][1])) < 1e-14, f"formula xd at {p}")
        pix = to_pixel(cam, f)
        check(max(abs(pix[0] - uv[i][0]), abs(pix[1] - uv[i][1])) < 1e-11, f"formula uv at {p}")
        rows.append((list(p), list(uv[i]), list(xd[i]), J.tolist()))
    return rows


def undistortions(cam, pixels):
    """Rows (pixel, xn): OpenCV's undistortion, re-projected to within 1e-12 px."""
    xn = cam.undistort(pixels)
    back, _ = cam.project(np.hstack([xn, np.ones((len(xn), 1))]))
    err = np.abs(back - np.asarray(pixels)).max()
    check(err < 1e-12, f"re-projection of undistorted points: {err} px")
    return [(list(p), list(x)) for p, x in zip(pixels, xn)]


def f(v):
    """A Rust f64 literal that round-trips (Python's shortest repr)."""
    s = repr(float(v))
    check(float(s) == v, s)
    return s


def arr(vs):
    return "[" + ", ".join(f(v) for v in vs) + "]"


def emit_proj(name, rows):
    print("#[rustfmt::skip]")
    print(f"const {name}: [ProjCase; {len(rows)}] = [")
    for p, uv, xd, J in rows:
        print("    ProjCase {")
        print(f"        p_in_C: {arr(p)},")
        print(f"        uv: {arr(uv)},")
        print(f"        xd: {arr(xd)},")
        print(f"        duv_dxn: [{arr(J[0])}, {arr(J[1])}],")
        print("    },")
    print("];")


def emit_undist(name, rows):
    print("#[rustfmt::skip]")
    print(f"const {name}: [UndistCase; {len(rows)}] = [")
    for px, xn in rows:
        print(f"    UndistCase {{ uv: {arr(px)}, xn: {arr(xn)} }},")
    print("];")


def at_angle(deg, azimuth_deg, z):
    t = math.tan(math.radians(deg))
    a = math.radians(azimuth_deg)
    return [z * t * math.cos(a), z * t * math.sin(a), z]


EUROC_INTR = [458.654, 457.296, 367.215, 248.375]
EUROC_DIST = [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
TANGENTIAL_DIST = [-0.28340811, 0.07395907, 0.01, -0.005]
TUMVI_INTR = [190.978, 190.973, 254.932, 256.897]
TUMVI_DIST = [0.00348, 0.000715, -0.00205, 0.000203]

RADTAN_POINTS = [
    [0.0, 0.0, 2.0],  # on the axis
    [0.4, 0.25, 1.6],  # right, down (+x, +y)
    [-0.9, 0.5, 3.0],  # left, down
    [-0.35, -0.42, 1.2],  # left, up
    [1.1, -0.6, 2.5],  # right, up
    [2.2, 1.36, 2.0],  # wide: 52 deg off axis, 15 px left of and 3.5 px above the bottom-right corner
]
EQUI_POINTS = RADTAN_POINTS[:5] + [
    at_angle(40.0, 30.0, 1.5),
    at_angle(55.0, 135.0, 0.8),
    at_angle(62.0, 250.0, 2.0),
    at_angle(70.0, -20.0, 1.0),
    [1.0, -0.75, 1.0],  # r = 1.25 (51.3 deg): the case worked by hand in the test
]
# 75 deg off axis: x/z = 3.73, beyond the project's |x/z| <= 3 cut-off in
# `project`, but `distort` is defined there and OpenCV projects it.
EQUI_BEYOND_CUTOFF = [at_angle(75.0, 60.0, 1.0)]

RADTAN_PIXELS = [[367.215, 248.375], [100.5, 50.25], [700.0, 400.0], [0.0, 0.0], [751.0, 479.0],
                 [20.0, 470.0], [740.0, 10.0]]
EQUI_PIXELS = [[254.932, 256.897], [300.0, 280.0], [100.25, 400.5], [30.0, 256.0], [420.0, 100.0]]
# About 83 deg off axis (|x/z| = 8.6 and 8.8), near where the lens model ends.
EQUI_PIXELS_WIDE = [[470.5, 430.0], [60.0, 60.0]]


def main():
    euroc = Radtan(EUROC_INTR, EUROC_DIST)
    tang = Radtan(EUROC_INTR, TANGENTIAL_DIST)
    equi = Equidistant(TUMVI_INTR, TUMVI_DIST)

    r_a = projections(euroc, RADTAN_POINTS)
    r_b = projections(tang, RADTAN_POINTS)
    e_p = projections(equi, EQUI_POINTS)
    e_x = projections(equi, EQUI_BEYOND_CUTOFF)
    check(0 <= r_a[-1][1][0] < 752 and 0 <= r_a[-1][1][1] < 480, "wide radtan point in the image")
    for rows in (e_p, e_x):
        for r in rows:
            check(0 <= r[1][0] < 512 and 0 <= r[1][1] < 512, f"equidistant point {r[0]} in the image")
    u_a = undistortions(euroc, RADTAN_PIXELS)
    u_b = undistortions(tang, RADTAN_PIXELS)
    u_e = undistortions(equi, EQUI_PIXELS)
    u_w = undistortions(equi, EQUI_PIXELS_WIDE)
    # A swapped p1/p2 must move the pixels by far more than the tolerance.
    swapped = Radtan(EUROC_INTR, [TANGENTIAL_DIST[0], TANGENTIAL_DIST[1], TANGENTIAL_DIST[3], TANGENTIAL_DIST[2]])
    moved = np.abs(swapped.project(RADTAN_POINTS)[0] - np.array([r[1] for r in r_b]))[1:].max(axis=1)
    check(moved.min() > 0.1, f"swapped p1/p2 moves each off-axis pixel: {moved}")

    print(f"// --- generated by camera_opencv_values.py (OpenCV {cv2.__version__}, numpy {np.__version__})")
    emit_proj("RADTAN_EUROC_PROJ", r_a)
    emit_proj("RADTAN_TANGENTIAL_PROJ", r_b)
    emit_proj("EQUI_PROJ", e_p)
    emit_proj("EQUI_PROJ_BEYOND_CUTOFF", e_x)
    emit_undist("RADTAN_EUROC_UNDIST", u_a)
    emit_undist("RADTAN_TANGENTIAL_UNDIST", u_b)
    emit_undist("EQUI_UNDIST", u_e)
    emit_undist("EQUI_UNDIST_WIDE", u_w)
    print("// --- end generated")
    print(f"swapped p1/p2 moves the off-axis pixels by {moved.min():.3f}..{moved.max():.3f} px", file=sys.stderr)


if __name__ == "__main__":
    main()
