//! The camera model checked against OpenCV.
//!
//! OpenCV is the reference implementation of both lens models the project
//! supports: `cv::projectPoints` of the radial-tangential ("plumb bob") model
//! and `cv::fisheye::projectPoints` of the equidistant (Kannala–Brandt) model,
//! the ones Kalibr, EuRoC and TUM-VI calibrations are written for. The
//! project's own unit tests only check the camera against itself (undistort
//! inverts distort); these tests check it against an independent
//! implementation, so a wrong coefficient order, a swapped p1/p2 or a wrong
//! power of θ fails here even though it would round-trip.
//!
//! Every expected value below was computed by OpenCV 5.0.0
//! (opencv-python-headless 5.0.0.93, numpy 2.4.6, Python 3.11.7), in double
//! precision, by `camera_opencv_values.py` next to this file, which also
//! documents each call and checks the values before printing them. Run it to
//! regenerate the block between the `// --- generated` lines.
//!
//! Tolerances, and why:
//! * pixels: 1e-9 px. OpenCV and the project evaluate the same double-precision
//!   formula, in a slightly different order, so they differ only by rounding
//!   (at most 6e-14 px on these cases with the camera code the project had
//!   when this was written); a real modelling difference is far
//!   larger (swapping p1 and p2 of the tangential set moves every off-axis
//!   pixel here by 0.9 px or more, and the small EuRoC p1 and p2 alone move
//!   these pixels by 0.013 to 0.24 px).
//! * distorted normalised coordinates: 1e-12 (values are below 1.2; rounding
//!   is about 2e-16).
//! * undistortion: 1e-10 in normalised coordinates. OpenCV, asked for 100
//!   iterations and 1e-14, re-projects its answers to within 1.2e-13 px; the
//!   project's Gauss–Newton stops when the residual in distorted normalised
//!   coordinates is below 1e-13, which near 83° off axis (|x/z| ≈ 8.7, where
//!   dx/dx_d ≈ 70) still allows 7e-12. Both agree to 2e-14 today.
//! * `pixel_jacobian`: 1e-5 relative to the largest entry. The reference is
//!   OpenCV's analytic Jacobian; the project's is numeric (central differences
//!   with a 1e-7 step today, 2e-9 relative error on these cases), so the
//!   bound leaves room for a different step or a one-sided difference while
//!   still catching a wrong formula (swapping p1 and p2 of the tangential
//!   set changes the Jacobians by 2e-2 to 1e-1 of their largest entry).

#![allow(non_snake_case)]

use cmsckf_models::camera::Camera;
use cmsckf_models::sensors::{CameraConfig, CameraModelKind};
use nalgebra::{Matrix2, Vector2, Vector3};

const PIXEL_TOL: f64 = 1e-9;
const DISTORT_TOL: f64 = 1e-12;
const UNDISTORT_TOL: f64 = 1e-10;
const JACOBIAN_REL_TOL: f64 = 1e-5;

/// EuRoC cam0, the project's default camera: `[fx, fy, cx, cy]`, 752 × 480.
const EUROC_INTRINSICS: [f64; 4] = [458.654, 457.296, 367.215, 248.375];
/// EuRoC cam0 radtan `[k1, k2, p1, p2]` (OpenCV `distCoeffs = [k1, k2, p1, p2, k3 = 0]`).
const EUROC_DISTORTION: [f64; 4] = [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05];
/// The EuRoC radial terms with large, unequal tangential terms
/// (p1 = 0.01, p2 = -0.005), so that a swapped p1/p2 cannot pass.
const TANGENTIAL_DISTORTION: [f64; 4] = [-0.28340811, 0.07395907, 0.01, -0.005];
/// A TUM-VI-like fisheye: `[fx, fy, cx, cy]`, 512 × 512.
const TUMVI_INTRINSICS: [f64; 4] = [190.978, 190.973, 254.932, 256.897];
/// Equidistant `[k1, k2, k3, k4]` (OpenCV `cv::fisheye` `D`).
const TUMVI_DISTORTION: [f64; 4] = [0.00348, 0.000715, -0.00205, 0.000203];

/// One 3-D point in the camera frame and what OpenCV makes of it.
struct ProjCase {
    /// The point, camera frame (z forward).
    p_in_C: [f64; 3],
    /// Distorted pixel `[u, v]`.
    uv: [f64; 2],
    /// Distorted normalised coordinates `[x_d, y_d]` (the same call with K = I).
    xd: [f64; 2],
    /// d(pixel)/d(x/z, y/z), rows u, v; OpenCV's analytic Jacobian.
    duv_dxn: [[f64; 2]; 2],
}

/// One pixel and OpenCV's undistorted normalised coordinates for it.
struct UndistCase {
    uv: [f64; 2],
    xn: [f64; 2],
}

fn camera(model: CameraModelKind, intrinsics: [f64; 4], distortion: [f64; 4], size_px: [u32; 2]) -> Camera {
    Camera::from_config(&CameraConfig {
        model,
        width_px: size_px[0],
        height_px: size_px[1],
        intrinsics,
        distortion,
        ..Default::default()
    })
}

fn euroc() -> Camera {
    camera(
        CameraModelKind::PinholeRadtan,
        EUROC_INTRINSICS,
        EUROC_DISTORTION,
        [752, 480],
    )
}

fn tangential() -> Camera {
    camera(
        CameraModelKind::PinholeRadtan,
        EUROC_INTRINSICS,
        TANGENTIAL_DISTORTION,
        [752, 480],
    )
}

fn tumvi() -> Camera {
    camera(
        CameraModelKind::PinholeEquidistant,
        TUMVI_INTRINSICS,
        TUMVI_DISTORTION,
        [512, 512],
    )
}

/// `(x/z, y/z)`, computed as OpenCV computes it.
fn normalised(p: [f64; 3]) -> Vector2<f64> {
    Vector2::new(p[0] / p[2], p[1] / p[2])
}

fn assert_close(got: &Vector2<f64>, want: [f64; 2], tol: f64, what: &str) {
    let err = (got.x - want[0]).abs().max((got.y - want[1]).abs());
    assert!(
        err <= tol,
        "{what}: got [{}, {}], OpenCV [{}, {}], off by {err:e} > {tol:e}",
        got.x,
        got.y,
        want[0],
        want[1]
    );
}

/// `project`, `distort` and `pixel_jacobian` against one table.
fn check_projections(cam: &Camera, cases: &[ProjCase], what: &str) {
    for c in cases {
        let p = Vector3::from(c.p_in_C);
        let xn = normalised(c.p_in_C);
        let uv = cam.project(&p).unwrap_or_else(|| panic!("{what}: {p:?} not projected"));
        assert_close(&uv, c.uv, PIXEL_TOL, &format!("{what}: project {:?}", c.p_in_C));
        assert_close(
            &cam.distort(&xn),
            c.xd,
            DISTORT_TOL,
            &format!("{what}: distort {:?}", c.p_in_C),
        );
        check_jacobian(cam, c, what);
    }
}

fn check_jacobian(cam: &Camera, c: &ProjCase, what: &str) {
    let j = &c.duv_dxn;
    let want = Matrix2::new(j[0][0], j[0][1], j[1][0], j[1][1]);
    let got = cam.pixel_jacobian(&normalised(c.p_in_C));
    let err = (got - want).amax();
    assert!(
        err <= JACOBIAN_REL_TOL * want.amax(),
        "{what}: pixel_jacobian at {:?}: got {got}, OpenCV {want}, off by {err:e}",
        c.p_in_C
    );
}

/// `undistort` against one table, and the answer re-projected.
fn check_undistortions(cam: &Camera, cases: &[UndistCase], what: &str) {
    for c in cases {
        let uv = Vector2::from(c.uv);
        let xn = cam
            .undistort(&uv)
            .unwrap_or_else(|| panic!("{what}: undistort {:?} gave None", c.uv));
        assert_close(&xn, c.xn, UNDISTORT_TOL, &format!("{what}: undistort {:?}", c.uv));
        let back = cam.project(&Vector3::new(xn.x, xn.y, 1.0)).expect("re-projects");
        assert_close(&back, c.uv, PIXEL_TOL, &format!("{what}: re-projection of {:?}", c.uv));
    }
}

// Reference values.
//
// Radtan tables: cv2.projectPoints(points, rvec = 0, tvec = 0, K,
// distCoeffs = [k1, k2, p1, p2, 0]) (OpenCV 5.0.0), which computes, with
// x = X/Z, y = Y/Z, r² = x² + y²:
//     x_d = x (1 + k1 r² + k2 r⁴) + 2 p1 x y + p2 (r² + 2 x²)
//     y_d = y (1 + k1 r² + k2 r⁴) + p1 (r² + 2 y²) + 2 p2 x y
//     u = fx x_d + cx,  v = fy y_d + cy
// `xd` is the same call with K = identity; `duv_dxn` is columns 3 and 4
// (d/dtvec_x, d/dtvec_y) of its `jacobian` output for the point (x, y, 1),
// which at rvec = 0 and depth 1 is d(u, v)/d(x, y).
// Points: on the axis, one in each image quadrant, and one wide point
// (x = 1.1, y = 0.68, about 52° off axis) 15 px left and 3.5 px above the
// bottom-right corner of the 752 × 480 image.
//
// Equidistant tables: cv2.fisheye.projectPoints(points, rvec = 0, tvec = 0, K,
// D = [k1, k2, k3, k4]) (OpenCV 5.0.0, skew alpha = 0), which computes, with
// r = √(x² + y²):
//     θ = atan r,  θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)
//     x_d = (θ_d / r) x,  y_d = (θ_d / r) y      (x_d = x when r ≤ 1e-8)
//     u = fx x_d + cx,  v = fy y_d + cy
// `duv_dxn` is columns 11 and 12 (d/dtvec_x, d/dtvec_y) of its 2N × 15
// `jacobian` output for (x, y, 1). Points: the radtan ones, then 40°, 55°,
// 62° and 70° off axis at several azimuths, then 51.3° (the case worked by
// hand below); and, apart, one 75° off axis (x/z = 3.73), beyond `project`'s
// |x/z| ≤ 3.
//
// Undistortion tables: cv2.undistortPoints(pixels, K, [k1, k2, p1, p2, 0],
// criteria = (COUNT | EPS, 100, 1e-14)) and cv2.fisheye.undistortPoints(pixels,
// K, D, criteria = (COUNT | EPS, 100, 1e-14)), no R or P, so the output is
// normalised (x, y) with (x, y, 1) projecting to the pixel; each was
// re-projected by OpenCV to within 1.2e-13 px. (OpenCV's radtan default is
// only 5 fixed-point iterations, which is off by up to 1e-3 here; hence the
// explicit criteria.) Radtan pixels include the image corners; the
// equidistant ones reach 68° off axis, and EQUI_UNDIST_WIDE about 83°.
//
// All Jacobians were also checked in the script against central differences
// of OpenCV's own projections (step 1e-6, agreement better than 1e-7
// relative).

// --- generated by camera_opencv_values.py (OpenCV 5.0.0, numpy 2.4.6)
#[rustfmt::skip]
const RADTAN_EUROC_PROJ: [ProjCase; 6] = [
    ProjCase {
        p_in_C: [0.0, 0.0, 2.0],
        uv: [367.215, 248.375],
        xd: [0.0, 0.0],
        duv_dxn: [[458.654, 0.0], [0.0, 457.296]],
    },
    ProjCase {
        p_in_C: [0.4, 0.25, 1.6],
        uv: [479.12680213111105, 318.1200375709614],
        xd: [0.24400049303202653, 0.1525161767672611],
        duv_dxn: [[432.1412636553624, -9.64758955015904], [-9.619024604450257, 440.3331977665703]],
    },
    ProjCase {
        p_in_C: [-0.9, 0.5, 3.0],
        uv: [234.06401098962806, 322.1397041174593],
        xd: [-0.2903081386194646, 0.16130625266230034],
        duv_dxn: [[421.8708548986059, 12.149002780513333], [12.113031556505831, 435.8272043315203]],
    },
    ProjCase {
        p_in_C: [-0.35, -0.42, 1.2],
        uv: [240.9053314134153, 97.26854543023939],
        xd: [-0.2753920571641906, -0.3304346737556432],
        duv_dxn: [[413.3382529657534, -23.721200590067866], [-23.650965967887934, 403.3488684617824]],
    },
    ProjCase {
        p_in_C: [1.1, -0.6, 2.5],
        uv: [555.5838659524676, 145.95590416662864],
        xd: [0.41069927647522453, -0.22396674327650223],
        duv_dxn: [[384.38873571048026, 23.928038293678767], [23.857191258652765, 413.78127559347877]],
    },
    ProjCase {
        p_in_C: [2.2, 1.36, 2.0],
        uv: [737.1361108863407, 476.51614944215],
        xd: [0.8065363234297329, 0.49889163570674133],
        duv_dxn: [[296.32416219117835, -24.51539584056547], [-24.442809735240992, 320.28748743058935]],
    },
];
#[rustfmt::skip]
const RADTAN_TANGENTIAL_PROJ: [ProjCase; 6] = [
    ProjCase {
        p_in_C: [0.0, 0.0, 2.0],
        uv: [367.215, 248.375],
        xd: [0.0, 0.0],
        duv_dxn: [[458.654, 0.0], [0.0, 457.296]],
    },
    ProjCase {
        p_in_C: [0.4, 0.25, 1.6],
        uv: [478.99050016832564, 318.54950348899183],
        xd: [0.24370331484806776, 0.15345531885035482],
        duv_dxn: [[430.09478393296854, -8.117887117982308], [-8.093851372722876, 443.3900843465962]],
    },
    ProjCase {
        p_in_C: [-0.9, 0.5, 3.0],
        uv: [232.92894491777088, 323.14645937242653],
        xd: [-0.2927829149690815, 0.16350779226677367],
        duv_dxn: [[427.5125362290778, 8.683236313076515], [8.657526660673705, 441.68835857862933]],
    },
    ProjCase {
        p_in_C: [-0.35, -0.42, 1.2],
        uv: [240.95438245938823, 98.82959439567097],
        xd: [-0.275285111523309, -0.3270210227168596],
        duv_dxn: [[414.2171926070577, -24.733941982428615], [-24.660708797474072, 395.2700410173046]],
    },
    ProjCase {
        p_in_C: [1.1, -0.6, 2.5],
        uv: [553.1647589175661, 148.08360628338102],
        xd: [0.4054249148978668, -0.21931395358065456],
        duv_dxn: [[376.15424975176273, 28.990705993542026], [28.904869221728784, 405.30450088618176]],
    },
    ProjCase {
        p_in_C: [2.2, 1.36, 2.0],
        uv: [734.4466952555651, 484.7304891059898],
        xd: [0.8006726099751995, 0.5168544861664869],
        duv_dxn: [[287.25218517506295, -17.750184875600972], [-17.697629461146782, 333.53598893967177]],
    },
];
#[rustfmt::skip]
const EQUI_PROJ: [ProjCase; 10] = [
    ProjCase {
        p_in_C: [0.0, 0.0, 2.0],
        uv: [254.932, 256.897],
        xd: [0.0, 0.0],
        duv_dxn: [[190.978, 0.0], [0.0, 190.973]],
    },
    ProjCase {
        p_in_C: [0.4, 0.25, 1.6],
        uv: [301.3746664345821, 285.9229065737004],
        xd: [0.243183332292631, 0.15198958268289436],
        duv_dxn: [[178.64407575849862, -4.454118737393579], [-4.454002123994718, 182.98205074418578]],
    },
    ProjCase {
        p_in_C: [-0.9, 0.5, 3.0],
        uv: [199.71988432398746, 287.56959453676205],
        xd: [-0.28910196816393796, 0.16061220453552108],
        duv_dxn: [[174.11694603231692, 5.513021974661994], [5.5128776380898525, 180.97285742163362]],
    },
    ProjCase {
        p_in_C: [-0.35, -0.42, 1.2],
        uv: [202.63159335482177, 194.13815515975904],
        xd: [-0.27385566214526386, -0.32862679457431654],
        duv_dxn: [[170.76738452847536, -10.25795447741986], [-10.257685913646105, 167.001762161456]],
    },
    ProjCase {
        p_in_C: [1.1, -0.6, 2.5],
        uv: [332.8867942437106, 214.37731637788602],
        xd: [0.40818730033674366, -0.2226476183654965],
        duv_dxn: [[158.5297122340693, 10.167422554611742], [10.167156361056605, 171.61962677398947]],
    },
    ProjCase {
        p_in_C: [1.0900223953585162, 0.6293247233829599, 1.5],
        uv: [370.5866290852622, 323.6684830436935],
        xd: [0.605591372227493, 0.3496383417744579],
        duv_dxn: [[124.20957555308563, -20.175447926838196], [-20.17491971290971, 147.50231427320287]],
    },
    ProjCase {
        p_in_C: [-0.8078825120843203, 0.8078825120843204, 0.8],
        uv: [124.9957028910029, 386.82989524341286],
        xd: [-0.6803731168459041, 0.6803731168459042],
        duv_dxn: [[95.83541205798976, 32.833096211871535], [32.832236607723104, 95.8329029885666]],
    },
    ProjCase {
        p_in_C: [-1.2864926704682609, -3.534609562405425, 2.0],
        uv: [184.09911993118584, 62.29035659099921],
        xd: [-0.37089549617659706, -1.0190270007226192],
        duv_dxn: [[102.1481307983693, -21.896523651393377], [-21.895950377936455, 49.956301403151485]],
    },
    ProjCase {
        p_in_C: [2.581784256837418, -0.9396926207859081, 1.0],
        uv: [474.39887484456256, 177.01968147406632],
        xd: [1.1491735950976687, -0.41826498262023243],
        duv_dxn: [[29.372724229172512, 20.248817267308166], [20.24828713249507, 77.63389308917344]],
    },
    ProjCase {
        p_in_C: [1.0, -0.75, 1.0],
        uv: [392.14539997001873, 153.989644313189],
        xd: [0.7184775208140137, -0.5388581406105103],
        duv_dxn: [[97.28642445963789, 29.945231632785635], [29.944447635895074, 114.75147185549335]],
    },
];
#[rustfmt::skip]
const EQUI_PROJ_BEYOND_CUTOFF: [ProjCase; 1] = [
    ProjCase {
        p_in_C: [1.8660254037844393, 3.232050807568877, 1.0],
        uv: [379.8641826648302, 473.2802225928432],
        xd: [0.6541705466851168, 1.1330566236737298],
        duv_dxn: [[53.32175570018544, -23.60646549336875], [-23.605847451879846, 26.062674920324344]],
    },
];
#[rustfmt::skip]
const RADTAN_EUROC_UNDIST: [UndistCase; 7] = [
    UndistCase { uv: [367.215, 248.375], xn: [0.0, 0.0] },
    UndistCase { uv: [100.5, 50.25], xn: [-0.7049896308733502, -0.5254146418190828] },
    UndistCase { uv: [700.0, 400.0], xn: [0.9217182289268104, 0.42096251397739975] },
    UndistCase { uv: [0.0, 0.0], xn: [-1.0967458242338655, -0.7444513920192236] },
    UndistCase { uv: [751.0, 479.0], xn: [1.1462572782933311, 0.6904083637889364] },
    UndistCase { uv: [20.0, 470.0], xn: [-1.0172820439771368, 0.650851040005735] },
    UndistCase { uv: [740.0, 10.0], xn: [1.112845297876199, -0.7142055821271175] },
];
#[rustfmt::skip]
const RADTAN_TANGENTIAL_UNDIST: [UndistCase; 7] = [
    UndistCase { uv: [367.215, 248.375], xn: [0.0, 0.0] },
    UndistCase { uv: [100.5, 50.25], xn: [-0.7052628697657153, -0.5386477287515143] },
    UndistCase { uv: [700.0, 400.0], xn: [0.9310479509746562, 0.40927783899117565] },
    UndistCase { uv: [0.0, 0.0], xn: [-1.0918239704206811, -0.7737490796370613] },
    UndistCase { uv: [751.0, 479.0], xn: [1.1558270267365025, 0.6649973924710347] },
    UndistCase { uv: [20.0, 470.0], xn: [-0.9638735540695728, 0.605745183382971] },
    UndistCase { uv: [740.0, 10.0], xn: [1.172565686010537, -0.7710869712111156] },
];
#[rustfmt::skip]
const EQUI_UNDIST: [UndistCase; 5] = [
    UndistCase { uv: [254.932, 256.897], xn: [0.0, 0.0] },
    UndistCase { uv: [300.0, 280.0], xn: [0.24161459835480198, 0.12386101474843764] },
    UndistCase { uv: [100.25, 400.5], xn: [-1.450403545311673, 1.346554566817731] },
    UndistCase { uv: [30.0, 256.0], xn: [-2.400184742705423, -0.009571879868289314] },
    UndistCase { uv: [420.0, 100.0], xn: [1.8151713305762456, -1.7253640479820032] },
];
#[rustfmt::skip]
const EQUI_UNDIST_WIDE: [UndistCase; 2] = [
    UndistCase { uv: [470.5, 430.0], xn: [6.681093268317033, 5.365117121407268] },
    UndistCase { uv: [60.0, 60.0], xn: [-6.209472002737196, -6.2722304156060495] },
];
// --- end generated

#[test]
fn radtan_projection_matches_opencv() {
    check_projections(&euroc(), &RADTAN_EUROC_PROJ, "EuRoC radtan");
    check_projections(&tangential(), &RADTAN_TANGENTIAL_PROJ, "radtan, large p1/p2");
}

#[test]
fn equidistant_projection_matches_opencv() {
    check_projections(&tumvi(), &EQUI_PROJ, "equidistant");
}

#[test]
fn radtan_undistortion_matches_opencv() {
    check_undistortions(&euroc(), &RADTAN_EUROC_UNDIST, "EuRoC radtan");
    check_undistortions(&tangential(), &RADTAN_TANGENTIAL_UNDIST, "radtan, large p1/p2");
}

#[test]
fn equidistant_undistortion_matches_opencv() {
    check_undistortions(&tumvi(), &EQUI_UNDIST, "equidistant");
}

/// About 83° off axis (|x/z| ≈ 8.6 and 8.8): still inside the project's
/// undistortion, which gives up beyond |x/z| = 10 (84.3°); OpenCV goes on to
/// θ_d = π/2. `project` refuses these (|x/z| > 3), so the forward check is on
/// `distort`: the distorted normalised point of OpenCV's answer is the pixel's.
///
/// Not tested, for the record: this lens's θ_d peaks at about 1.555 rad (at
/// θ = 90°), so pixels further than about 297 px from the centre (the image
/// corners, say) have no pre-image. OpenCV (criteria as above) still returns
/// one, mirrored through the axis: pixel (500, 30), up and right, gives
/// (-45.1, 41.8), and (0, 0) gives (46.9, 47.3). The project's `undistort`
/// returns None there.
#[test]
fn equidistant_undistortion_matches_opencv_near_90_degrees() {
    let cam = tumvi();
    let [fx, fy, cx, cy] = TUMVI_INTRINSICS;
    for c in &EQUI_UNDIST_WIDE {
        let uv = Vector2::from(c.uv);
        let xn = cam
            .undistort(&uv)
            .unwrap_or_else(|| panic!("undistort {:?} gave None", c.uv));
        assert_close(
            &xn,
            c.xn,
            UNDISTORT_TOL,
            &format!("wide equidistant: undistort {:?}", c.uv),
        );
        let xd = [(c.uv[0] - cx) / fx, (c.uv[1] - cy) / fy];
        assert_close(
            &cam.distort(&Vector2::from(c.xn)),
            xd,
            DISTORT_TOL,
            "wide equidistant: distort",
        );
    }
}

/// The radtan formula worked through for one point, in plain arithmetic from
/// the coefficients, giving OpenCV's pixel; and the camera gives the same.
/// Uses the large tangential terms so both p1 and p2 visibly matter.
#[test]
fn radtan_case_worked_by_hand() {
    let [fx, fy, cx, cy] = EUROC_INTRINSICS;
    let [k1, k2, p1, p2] = TANGENTIAL_DISTORTION; // p1 = 0.01, p2 = -0.005
    let p_in_C: [f64; 3] = [0.4, 0.25, 1.6];
    let x = p_in_C[0] / p_in_C[2]; // 0.25
    let y = p_in_C[1] / p_in_C[2]; // 0.15625
    let r2 = x * x + y * y; // 0.0869140625
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2; // 0.975926540642271
    let dx_tangential = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x); // 0.00078125 - 0.0010595703125
    let dy_tangential = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y; // 0.001357421875 - 0.000390625
    assert!((dx_tangential - -0.0002783203125).abs() < 1e-15);
    assert!((dy_tangential - 0.000966796875).abs() < 1e-15);
    let x_d = x * radial + dx_tangential; // 0.24370331484806776
    let y_d = y * radial + dy_tangential; // 0.15345531885035482
    let by_hand = [fx * x_d + cx, fy * y_d + cy]; // [478.99050016832564, 318.54950348899183]

    let opencv = &RADTAN_TANGENTIAL_PROJ[1];
    assert_eq!(opencv.p_in_C, p_in_C);
    assert_close(
        &Vector2::from(by_hand),
        opencv.uv,
        PIXEL_TOL,
        "radtan by hand vs OpenCV",
    );
    assert_close(
        &Vector2::new(x_d, y_d),
        opencv.xd,
        DISTORT_TOL,
        "radtan x_d by hand vs OpenCV",
    );

    let uv = tangential().project(&Vector3::from(p_in_C)).unwrap();
    assert_close(&uv, by_hand, PIXEL_TOL, "radtan project vs by hand");
}

/// The equidistant formula worked through for one point 51.3° off axis.
#[test]
fn equidistant_case_worked_by_hand() {
    let [fx, fy, cx, cy] = TUMVI_INTRINSICS;
    let [k1, k2, k3, k4] = TUMVI_DISTORTION;
    let p_in_C: [f64; 3] = [1.0, -0.75, 1.0];
    let x = p_in_C[0] / p_in_C[2]; // 1
    let y = p_in_C[1] / p_in_C[2]; // -0.75
    let r = (x * x + y * y).sqrt(); // 1.25 exactly
    let theta = r.atan(); // 0.8960553845713439 rad = 51.34°
    let t2 = theta * theta;
    // 0.8980969010175173:
    let theta_d = theta * (1.0 + k1 * t2 + k2 * t2 * t2 + k3 * t2 * t2 * t2 + k4 * t2 * t2 * t2 * t2);
    let scale = theta_d / r; // 0.7184775208140138
    let (x_d, y_d) = (scale * x, scale * y); // (0.7184775208140138, -0.5388581406105104)
    let by_hand = [fx * x_d + cx, fy * y_d + cy]; // [392.14539997001873, 153.989644313189]

    let opencv = EQUI_PROJ
        .iter()
        .find(|c| c.p_in_C == p_in_C)
        .expect("in the OpenCV table");
    assert_close(
        &Vector2::from(by_hand),
        opencv.uv,
        PIXEL_TOL,
        "equidistant by hand vs OpenCV",
    );
    assert_close(
        &Vector2::new(x_d, y_d),
        opencv.xd,
        DISTORT_TOL,
        "equidistant x_d by hand vs OpenCV",
    );

    let uv = tumvi().project(&Vector3::from(p_in_C)).unwrap();
    assert_close(&uv, by_hand, PIXEL_TOL, "equidistant project vs by hand");
}

/// The tests above have teeth: the tangential set with p1 and p2 swapped
/// misses OpenCV's pixels by far more than the tolerance.
#[test]
fn swapped_tangential_terms_would_fail() {
    let [k1, k2, p1, p2] = TANGENTIAL_DISTORTION;
    let swapped = camera(
        CameraModelKind::PinholeRadtan,
        EUROC_INTRINSICS,
        [k1, k2, p2, p1],
        [752, 480],
    );
    for c in &RADTAN_TANGENTIAL_PROJ[1..] {
        let uv = swapped.project(&Vector3::from(c.p_in_C)).unwrap();
        let miss = (uv.x - c.uv[0]).abs().max((uv.y - c.uv[1]).abs());
        assert!(miss > 0.5, "{:?}: swapped p1/p2 only {miss} px off", c.p_in_C);
    }
}

/// Where the two implementations part ways on purpose: OpenCV projects any
/// point, the project's `project` refuses points at or behind the image plane
/// (z ≤ 1e-6) and, for both models, points with |x/z| > 3 (71.6° off axis).
/// `distort` and `pixel_jacobian` have no cut-off and still match OpenCV
/// there.
#[test]
fn outside_the_projection_domain() {
    let cam = tumvi();
    for c in &EQUI_PROJ_BEYOND_CUTOFF {
        // OpenCV: the 75° point lands on pixel c.uv ≈ (379.9, 473.3), inside the 512 × 512 image.
        assert!(
            cam.project(&Vector3::from(c.p_in_C)).is_none(),
            "|x/z| = 3.73 is beyond project's cut-off"
        );
        assert_close(&cam.distort(&normalised(c.p_in_C)), c.xd, DISTORT_TOL, "distort at 75°");
        check_jacobian(&cam, c, "equidistant at 75°");
    }
    // OpenCV divides by z regardless: radtan (0.3, 0.2, -1) comes out mirrored at
    // (234.53, 160.19), and z = 0 is taken as 1/z = 1, giving (499.93, 336.60);
    // cv::fisheye mirrors (0.3, 0.2, -1) to (199.92, 220.22).
    for cam in [euroc(), tumvi()] {
        for p in [[0.3, 0.2, -1.0], [0.3, 0.2, 0.0], [0.0, 0.0, 1e-7]] {
            assert!(
                cam.project(&Vector3::from(p)).is_none(),
                "{p:?} is not in front of the camera"
            );
        }
    }
}
