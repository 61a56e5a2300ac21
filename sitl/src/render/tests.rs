use super::*;
use crate::config::SimConfig;
use crate::trajectory::{racetrack, GustField, RacetrackParams};

fn setup(duration_s: f64) -> (crate::trajectory::Trajectory, Renderer) {
    let traj = racetrack(&RacetrackParams::default(), duration_s, 0.0, &GustField::default());
    let cfg = SimConfig::new();
    let world = World::around(&traj, 1);
    let r = Renderer::new(world, Camera::from_config(&cfg.camera), RenderConfig::default());
    (traj, r)
}

#[test]
fn every_pixels_world_point_projects_back_to_it() {
    let (traj, r) = setup(10.0);
    let T_W_C = r.camera_pose(&traj.sample(3.0));
    let mut hits = 0;
    for k in 0..400 {
        let uv = [(k * 37 % 752) as f64 + 0.25, (k * 53 % 480) as f64 + 0.5];
        let Some(hit) = r.surface_point(&T_W_C, uv) else {
            continue;
        };
        hits += 1;
        let back = r.project(&T_W_C, &hit.p_in_W).expect("a hit is in view");
        assert!((back[0] - uv[0]).hypot(back[1] - uv[1]) < 1e-6, "{uv:?} -> {back:?}");
    }
    assert!(hits > 200, "only {hits} of 400 pixels see a surface");
}

#[test]
fn blocks_stand_clear_of_the_path_and_in_view_of_it() {
    let (traj, r) = setup(70.0);
    let blocks = &r.world.blocks;
    assert!(blocks.len() > 100, "{} blocks", blocks.len());
    for t in (0..700).map(|k| k as f64 * 0.1) {
        let p = traj.sample(t).p_B_in_W;
        for b in blocks {
            let dx = (b.min.x - p.x).max(p.x - b.max.x).max(0.0);
            let dy = (b.min.y - p.y).max(p.y - b.max.y).max(0.0);
            assert!(
                dx.hypot(dy) >= 4.9,
                "block within {} m of the path at {t} s",
                dx.hypot(dy)
            );
        }
    }
}

#[test]
fn images_are_textured_below_the_horizon_deterministic_and_noisy() {
    let (traj, mut r) = setup(10.0);
    let T_W_C = r.camera_pose(&traj.sample(2.0));
    let (mut a, mut b, mut c) = (Vec::new(), Vec::new(), Vec::new());
    r.render(&[T_W_C], 1, &mut a);
    r.render(&[T_W_C], 1, &mut b);
    r.render(&[T_W_C], 2, &mut c);
    assert_eq!(a.len(), 752 * 480);
    assert_eq!(a, b, "same pose and seed, same image");
    let diff: f64 = a
        .iter()
        .zip(&c)
        .map(|(x, y)| (f64::from(*x) - f64::from(*y)).powi(2))
        .sum::<f64>()
        / a.len() as f64;
    // Two draws of noise with σ = 2 grey levels differ by σ√2 (less the clamp).
    assert!(
        (diff.sqrt() - 2.0 * 2f64.sqrt()).abs() < 0.3,
        "noise {:.2}",
        diff.sqrt()
    );
    let spread = |rows: std::ops::Range<usize>| {
        let v: Vec<f64> = rows
            .flat_map(|y| (0..752).map(move |x| (x, y)))
            .map(|(x, y)| f64::from(a[y * 752 + x]))
            .collect();
        let m = v.iter().sum::<f64>() / v.len() as f64;
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
    };
    let (ground, top) = (spread(380..480), spread(0..20));
    assert!(ground > 15.0, "ground σ {ground:.1} grey levels");
    assert!(top < ground, "top rows σ {top:.1} against the ground's {ground:.1}");
}

#[test]
fn motion_blur_smooths_the_image() {
    let (traj, r) = setup(10.0);
    let quiet = RenderConfig {
        noise_grey: 0.0,
        ..RenderConfig::default()
    };
    let mut r = Renderer::new(r.world, r.cam, quiet);
    let poses: Vec<_> = (0..4)
        .map(|k| r.camera_pose(&traj.sample(2.0 + 0.01 * k as f64)))
        .collect();
    let (mut sharp, mut blurred) = (Vec::new(), Vec::new());
    r.render(&poses[..1], 1, &mut sharp);
    r.render(&poses, 1, &mut blurred);
    let grad = |img: &[u8]| -> f64 {
        // Flying forward, the ground below moves down the image.
        (380..479)
            .flat_map(|y| (0..752).map(move |x| (x, y)))
            .map(|(x, y)| (f64::from(img[(y + 1) * 752 + x]) - f64::from(img[y * 752 + x])).abs())
            .sum()
    };
    assert!(
        grad(&blurred) < 0.9 * grad(&sharp),
        "{} vs {}",
        grad(&blurred),
        grad(&sharp)
    );
}

/// Vignetting keeps `cos(θ)^p` of each pixel's light, and the gain flicker
/// scales a whole frame, drawn from the frame's seed.
#[test]
fn vignetting_darkens_the_corners_and_the_gain_scales_a_frame() {
    let (traj, r) = setup(10.0);
    let T_W_C = r.camera_pose(&traj.sample(3.0));
    let plain = RenderConfig {
        noise_grey: 0.0,
        ..RenderConfig::default()
    };
    let mut flat = Renderer::new(r.world.clone(), r.cam.clone(), plain.clone());
    let mut vig = Renderer::new(
        r.world.clone(),
        r.cam.clone(),
        RenderConfig {
            vignetting_cos_power: 4.0,
            ..plain.clone()
        },
    );
    let (mut a, mut b) = (Vec::new(), Vec::new());
    flat.render(&[T_W_C], 1, &mut a);
    vig.render(&[T_W_C], 1, &mut b);
    // Lower-left corner (ground) against its own unvignetted grey.
    let k = 470 * 752 + 10;
    let want = f64::from(a[k]) * f64::from(vig.vignette[k]);
    assert!(vig.vignette[k] < 0.5, "corner keeps {}", vig.vignette[k]);
    assert!((f64::from(b[k]) - want).abs() <= 1.0, "{} vs {want}", b[k]);
    let centre = 240 * 752 + 376;
    assert!(vig.vignette[centre] > 0.99);

    let mut flicker = Renderer::new(
        r.world.clone(),
        r.cam.clone(),
        RenderConfig {
            gain_flicker: 0.05,
            ..plain
        },
    );
    let mean = |img: &[u8]| img.iter().map(|&g| f64::from(g)).sum::<f64>() / img.len() as f64;
    let ratios: Vec<f64> = (1..=8)
        .map(|seed| {
            flicker.render(&[T_W_C], seed, &mut b);
            mean(&b) / mean(&a)
        })
        .collect();
    assert!(ratios.iter().all(|r| (r - 1.0).abs() < 0.25), "{ratios:?}");
    assert!(ratios.iter().any(|r| (r - 1.0).abs() > 0.01), "{ratios:?}");
}

/// Each edge's blur is measured across its own image line: the footprints
/// match the image Jacobian of a pinhole camera looking along the ray
/// (central differences), from square-on to grazing, ground and walls,
/// straight and diagonal views.
#[test]
fn edge_footprints_match_the_image_jacobian_across_each_edge() {
    use super::world::footprint;
    let (f_px, range_m): (f64, f64) = (458.0, 5.0);
    let views = [
        (Vector3::<f64>::new(0.0, 0.0, 1.0), Vector3::z(), (0, 1)),
        (Vector3::new(0.94, 0.0, 0.33), Vector3::z(), (0, 1)),
        (Vector3::new(0.7, 0.7, 0.14), Vector3::z(), (0, 1)),
        (Vector3::new(0.3, -0.9, 0.1), Vector3::z(), (0, 1)),
        (Vector3::new(0.8, 0.5, -0.2), Vector3::x(), (1, 2)),
        (Vector3::new(0.2, 0.9, 0.3), Vector3::y(), (0, 2)),
    ];
    for (d, n, (u, v)) in views {
        let d: Vector3<f64> = d.normalize();
        // The camera: optical axis along the ray, the hit on it.
        let z_c = d;
        let x_c = (if d.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() })
            .cross(&z_c)
            .normalize();
        let y_c = z_c.cross(&x_c);
        let proj = |p: &Vector3<f64>| {
            nalgebra::Vector2::new(f_px * p.dot(&x_c) / p.dot(&z_c), f_px * p.dot(&y_c) / p.dot(&z_c))
        };
        let hit = d * range_m;
        let h = 1e-5;
        let jac = |k: usize| {
            let mut e = Vector3::zeros();
            e[k] = h;
            (proj(&(hit + e)) - proj(&(hit - e))) / (2.0 * h)
        };
        let (ju, jv) = (jac(u), jac(v));
        let det = (ju.x * jv.y - ju.y * jv.x).abs();
        // Surface metres of u (v) that one image pixel across an edge of
        // constant u (v) spans.
        let (across_u, across_v) = (jv.norm() / det, ju.norm() / det);
        let fp = footprint(range_m / f_px, &d, &n, (u, v));
        for (got, want) in [(fp.edge_m[0], across_u), (fp.edge_m[1], across_v)] {
            assert!((got - want).abs() < 1e-6 * want, "d {d:?}: {got} m against {want} m");
        }
        // Detail fades over the largest: the footprint along the steepest
        // foreshortening, 1 / the Jacobian's smallest singular value.
        let jm = nalgebra::Matrix2::from_columns(&[ju, jv]);
        let smallest = jm.singular_values().min();
        assert!(
            (fp.fade_m - 1.0 / smallest).abs() < 1e-6 * fp.fade_m,
            "d {d:?}: fade {}",
            fp.fade_m
        );
    }
}

#[test]
fn a_route_keeps_its_blocks_clear_and_an_empty_one_gives_the_ground_alone() {
    // A 10 m box: every block at least the clearance from each point.
    let route: Vec<[f64; 2]> = (0..=40)
        .map(|k| {
            let s = f64::from(k) * 1.0;
            match k {
                0..=10 => [s, 0.0],
                11..=20 => [10.0, s - 10.0],
                21..=30 => [30.0 - s, 10.0],
                _ => [0.0, 40.0 - s],
            }
        })
        .collect();
    let w = World::around_path(&route, 1);
    assert!(!w.blocks.is_empty());
    for b in &w.blocks {
        for p in &route {
            let dx = (p[0] - (b.min.x + b.max.x) / 2.0).abs() - (b.max.x - b.min.x) / 2.0;
            let dy = (p[1] - (b.min.y + b.max.y) / 2.0).abs() - (b.max.y - b.min.y) / 2.0;
            assert!(
                dx.max(0.0).hypot(dy.max(0.0)) >= 5.0 - 1e-9,
                "a block within 5 m of the route"
            );
        }
    }
    assert!(World::around_path(&[], 1).blocks.is_empty());
}
