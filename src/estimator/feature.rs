//! Feature tracks: triangulation, the camera measurement model and its
//! Jacobians, and the projection onto the left null space of `H_f`
//! (README.md §3).

use crate::counters::Counter;
use nalgebra::{DMatrix, DVector, Matrix2, Matrix2x3, Matrix3, Vector2, Vector3};

use super::math::skew;

/// Camera mounting on the body.
#[derive(Clone, Copy, Debug)]
pub struct Extrinsic {
    pub R_B_C: Matrix3<f64>,
    pub p_C_in_B: Vector3<f64>,
}

/// A pose that observed a feature: a clone or a keyframe.
#[derive(Clone, Copy, Debug)]
pub struct View {
    pub R_W_B: Matrix3<f64>,
    pub p_B_in_W: Vector3<f64>,
    /// The position the rotation's Jacobian is taken at: the view's first
    /// estimate (its value when it entered the state, README §3d), so the
    /// unobservable yaw and position stay unobservable.
    pub p_lin_in_W: Vector3<f64>,
}

/// One observation: undistorted normalised coordinates and the whitening
/// matrix `W` (noise of `W z` is unit).
#[derive(Clone, Copy, Debug)]
pub struct Obs {
    pub view: usize,
    pub xn: Vector2<f64>,
    pub W: Matrix2<f64>,
}

/// Why a track was not used. Ordered by name, as the log's `rejected`
/// objects list them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Reject {
    TooFewObservations,
    NonFinite,
    PoorParallax,
    BadDepth,
    NotConverged,
    Chi2,
}

impl Reject {
    pub fn name(self) -> &'static str {
        match self {
            Reject::TooFewObservations => "too_few_observations",
            Reject::NonFinite => "non_finite",
            Reject::PoorParallax => "poor_parallax",
            Reject::BadDepth => "bad_depth",
            Reject::NotConverged => "not_converged",
            Reject::Chi2 => "chi2",
        }
    }

    /// The daemon's counter of tracks rejected for this reason.
    pub fn counter(self) -> Counter {
        match self {
            Reject::TooFewObservations => Counter::TrackRejectedTooFewObservations,
            Reject::NonFinite => Counter::TrackRejectedNonFinite,
            Reject::PoorParallax => Counter::TrackRejectedPoorParallax,
            Reject::BadDepth => Counter::TrackRejectedBadDepth,
            Reject::NotConverged => Counter::TrackRejectedNotConverged,
            Reject::Chi2 => Counter::TrackRejectedChi2,
        }
    }
}

impl PartialOrd for Reject {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Reject {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.name().cmp(other.name())
    }
}

impl serde::Serialize for Reject {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

/// Landmark in the camera frame of a view (README §3, eq. C1):
/// `p_C = R_B_Cᵀ (R_W_Bᵀ (p_f − p_B) − p_C_in_B)`.
pub fn point_in_camera(v: &View, e: &Extrinsic, p_f: &Vector3<f64>) -> Vector3<f64> {
    e.R_B_C.transpose() * (v.R_W_B.transpose() * (p_f - v.p_B_in_W) - e.p_C_in_B)
}

/// `∂(x/z, y/z)/∂p_C`.
fn proj_jacobian(p_c: &Vector3<f64>) -> Matrix2x3<f64> {
    let iz = 1.0 / p_c.z;
    Matrix2x3::new(iz, 0.0, -p_c.x * iz * iz, 0.0, iz, -p_c.y * iz * iz)
}

/// Predicted normalised coordinates and the Jacobians with respect to the
/// view's pose error `[δθ, δp]` (2×6) and the landmark (2×3) (README §3,
/// eqs. C2–C4): `∂p_C/∂δθ = R_B_Cᵀ R_W_Bᵀ [p_f − p_B^FE]×` (with the
/// view's first-estimate position, §3d; a keyframe's rotation error `δ` is
/// taken at its first estimate too, where its chart is the identity, §4),
/// `∂p_C/∂δp = −R_B_Cᵀ R_W_Bᵀ`, `∂p_C/∂p_f = R_B_Cᵀ R_W_Bᵀ`.
pub fn measure(
    v: &View,
    e: &Extrinsic,
    p_f: &Vector3<f64>,
) -> (Vector2<f64>, nalgebra::Matrix2x6<f64>, Matrix2x3<f64>) {
    let p_c = point_in_camera(v, e, p_f);
    let jp = proj_jacobian(&p_c);
    let r_cw = e.R_B_C.transpose() * v.R_W_B.transpose();
    let d_th = r_cw * skew(&(p_f - v.p_lin_in_W));
    let mut h_pose = nalgebra::Matrix2x6::zeros();
    h_pose.fixed_view_mut::<2, 3>(0, 0).copy_from(&(jp * d_th));
    h_pose.fixed_view_mut::<2, 3>(0, 3).copy_from(&(-jp * r_cw));
    (Vector2::new(p_c.x / p_c.z, p_c.y / p_c.z), h_pose, jp * r_cw)
}

/// The point's camera-frame position, its predicted normalised
/// coordinates and their Jacobian with respect to the landmark (`∂z/∂p_f =
/// J_proj R_B_Cᵀ R_W_Bᵀ`, eq. C4): what triangulation's Gauss–Newton needs,
/// without [`measure`]'s pose Jacobian, computed as `measure` computes them.
fn measure_point(v: &View, e: &Extrinsic, p_f: &Vector3<f64>) -> (Vector3<f64>, Vector2<f64>, Matrix2x3<f64>) {
    let p_c = point_in_camera(v, e, p_f);
    let jp = proj_jacobian(&p_c);
    let r_cw = e.R_B_C.transpose() * v.R_W_B.transpose();
    (p_c, Vector2::new(p_c.x / p_c.z, p_c.y / p_c.z), jp * r_cw)
}

/// An observation's ray in the world: the camera centre
/// `p_B + R_W_B p_C_in_B` and the unit bearing `R_W_B R_B_C [x_n, y_n, 1]`.
fn world_ray(v: &View, e: &Extrinsic, o: &Obs) -> (Vector3<f64>, Vector3<f64>) {
    (
        v.p_B_in_W + v.R_W_B * e.p_C_in_B,
        (v.R_W_B * e.R_B_C * Vector3::new(o.xn.x, o.xn.y, 1.0)).normalize(),
    )
}

/// The parallax a triangulation has to work with (rad): the widest angle
/// between two of a track's bearing rays in the world frame, once the one
/// observation that widens it most is left out. A single outlier (a wrong
/// id, a gross pixel error) sits at one end of the widest pair and would
/// otherwise make a still camera's track look wide.
pub fn parallax_rad(views: &[View], e: &Extrinsic, obs: &[Obs]) -> f64 {
    // The rays on the stack for a track of up to 32 views (the defaults'
    // longest is 11 clones and 8 keyframes): no allocation per track.
    let mut stack = [Vector3::zeros(); 32];
    let mut heap = Vec::new();
    let dirs: &mut [Vector3<f64>] = if obs.len() <= stack.len() {
        &mut stack[..obs.len()]
    } else {
        heap.resize(obs.len(), Vector3::zeros());
        &mut heap
    };
    for (d, o) in dirs.iter_mut().zip(obs) {
        *d = world_ray(&views[o.view], e, o).1;
    }
    let dirs = &*dirs;
    // The widest pair, by the smallest cosine.
    let widest_without = |skip: Option<usize>| {
        let mut best = (1.0f64, 0, 0);
        for (i, a) in dirs.iter().enumerate() {
            for (j, b) in dirs.iter().enumerate().skip(i + 1) {
                if Some(i) == skip || Some(j) == skip {
                    continue;
                }
                let c = a.dot(b);
                if c < best.0 || c.is_nan() {
                    best = (c, i, j);
                }
            }
        }
        best
    };
    let (c, a, b) = widest_without(None);
    if c.is_nan() {
        return f64::NAN;
    }
    if dirs.len() < 3 {
        return c.clamp(-1.0, 1.0).acos();
    }
    // Leave out either end of the widest pair; the narrower result is
    // the parallax without that end.
    let c = widest_without(Some(a)).0.max(widest_without(Some(b)).0);
    if c.is_nan() {
        return f64::NAN;
    }
    c.clamp(-1.0, 1.0).acos()
}

/// Triangulation limits.
#[derive(Clone, Copy, Debug)]
pub struct TriangulationLimits {
    pub min_depth_m: f64,
    pub max_depth_m: f64,
    pub max_cond: f64,
}

/// Triangulates a landmark from its observations (README §3, eq. T1–T2):
/// a linear initial guess from the bearing rays,
/// `Σ (I − bbᵀ) p = Σ (I − bbᵀ) c`, whose conditioning measures the
/// parallax, then Gauss–Newton on the whitened reprojection error.
pub fn triangulate(
    views: &[View],
    e: &Extrinsic,
    obs: &[Obs],
    lim: &TriangulationLimits,
) -> Result<Vector3<f64>, Reject> {
    if obs.len() < 2 {
        return Err(Reject::TooFewObservations);
    }
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for o in obs {
        let (c, dir) = world_ray(&views[o.view], e, o);
        let m = Matrix3::identity() - dir * dir.transpose();
        a += m;
        b += m * c;
    }
    if !a.iter().all(|x| x.is_finite()) || !b.iter().all(|x| x.is_finite()) {
        return Err(Reject::NonFinite);
    }
    let eig = a.symmetric_eigenvalues();
    let (lo, hi) = (eig.min(), eig.max());
    if lo <= 0.0 || hi / lo > lim.max_cond {
        return Err(Reject::PoorParallax);
    }
    let mut p = a.cholesky().ok_or(Reject::PoorParallax)?.solve(&b);
    // Gauss–Newton on Σ |W (z − h(p))|².
    let mut cost_prev = f64::INFINITY;
    for _ in 0..10 {
        let mut jtj = Matrix3::zeros();
        let mut jtr = Vector3::zeros();
        let mut cost = 0.0;
        for o in obs {
            let (p_c, z, hf) = measure_point(&views[o.view], e, &p);
            if p_c.z < lim.min_depth_m {
                return Err(Reject::BadDepth);
            }
            let r = o.W * (o.xn - z);
            let j = o.W * hf;
            jtj += j.transpose() * j;
            jtr += j.transpose() * r;
            cost += r.norm_squared();
        }
        let Some(ch) = jtj.cholesky() else {
            return Err(Reject::PoorParallax);
        };
        let dp = ch.solve(&jtr);
        p += dp;
        if !p.iter().all(|x| x.is_finite()) {
            return Err(Reject::NonFinite);
        }
        if dp.norm() < 1e-8 * (1.0 + p.norm()) || (cost_prev - cost).abs() < 1e-12 {
            break;
        }
        cost_prev = cost;
    }
    for o in obs {
        let d = point_in_camera(&views[o.view], e, &p).z;
        if !(lim.min_depth_m..=lim.max_depth_m).contains(&d) {
            return Err(Reject::BadDepth);
        }
    }
    Ok(p)
}

/// The buffers a track's gate works in (`track_system_into`,
/// `nullspace_project_into`, `projected_nis_into` and the χ² gate's
/// factor), kept across tracks and frames so that a track's working
/// matrices allocate nothing once they have grown to the longest track
/// (issue 43; a passing track's rows are copied out, into the frame's
/// `msckf::StackRows`). Kept inside the
/// filter's [`super::math::Scratch`].
#[derive(Default)]
pub struct TrackScratch {
    /// `track_system`'s whitened `H_x` (`2m × 6·n_views`), `H_f` (`2m × 3`)
    /// and residual.
    pub hx: DMatrix<f64>,
    pub hf: DMatrix<f64>,
    pub r: DVector<f64>,
    /// `[H_f | H_x | r]` reflected by `nullspace_project_into`.
    pub projected: DMatrix<f64>,
    /// `projected_nis_into`'s `C = H_x P H_xᵀ + I` (then its Cholesky
    /// factor) and `L⁻¹ [H_f | r]`.
    pub c: DMatrix<f64>,
    pub y: DMatrix<f64>,
    /// The low-parallax gate's `S` (then its Cholesky factor) and `S⁻¹ r`.
    pub s: DMatrix<f64>,
    pub s_inv_r: DVector<f64>,
}

/// The stacked, whitened residual of a track and its Jacobians with respect
/// to the views' poses (`2m × 6·n_views`) and the landmark (`2m × 3`).
pub fn track_system(
    views: &[View],
    e: &Extrinsic,
    obs: &[Obs],
    p_f: &Vector3<f64>,
) -> (DMatrix<f64>, DMatrix<f64>, DVector<f64>) {
    let mut w = TrackScratch::default();
    track_system_into(views, e, obs, p_f, &mut w);
    (w.hx, w.hf, w.r)
}

/// [`track_system`] into `w.hx`, `w.hf` and `w.r`.
pub fn track_system_into(views: &[View], e: &Extrinsic, obs: &[Obs], p_f: &Vector3<f64>, w: &mut TrackScratch) {
    let m = obs.len();
    super::math::reshape_zeroed(&mut w.hx, 2 * m, 6 * views.len());
    super::math::reshape_zeroed(&mut w.hf, 2 * m, 3);
    super::math::reshape_zeroed_vector(&mut w.r, 2 * m);
    for (i, o) in obs.iter().enumerate() {
        let (z, hp, hfi) = measure(&views[o.view], e, p_f);
        w.hx.view_mut((2 * i, 6 * o.view), (2, 6)).copy_from(&(o.W * hp));
        w.hf.view_mut((2 * i, 0), (2, 3)).copy_from(&(o.W * hfi));
        w.r.rows_mut(2 * i, 2).copy_from(&(o.W * (o.xn - z)));
    }
}

/// Projects `r = H_x δx + H_f δp_f + n` onto the left null space of `H_f`
/// (README §3, eq. N1) with Householder reflections: `Qᵀ H_f = [R; 0]`, so
/// the last `2m − 3` rows of `Qᵀ H_x` and `Qᵀ r` are free of `δp_f`. With
/// whitened (unit) noise the projected noise stays unit.
pub fn nullspace_project(hx: &DMatrix<f64>, hf: &DMatrix<f64>, r: &DVector<f64>) -> (DMatrix<f64>, DVector<f64>) {
    let mut a = DMatrix::zeros(0, 0);
    let (r0, keep) = nullspace_project_into(hx, hf, r, &mut a);
    let nx = hx.ncols();
    (
        super::math::block_owned(&a, r0, 3, keep, nx),
        DVector::from_column_slice(&a.column(3 + nx).as_slice()[r0..]),
    )
}

/// [`nullspace_project`] into `a`: `[H_f | H_x | r]` reflected on its first
/// three columns. The projected rows are `a[r0.., 3..3 + n_x]` and their
/// residual `a[r0.., 3 + n_x]`; returns `(r0, rows kept)`.
pub fn nullspace_project_into(
    hx: &DMatrix<f64>,
    hf: &DMatrix<f64>,
    r: &DVector<f64>,
    a: &mut DMatrix<f64>,
) -> (usize, usize) {
    let (rows, nx) = hx.shape();
    super::math::reshape_zeroed(a, rows, 3 + nx + 1);
    a.columns_mut(0, 3).copy_from(hf);
    a.columns_mut(3, nx).copy_from(hx);
    a.column_mut(3 + nx).copy_from(r);
    super::math::householder_in_place(a, 3);
    (3.min(rows), rows.saturating_sub(3))
}

/// Largest angle between a low-parallax track's mean bearing and its
/// remembered landmark, seen from the views (rad, §3e): 5°.
const MAX_PRIOR_OFF_BEARING_RAD: f64 = 0.087;

/// Where a low-parallax track's landmark is taken to lie (§3e): where it
/// was last triangulated, its inverse depth from the views known to a
/// fraction of itself.
#[derive(Clone, Copy, Debug)]
pub struct DepthPrior {
    pub p_W: Vector3<f64>,
    pub inverse_depth_sigma_ratio: f64,
}

/// A low-parallax track's whitened, projected rows: `r = H_x δx + n` with
/// unit noise, and the point they were linearised at.
#[derive(Clone, Debug)]
pub struct LowParallaxRows {
    pub hx: DMatrix<f64>,
    pub r: DVector<f64>,
    pub p_f: Vector3<f64>,
}

/// A low-parallax track's whitened rows (README §3e, eqs. LP1–LP4), with
/// the landmark's linearisation point: the track is anchored along its mean
/// bearing `b̄` from its views' mean centre `c̄`, at the depth
/// `d = b̄ᵀ (p_prior − c̄)` of the remembered landmark (LP1), and refined
/// across the bearing only; the two directions across `b̄` are projected out
/// as `nullspace_project` does all three (LP2); the depth is a nuisance of
/// inverse-depth sigma `κ/d` (σ_d = κ d at the linearisation point), whose
/// column joins the noise (LP3) and is whitened away (LP4). An error when
/// the bearings are not finite or the point falls behind a view.
pub fn low_parallax_system(
    views: &[View],
    e: &Extrinsic,
    obs: &[Obs],
    prior: DepthPrior,
    min_depth_m: f64,
) -> Result<LowParallaxRows, Reject> {
    if obs.len() < 2 {
        return Err(Reject::TooFewObservations);
    }
    // LP1: p = c̄ + d̄ b̄ + U u, U spanning the plane across b̄.
    let mut b = Vector3::zeros();
    let mut c = Vector3::zeros();
    for o in obs {
        let (centre, dir) = world_ray(&views[o.view], e, o);
        b += dir;
        c += centre;
    }
    let b = b.normalize();
    let c = c / obs.len() as f64;
    // The remembered landmark must lie along the bearing: one elsewhere
    // (a front-end that reused the id, a landmark that moved) lends no
    // depth.
    let to_prior = prior.p_W - c;
    let depth_m = b.dot(&to_prior);
    if depth_m.is_finite() && depth_m < MAX_PRIOR_OFF_BEARING_RAD.cos() * to_prior.norm() {
        return Err(Reject::BadDepth);
    }
    let sigma_d_m = depth_m * prior.inverse_depth_sigma_ratio;
    if !(b.iter().chain(c.iter()).all(|x| x.is_finite()) && depth_m.is_finite() && sigma_d_m.is_finite()) {
        return Err(Reject::NonFinite);
    }
    if depth_m < min_depth_m {
        return Err(Reject::BadDepth);
    }
    let seed = if b.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
    let u1 = b.cross(&seed).normalize();
    let u = nalgebra::Matrix3x2::from_columns(&[u1, b.cross(&u1)]);
    let mut p = c + b * depth_m;
    // Gauss–Newton across the bearing (the depth stays at the prior's).
    for _ in 0..3 {
        let mut jtj = Matrix2::zeros();
        let mut jtr = Vector2::zeros();
        for o in obs {
            let v = &views[o.view];
            if point_in_camera(v, e, &p).z < min_depth_m {
                return Err(Reject::BadDepth);
            }
            let (z, _, hf) = measure(v, e, &p);
            let j = o.W * hf * u;
            jtj += j.transpose() * j;
            jtr += j.transpose() * (o.W * (o.xn - z));
        }
        let du = jtj.cholesky().ok_or(Reject::NonFinite)?.solve(&jtr);
        p += u * du;
        if !p.iter().all(|x| x.is_finite()) {
            return Err(Reject::NonFinite);
        }
        if du.norm() < 1e-9 * depth_m {
            break;
        }
    }
    for o in obs {
        if point_in_camera(&views[o.view], e, &p).z < min_depth_m {
            return Err(Reject::BadDepth);
        }
    }
    let (mut hx, hf, r) = track_system(views, e, obs, &p);
    // The depth is the views' own, from their mean centre c̄ = Σ c_i / n,
    // c_i = p_B_i + R_W_B_i p_C_in_B: the landmark moves along b̄ with
    // them, ∂p/∂δp_i = b̄ b̄ᵀ / n and ∂p/∂δθ_i = −b̄ b̄ᵀ [R_W_B_i p_C_in_B]× / n
    // − b̄ b̄ᵀ [p − c̄_FE]× / n (the parts across b̄ are projected out with
    // the others), so a translation or a turn about gravity of the whole
    // window leaves the residual as it is, as the unobservable position
    // and yaw must (LP1′).
    let h_d = &hf * b;
    let n = obs.len() as f64;
    // The landmark's offset from the views, p − c̄_FE (centres at their
    // first estimates), turns with the views: its share along b̄,
    // −b̄ᵀ [p − c̄_FE]× δθ_i / n on each view's rotation (LP1′). With it a
    // turn of the whole window about gravity, at the first estimates C5
    // takes it at, leaves the rows exactly as they are.
    let c_fe = obs
        .iter()
        .map(|o| views[o.view].p_lin_in_W + views[o.view].R_W_B * e.p_C_in_B)
        .sum::<Vector3<f64>>()
        / n;
    let turn = b.transpose() * skew(&(p - c_fe));
    for o in obs {
        let v = &views[o.view];
        let d_rot = -(b.transpose() * skew(&(v.R_W_B * e.p_C_in_B)) + turn) / n;
        let d_pos = b.transpose() / n;
        let mut block = hx.view_mut((0, 6 * o.view), (2 * obs.len(), 6));
        block.columns_mut(0, 3).gemm(1.0, &h_d, &d_rot, 1.0);
        block.columns_mut(3, 3).gemm(1.0, &h_d, &d_pos, 1.0);
    }
    // LP2: [H_f U | H_x | H_f b̄ | r], reflected on its first two columns.
    let (rows, nx) = hx.shape();
    let mut a = DMatrix::zeros(rows, 2 + nx + 2);
    a.columns_mut(0, 2).copy_from(&(&hf * u));
    a.columns_mut(2, nx).copy_from(&hx);
    a.column_mut(2 + nx).copy_from(&h_d);
    a.column_mut(3 + nx).copy_from(&r);
    super::math::householder_in_place(&mut a, 2);
    let keep = rows - 2;
    let mut hx = super::math::block_owned(&a, 2, 2, keep, nx);
    let mut r = DVector::from_column_slice(&a.column(3 + nx).as_slice()[2..]);
    // LP3: the noise is I + v vᵀ, v = σ_d Q₂ᵀ H_f b̄, σ_d = κ d.
    let v = DVector::from_column_slice(&a.column(2 + nx).as_slice()[2..]) * sigma_d_m;
    // LP4: (I + v vᵀ)^(-1/2) = I − κ v vᵀ, κ = (1 − 1/√(1 + |v|²)) / |v|².
    let s = v.norm_squared();
    if s > 0.0 {
        let kappa = (1.0 - 1.0 / (1.0 + s).sqrt()) / s;
        let vt_h = v.transpose() * &hx;
        hx -= &v * (vt_h * kappa);
        let vt_r = v.dot(&r);
        r -= &v * (vt_r * kappa);
    }
    Ok(LowParallaxRows { hx, r, p_f: p })
}

/// `C = H_x P H_xᵀ + I` into `c`, its lower triangle (and the diagonal
/// blocks whole; the upper triangle is never read) (README §3, G1′):
/// `H_x` from `track_system` is block diagonal, one 2×6 block `J_i` per
/// observation, so `M_ij = J_i P_ij J_jᵀ` is `O(m²)` products of 2×6 by 6×6.
fn whitened_innovation_covariance(hx: &DMatrix<f64>, obs: &[Obs], p: &DMatrix<f64>, c: &mut DMatrix<f64>) {
    let rows = hx.nrows();
    super::math::reshape_zeroed(c, rows, rows);
    let (hs, ps, np) = (hx.as_slice(), p.as_slice(), p.nrows());
    // J_i as two rows of six, read from the column-major `hx`.
    let block = |i: usize| {
        let col = 6 * obs[i].view;
        let at = |k: usize| (col + k) * rows + 2 * i;
        (col, [0, 1].map(|a| std::array::from_fn::<f64, 6, _>(|k| hs[at(k) + a])))
    };
    let cs = c.as_mut_slice();
    for j in 0..obs.len() {
        let (cj, jj) = block(j);
        for i in j..obs.len() {
            let (ci, ji) = block(i);
            // T = J_i P_ij (2×6), then M_ij = T J_jᵀ (2×2), i ≥ j: in the
            // lower triangle. Plain arrays: nalgebra's generic small
            // products were a tenth of the gate's time.
            let mut t = [[0.0; 6]; 2];
            for k in 0..6 {
                let pc = &ps[(cj + k) * np + ci..(cj + k) * np + ci + 6];
                for a in 0..2 {
                    t[a][k] = (0..6).map(|r| ji[a][r] * pc[r]).sum();
                }
            }
            for d in 0..2 {
                for a in 0..2 {
                    cs[(2 * j + d) * rows + 2 * i + a] = (0..6).map(|k| t[a][k] * jj[d][k]).sum();
                }
            }
        }
    }
    for d in 0..rows {
        cs[d * rows + d] += 1.0;
    }
}

/// The projected track's NIS for the χ² gate (README §3, G1′), without
/// projecting its covariance: with `C = H_x P H_xᵀ + I` (whitened noise)
/// and `Q₂` spanning the left null space of `H_f`,
/// `rᵀ Q₂ (Q₂ᵀ C Q₂)⁻¹ Q₂ᵀ r = rᵀ C⁻¹ r − rᵀ C⁻¹ H_f (H_fᵀ C⁻¹ H_f)⁻¹ H_fᵀ C⁻¹ r`,
/// the residual of `r` after the landmark's best correction, weighed by
/// `C`. With `C = L Lᵀ`, `[F | y] = L⁻¹ [H_f | r]`, it is `|y|²` less `y`'s
/// part in the span of `F`: the last `2m − 3` entries of `y` after the
/// three reflections that triangularise `F`, squared and summed (no
/// subtraction, so no cancellation). `r`, `hx`, `hf` are the unprojected,
/// whitened rows of `track_system`, whose `H_x` is block diagonal (one
/// 2×6 block per observation; a low-parallax track's rows are not, and
/// take the dense gate); `p` the covariance of the track's views in `hx`'s
/// column order. `H_f` must have full column rank, as a triangulated
/// track's has. `Ok((nis, dof))`; `Err` when `C` is not
/// positive definite (a non-finite entry, or a covariance that lost its
/// definiteness). Works in `(c, y)`, which keep their capacity.
pub fn projected_nis_into(
    (hx, hf, r): (&DMatrix<f64>, &DMatrix<f64>, &DVector<f64>),
    obs: &[Obs],
    p: &DMatrix<f64>,
    (c, y): (&mut DMatrix<f64>, &mut DMatrix<f64>),
) -> Result<(f64, usize), Reject> {
    let rows = hx.nrows();
    if rows <= 3 {
        return Ok((0.0, 0));
    }
    whitened_innovation_covariance(hx, obs, p, c);
    if !super::math::cholesky_lower_in_place(c) {
        return Err(Reject::NonFinite);
    }
    super::math::reshape_zeroed(y, rows, 4);
    y.columns_mut(0, 3).copy_from(hf);
    y.column_mut(3).copy_from(r);
    super::math::solve_lower_in_place(c, y);
    super::math::householder_in_place(y, 3);
    let nis = y.column(3).as_slice()[3..].iter().map(|v| v * v).sum();
    Ok((nis, rows - 3))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::math::exp_so3;

    fn ext() -> Extrinsic {
        let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(0.5, 0.5, 0.5, 0.5));
        Extrinsic {
            R_B_C: q.to_rotation_matrix().into_inner(),
            p_C_in_B: Vector3::new(0.1, 0.0, 0.02),
        }
    }

    fn view(yaw: f64, p: Vector3<f64>) -> View {
        View {
            R_W_B: exp_so3(&Vector3::new(0.05, -0.02, yaw))
                .to_rotation_matrix()
                .into_inner(),
            p_B_in_W: p,
            p_lin_in_W: p,
        }
    }

    #[test]
    fn measure_point_is_measure_without_the_pose_jacobian() {
        // Triangulation's Gauss–Newton takes it for `measure`: the same
        // numbers, bit for bit, so that no estimate moves.
        let e = ext();
        for (k, p_f) in [Vector3::new(12.0, 3.0, -2.0), Vector3::new(-4.0, 7.5, 1.25)]
            .iter()
            .enumerate()
        {
            let v = view(0.1 + k as f64, Vector3::new(1.0, 0.5, -3.0));
            let (z, _, hf) = measure(&v, &e, p_f);
            let (p_c, z2, hf2) = measure_point(&v, &e, p_f);
            assert_eq!((z, hf, p_c), (z2, hf2, point_in_camera(&v, &e, p_f)));
        }
    }

    /// Projection Jacobians against central differences.
    #[test]
    fn measurement_jacobians_match_finite_differences() {
        let e = ext();
        let p_f = Vector3::new(12.0, 3.0, -2.0);
        let v0 = view(0.1, Vector3::new(1.0, 0.5, -3.0));
        let (_, hp, hf) = measure(&v0, &e, &p_f);
        let h = 1e-6;
        for k in 0..6 {
            let perturb = |s: f64| {
                let mut v = v0;
                if k < 3 {
                    // World-frame rotation error: R = Exp(ε) R̂.
                    let mut eps = Vector3::zeros();
                    eps[k] = s;
                    v.R_W_B = exp_so3(&eps).to_rotation_matrix().into_inner() * v0.R_W_B;
                } else {
                    v.p_B_in_W[k - 3] += s;
                }
                measure(&v, &e, &p_f).0
            };
            let col = (perturb(h) - perturb(-h)) / (2.0 * h);
            assert!(
                (col - hp.column(k)).norm() < 1e-7,
                "pose col {k}: {col} vs {}",
                hp.column(k)
            );
        }
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let col = (measure(&v0, &e, &(p_f + d)).0 - measure(&v0, &e, &(p_f - d)).0) / (2.0 * h);
            assert!((col - hf.column(k)).norm() < 1e-8);
        }
    }

    fn synthetic(p_f: &Vector3<f64>) -> (Vec<View>, Vec<Obs>) {
        let e = ext();
        let views: Vec<_> = (0..5)
            .map(|i| view(0.02 * i as f64, Vector3::new(0.0, 0.6 * i as f64, -3.0)))
            .collect();
        let obs = (0..5)
            .map(|i| Obs {
                view: i,
                xn: measure(&views[i], &e, p_f).0,
                W: Matrix2::identity() * 400.0,
            })
            .collect();
        (views, obs)
    }

    #[test]
    fn triangulation_recovers_the_point_and_its_jacobian() {
        let e = ext();
        let lim = TriangulationLimits {
            min_depth_m: 0.2,
            max_depth_m: 100.0,
            max_cond: 1e6,
        };
        let p_f = Vector3::new(15.0, 2.0, -1.0);
        let (views, obs) = synthetic(&p_f);
        let p = triangulate(&views, &e, &obs, &lim).unwrap();
        assert!((p - p_f).norm() < 1e-8, "{p}");
        // The Gauss–Newton Jacobian (W·H_f) against finite differences of
        // the whitened residual.
        let (_, hf, r0) = track_system(&views, &e, &obs, &p);
        let h = 1e-6;
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let (_, _, rp) = track_system(&views, &e, &obs, &(p + d));
            let (_, _, rm) = track_system(&views, &e, &obs, &(p - d));
            // r = W (z − h), so ∂r/∂p = −W H_f.
            let col = (rp - rm) / (2.0 * h);
            assert!((col + hf.column(k)).norm() < 1e-5, "{k}");
        }
        assert!(r0.norm() < 1e-6);
        // Degenerate inputs are rejected, never a panic.
        assert_eq!(
            triangulate(&views, &e, &obs[..1], &lim),
            Err(Reject::TooFewObservations)
        );
        let behind = Vector3::new(-15.0, 2.0, -1.0);
        let (v2, o2) = synthetic(&behind);
        assert!(triangulate(&v2, &e, &o2, &lim).is_err());
        let mut nan = obs.clone();
        nan[2].xn.x = f64::NAN;
        assert_eq!(triangulate(&views, &e, &nan, &lim), Err(Reject::NonFinite));
        // Parallel rays: every view at the same place.
        let same: Vec<_> = views.iter().map(|_| views[0]).collect();
        let o3: Vec<_> = obs.iter().map(|o| Obs { xn: obs[0].xn, ..*o }).collect();
        assert_eq!(triangulate(&same, &e, &o3, &lim), Err(Reject::PoorParallax));
    }

    #[test]
    fn nullspace_projection_removes_the_landmark() {
        let e = ext();
        let p_f = Vector3::new(15.0, 2.0, -1.0);
        let (views, obs) = synthetic(&p_f);
        let (hx, hf, r) = track_system(&views, &e, &obs, &p_f);
        let (hx2, r2) = nullspace_project(&hx, &hf, &r);
        assert_eq!(hx2.nrows(), 2 * obs.len() - 3);
        assert_eq!(r2.len(), 2 * obs.len() - 3);
        // Applying the same transform to H_f leaves zeros in the kept rows.
        let (hf2, _) = nullspace_project(&hf, &hf, &DVector::zeros(2 * obs.len()));
        assert!(hf2.amax() < 1e-9, "{}", hf2.amax());
        assert!(hx2.amax() > 1.0);
        // The gate's NIS from the unprojected rows (G1′) equals the dense
        // projected one (G1), for a covariance correlating all the views.
        let p = correlated_covariance(hx.ncols());
        // A residual away from the triangulated point, so that the landmark's
        // own correction is not zero and the identity is exercised.
        let r = r + DVector::from_fn(2 * obs.len(), |i, _| 30.0 * ((i * 5 % 7) as f64 - 3.0));
        let (want, dof) = dense_projected_nis(&hx, &hf, &r, &p);
        let got = projected_nis_into(
            (&hx, &hf, &r),
            &obs,
            &p,
            (&mut DMatrix::zeros(0, 0), &mut DMatrix::zeros(0, 0)),
        );
        assert_eq!(got.map(|g| g.1), Ok(dof));
        let got = got.map(|g| g.0).unwrap_or(f64::NAN);
        assert!(want > 1.0, "a residual that tests something: {want}");
        assert!((got - want).abs() <= 1e-10 * want, "{got} vs {want}");
    }

    /// The χ² gate's `H P Hᵀ` for the projected track (README §3, G1):
    /// `Q₂ᵀ (H_x P H_xᵀ) Q₂`, where `Q₂` spans the left null space of `H_f` (the
    /// rows `nullspace_project` keeps) and `p` is the covariance of the track's
    /// views in `hx`'s column order: the dense product of the projected rows.
    /// The gate itself needs only the NIS, which [`projected_nis_into`] takes
    /// without projecting `H_x P H_xᵀ`; this is its reference in the tests.
    fn projected_hph(hx: &DMatrix<f64>, hf: &DMatrix<f64>, p: &DMatrix<f64>) -> DMatrix<f64> {
        let (hx2, _) = nullspace_project(hx, hf, &DVector::zeros(hx.nrows()));
        &hx2 * p * hx2.transpose()
    }

    /// A positive-definite `n × n` covariance that correlates every pair of
    /// entries, and whose off-diagonal blocks are not symmetric.
    fn correlated_covariance(n: usize) -> DMatrix<f64> {
        let g = DMatrix::from_fn(n, n, |i, j| ((i * 7 + j * 3) % 11) as f64 * 0.01 - 0.05);
        &g * g.transpose() + DMatrix::identity(n, n) * 0.01
    }

    /// G1 the long way: the projected rows `Q₂ᵀ H_x`, `Q₂ᵀ r`, and
    /// `rᵀ (H P Hᵀ + I)⁻¹ r` through nalgebra's Cholesky; with its dof.
    fn dense_projected_nis(hx: &DMatrix<f64>, hf: &DMatrix<f64>, r: &DVector<f64>, p: &DMatrix<f64>) -> (f64, usize) {
        let (_, r2) = nullspace_project(hx, hf, r);
        let s = projected_hph(hx, hf, p) + DMatrix::identity(r2.len(), r2.len());
        let s_inv_r = s.cholesky().map(|c| c.solve(&r2));
        (s_inv_r.map(|x| r2.dot(&x)).unwrap_or(f64::NAN), r2.len())
    }

    /// The gate's NIS refuses a covariance that is not positive definite
    /// (a NaN in it, or a negative variance) instead of passing the track.
    #[test]
    fn the_gates_nis_refuses_a_covariance_that_is_not_positive_definite() {
        let e = ext();
        let p_f = Vector3::new(15.0, 2.0, -1.0);
        let (views, obs) = synthetic(&p_f);
        let (hx, hf, r) = track_system(&views, &e, &obs, &p_f);
        let n = hx.ncols();
        let bufs = || (DMatrix::zeros(0, 0), DMatrix::zeros(0, 0));
        for bad in [f64::NAN, -1e6] {
            let mut p = DMatrix::identity(n, n) * 0.01;
            p[(0, 0)] = bad;
            let (mut c, mut y) = bufs();
            let got = projected_nis_into((&hx, &hf, &r), &obs, &p, (&mut c, &mut y));
            assert_eq!(got, Err(Reject::NonFinite), "P[0, 0] = {bad}");
        }
    }

    /// The gate's NIS equals the dense projected one also for long tracks,
    /// where `nullspace_project` takes the blocked triangularisation, and
    /// when several observations share a view.
    #[test]
    fn gate_nis_matches_the_dense_projection_on_long_and_shared_tracks() {
        let e = ext();
        let p_f = Vector3::new(15.0, 2.0, -1.0);
        for (n_obs, n_views, reverse) in [
            (12usize, 12usize, false),
            (24, 24, false),
            (40, 40, false),
            (9, 4, false),
            (9, 4, true),
            (12, 12, true),
        ] {
            let views: Vec<_> = (0..n_views)
                .map(|i| view(0.01 * i as f64, Vector3::new(0.05 * i as f64, 0.3 * i as f64, -3.0)))
                .collect();
            let obs: Vec<_> = (0..n_obs)
                .map(|i| {
                    // Views in decreasing order too, so that both triangles
                    // of P's blocks are read.
                    let v = if reverse {
                        n_views - 1 - i * n_views / n_obs
                    } else {
                        i * n_views / n_obs
                    };
                    Obs {
                        view: v,
                        xn: measure(&views[v], &e, &p_f).0 + Vector2::new(1e-3 * i as f64, -2e-3),
                        W: Matrix2::new(400.0, 20.0, 0.0, 380.0),
                    }
                })
                .collect();
            let (hx, hf, r) = track_system(&views, &e, &obs, &p_f);
            let p = correlated_covariance(hx.ncols());
            let r = r + DVector::from_fn(2 * n_obs, |i, _| 30.0 * ((i * 3 % 5) as f64 - 2.0));
            let (want, dof) = dense_projected_nis(&hx, &hf, &r, &p);
            let bufs = (&mut DMatrix::zeros(0, 0), &mut DMatrix::zeros(0, 0));
            let got = projected_nis_into((&hx, &hf, &r), &obs, &p, bufs);
            assert_eq!(got.map(|g| g.1), Ok(2 * n_obs - 3), "{n_obs} observations");
            assert_eq!(dof, 2 * n_obs - 3);
            let got = got.map(|g| g.0).unwrap_or(f64::NAN);
            assert!(want > 1.0, "a residual that tests something: {want}");
            assert!(
                (got - want).abs() <= 1e-9 * want,
                "{n_obs} observations of {n_views} views: {got} vs {want}"
            );
        }
    }

    /// A still camera's track (1 cm between views, turning): the
    /// low-parallax rows vanish at the truth and their Jacobian matches
    /// central differences of the rows' residual (LP1–LP4); a landmark
    /// remembered at the wrong depth, even at infinity, leaves a residual of
    /// about its inverse depth's error in sigmas, the nuisance's.
    #[test]
    fn low_parallax_rows_vanish_at_the_truth_and_match_finite_differences() {
        let e = ext();
        let views: Vec<_> = (0..8)
            .map(|i| view(0.01 * i as f64, Vector3::new(0.003 * i as f64, 0.01 * i as f64, -3.0)))
            .collect();
        let obs_of = |p_f: &Vector3<f64>| -> Vec<Obs> {
            (0..views.len())
                .map(|i| Obs {
                    view: i,
                    xn: measure(&views[i], &e, p_f).0,
                    W: Matrix2::identity() * 400.0,
                })
                .collect()
        };
        // A landmark 5 m along the first view's optical axis, a little off it.
        let r_wc = views[0].R_W_B * e.R_B_C;
        let c0 = views[0].p_B_in_W + views[0].R_W_B * e.p_C_in_B;
        let along = |d: f64| c0 + r_wc * (Vector3::new(0.1, -0.05, 1.0).normalize() * d);
        let kappa = 0.6;
        let prior = |p_W: Vector3<f64>| DepthPrior {
            p_W,
            inverse_depth_sigma_ratio: kappa,
        };
        let p_f = along(5.0);
        let obs = obs_of(&p_f);
        let LowParallaxRows { hx, r, p_f: p } = low_parallax_system(&views, &e, &obs, prior(p_f), 0.1).unwrap();
        assert_eq!(r.len(), 2 * obs.len() - 2);
        assert!(r.norm() < 1e-6, "{}", r.norm());
        assert!((p - p_f).norm() < 1e-6, "{p} vs {p_f}");
        let h = 1e-6;
        for k in 0..6 * views.len() {
            let perturbed = |s: f64| {
                let mut v = views.clone();
                let (i, j) = (k / 6, k % 6);
                if j < 3 {
                    let mut eps = Vector3::zeros();
                    eps[j] = s;
                    v[i].R_W_B = exp_so3(&eps).to_rotation_matrix().into_inner() * v[i].R_W_B;
                } else {
                    v[i].p_B_in_W[j - 3] += s;
                }
                v[i].p_lin_in_W = v[i].p_B_in_W;
                // The remembered landmark moves with the views' mean
                // centre: its depth from them is what is known (LP1′).
                let c_bar = |vs: &[View]| {
                    vs.iter()
                        .map(|x| x.p_B_in_W + x.R_W_B * e.p_C_in_B)
                        .sum::<Vector3<f64>>()
                        / vs.len() as f64
                };
                let p_W = p_f + c_bar(&v) - c_bar(&views);
                low_parallax_system(&v, &e, &obs, prior(p_W), 0.1).unwrap().r
            };
            // r = W (z − h(x̂)): ∂r/∂x̂ = −H.
            let col = (perturbed(h) - perturbed(-h)) / (2.0 * h);
            assert!(
                (&col + hx.column(k)).norm() < 1e-4 * (1.0 + hx.column(k).norm()),
                "column {k}: {col} vs {}",
                hx.column(k)
            );
        }
        // Moving the whole window is unobservable (the position columns of
        // all the views sum to zero, axis by axis), and so is a turn of the
        // whole world about gravity (C5 at the views' first estimates):
        // δθ_i = ĝ, δp_i = −[p_i^FE]× ĝ, exactly. Both here, with the first
        // estimates away from the current positions, and with the landmark
        // off the mean bearing (noisy bearings).
        let g = Vector3::z();
        let yaw_of = |vs: &[View]| {
            let mut yaw = DVector::zeros(6 * vs.len());
            for (i, v) in vs.iter().enumerate() {
                yaw.rows_mut(6 * i, 3).copy_from(&g);
                yaw.rows_mut(6 * i + 3, 3).copy_from(&(-skew(&v.p_lin_in_W) * g));
            }
            yaw
        };
        let mut moved = views.clone();
        for (i, v) in moved.iter_mut().enumerate() {
            v.p_lin_in_W += Vector3::new(0.4 - 0.1 * i as f64, 0.05 * i as f64, 0.2);
        }
        let mut noisy = obs.clone();
        for (i, o) in noisy.iter_mut().enumerate() {
            o.xn += Vector2::new(0.004, -0.003) * if i % 2 == 0 { 1.0 } else { -1.0 };
        }
        for (vs, os) in [(&views, &obs), (&moved, &obs), (&views, &noisy), (&moved, &noisy)] {
            let rows = low_parallax_system(vs, &e, os, prior(p_f), 0.1).unwrap();
            let leak = (&rows.hx * yaw_of(vs)).norm();
            assert!(leak < 1e-12 * rows.hx.norm(), "yaw: {leak} of {}", rows.hx.norm());
            for axis in 0..3 {
                let sum: DVector<f64> = (0..vs.len())
                    .map(|i| rows.hx.column(6 * i + 3 + axis).into_owned())
                    .sum();
                assert!(sum.norm() < 1e-9 * rows.hx.norm(), "axis {axis}: {}", sum.norm());
            }
        }
        // Remembered at 5 m, truly at 4 m, 10 m or at infinity: the
        // residual is about |1 − 5/d| / κ sigmas, never more.
        for d in [4.0, 10.0, 1e6] {
            let r = low_parallax_system(&views, &e, &obs_of(&along(d)), prior(p_f), 0.1)
                .unwrap()
                .r;
            let sigmas = (1.0 - 5.0 / d).abs() / kappa;
            assert!(
                r.norm() < 1.05 * sigmas + 1e-3,
                "{d} m: |r| = {} for {sigmas}",
                r.norm()
            );
            assert!(r.norm() > 0.5 * sigmas, "{d} m: |r| = {} for {sigmas}", r.norm());
        }
        // Degenerate input is refused, never a panic.
        let mut nan = obs.clone();
        nan[3].xn.y = f64::NAN;
        assert!(low_parallax_system(&views, &e, &nan, prior(p_f), 0.1).is_err());
        let nowhere = Vector3::new(f64::NAN, 0.0, 0.0);
        assert!(low_parallax_system(&views, &e, &obs, prior(nowhere), 0.1).is_err());
        assert!(low_parallax_system(&views, &e, &obs[..1], prior(p_f), 0.1).is_err());
        // Remembered beside the bearing (a reused id): 10 m to the side and
        // 0.35 m ahead would lend the nearest depth of all.
        let beside = c0 + r_wc * Vector3::new(10.0, 0.0, 0.35);
        assert_eq!(
            low_parallax_system(&views, &e, &obs, prior(beside), 0.1).map(|_| ()),
            Err(Reject::BadDepth)
        );
        // Remembered behind the views.
        assert_eq!(
            low_parallax_system(&views, &e, &obs, prior(along(-5.0)), 0.1).map(|_| ()),
            Err(Reject::BadDepth)
        );
    }
}
