//! Tests of the trajectories: the racetrack's length and speed, banked turns
//! and a level hover start, the historical scenarios without a standstill bit
//! for bit, an exact rest on the ground before take-off, and a smooth take-off.

use super::*;

#[test]
fn racetrack_is_about_a_kilometre_at_fifteen_mps() {
    let tr = racetrack(&RacetrackParams::default(), 200.0, 0.0, &GustField::default());
    let mut len = 0.0;
    let mut prev = tr.sample(0.0).p_B_in_W;
    let mut speeds = Vec::new();
    let mut t = 0.0;
    while t < 200.0 {
        t += 0.05;
        let s = tr.sample(t);
        len += (s.p_B_in_W - prev).xy().norm();
        prev = s.p_B_in_W;
        speeds.push(s.v_B_in_W.norm());
    }
    let lap_s = 992.0 / 15.0;
    assert!(
        (len / (200.0 / lap_s) - 992.0).abs() < 15.0,
        "lap length {}",
        len / (200.0 / lap_s)
    );
    let (lo, hi) = speeds
        .iter()
        .fold((f64::MAX, 0.0f64), |(l, h), &v| (l.min(v), h.max(v)));
    assert!(lo > 14.5 && hi < 15.5, "speed range {lo}..{hi}");
    // It revisits the start after one lap.
    let again = tr.sample(lap_s).p_B_in_W;
    assert!(again.xy().norm() < 3.0, "{again}");
}

#[test]
fn banked_turns_and_level_start_for_hover() {
    let tr = hover(30.0, 0.0, &GustField::default());
    let s = tr.sample(1.0);
    assert!(s.v_B_in_W.norm() < 1e-9 && s.w_B.norm() < 1e-9);
    let z_b = s.q_W_B * Vector3::z();
    assert!((z_b - Vector3::z()).norm() < 1e-9);
    let rt = racetrack(&RacetrackParams::default(), 70.0, 0.0, &GustField::default());
    // In a turn the body tilts into it (the thrust has a horizontal part).
    let mut max_tilt: f64 = 0.0;
    for k in 0..700 {
        let s = rt.sample(k as f64 * 0.1);
        let z = s.q_W_B * Vector3::z();
        max_tilt = max_tilt.max(z.z.acos());
    }
    assert!(
        max_tilt.to_degrees() > 10.0 && max_tilt.to_degrees() < 40.0,
        "{}",
        max_tilt.to_degrees()
    );
}

/// Samples of the scenarios as they were before the standstill existed
/// (printed by the previous code at full precision).
#[rustfmt::skip]
#[allow(clippy::type_complexity, clippy::excessive_precision)]
const BEFORE_STANDSTILL: [(&str, f64, [f64; 3], [f64; 3], [f64; 3], [f64; 4], [f64; 3]); 18] = [
    ("racetrack", 0.0, [0.010140584890256727, 0.0012118611914621186, -5.000193146606438], [14.999960839551193, 0.00032768193415933823, -0.2857026056647767], [-1.0589328724108782e-5, 0.48470736576836093, 3.158259389124396e-6], [0.024682836983249152, 9.57721604673112e-6, 0.000387809625538451, 0.9996952571010979], [2.9445590001843758e-5, 0.0007974636153889338, 0.016137764627715115]),
    ("racetrack", 0.37, [5.559993091205634, 0.03451556753804944, -5.105863450579064], [14.99888415076434, 0.1797152195684478, -0.2853815962213446], [-0.0058125159355526534, 0.48507822804426004, 0.0017323675863778476], [0.0247074628800635, 0.00014804809036303426, 0.005988984307570548, 0.9996767734756854], [0.0002463300602674454, 0.001597861843539416, 0.03230245147134805]),
    ("racetrack", 3.3, [49.4136251386594, 2.6687075961345212, -5.9147472915952415], [14.910787776787974, 1.6331145745322189, -0.2598488668199219], [-0.056464623941451464, 0.5155032933097843, 0.01591767204581629], [0.026408358343853838, 0.0014422204489690485, 0.054501127808316154, 0.9981633862636823], [0.0022301499325698576, 0.0018283932984384601, 0.03452548682894321]),
    ("racetrack", 12.9, [183.8409034341901, 49.0891488618597, -6.692178620861613], [11.600876124657077, 9.507887357595486, 0.24368155059313956], [-1.2600380269436755, 1.536798309723622, 0.11247024516542581], [0.09502488887498801, 0.03400164710409268, 0.3349098288322362, 0.9368295282707877], [0.058548305869827164, 0.026658637033748347, 0.12983714255695775]),
    ("racetrack", 41.7, [-127.1932584949134, 170.58998259985097, -6.927657114980656], [-14.182486803001488, -4.884031178950565, -0.09038396562368778], [0.2648478136406993, -0.7689845813192733, 0.05140199752631247], [-0.006864211164943227, 0.04099761316287122, 0.9854284073933055, -0.16493311438981534], [0.011491179189076413, 0.004506528325761782, 0.054040016787257616]),
    ("racetrack", 69.9, [55.814680423527314, 3.418239268720146, -6.024855847958492], [14.884622837741414, 1.8565036264129025, -0.25253160468593894], [-0.06543176224579383, 0.5245670042200601, 0.01815313329937851], [-0.02691322657576131, -0.0016723133669577176, -0.06198249296377397, -0.9977129106958974], [0.002593414047064228, 0.0019002745146731242, 0.03519242469243521]),
    ("figure8", 0.0, [2.0816681711721685e-17, 2.2551405187698492e-17, -6.0], [6.282496314069229, 6.280429757803897, -0.15707532630727128], [7.105427357601002e-15, 3.552713678800501e-15, 8.526512829121202e-14], [-0.001085120290294982, 0.0008037574905413125, 0.3825656667024976, 0.9239273170267917], [-0.029785434222208335, 0.04961379918621198, -0.0020928022827667856]),
    ("figure8", 0.37, [2.3221978328573467, 2.3144672309713252, -6.0581033299930365], [6.263642223920045, 6.205151331534978, -0.15695743431002052], [-0.10186299533467746, -0.4060955724756852, 0.0006371743126862839], [-0.017151526247262072, 0.012656584799221472, 0.3801575936450558, 0.9246760730129281], [-0.059072651835797026, 0.09775280897060294, -0.026781224835113478]),
    ("figure8", 3.3, [19.12062275890339, 14.727846892749906, -6.508092950507538], [4.840746607680401, 1.1768351841806055, -0.1477891537997138], [-0.8387243670365478, -2.58414263347575, 0.005571862689635054], [-0.12274665145744312, 0.055485439573013905, 0.10947893569561343, 0.9848192667643796], [-0.01444632340221065, 0.024399909985810597, -0.45845372914208576]),
    ("figure8", 12.9, [12.771978060911417, -11.552629905376243, -7.463835010453373], [-5.684572621987894, 4.00329659355576, -0.034264920824090606], [-0.5602416485079402, 2.027020221261978, 0.016052747179898574], [-0.05699500030186637, 0.08879906780420989, -0.9496921673276847, -0.2948746900195714], [0.04261350121372491, 0.05894189946551206, -0.20000002103678008]),
    ("figure8", 41.7, [19.120622758903373, -14.727846892749904, -4.588717538244383], [-4.840746607680355, 1.1768351841805922, 0.053207369355177336], [-0.8387243670350699, 2.584142633475466, -0.015476443995410705], [-0.055376363617902456, 0.12249642377982849, -0.9848524411173649, -0.10951599763859934], [0.014395523567405607, 0.024340552800548833, -0.45847599611049916]),
    ("figure8", 69.9, [26.28631761542549, -12.659364564532504, -7.291077644361699], [-3.026615681833375, -3.365222548214846, -0.07995784648290716], [-1.153046915974926, 2.2212074801015262, 0.014158250668160122], [-0.008159275211325487, 0.12445114352059183, -0.9084839985193325, 0.398876125556254], [-0.02852549397873504, 0.0514063363503258, -0.5077351740575724]),
    ("hover", 0.0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
    ("hover", 0.37, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
    ("hover", 3.3, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
    ("hover", 12.9, [2.270636492800005, 0.0, -3.0], [2.6603880960000126, 0.0, 0.0], [1.0828799999996548, 0.0, 4.973799150320701e-14], [-0.0038751217377371123, -0.05465938978757232, 0.07121188434415819, 0.9959549196965305], [0.02269783749706254, 0.1574028532965399, 0.16479177438958928]),
    ("hover", 41.7, [0.0, 0.0, -3.0], [0.0, 0.0, 3.774758283725532e-15], [0.0, 0.0, 4.973799150320701e-14], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
    ("hover", 69.9, [0.0, 2.116643558399994, -3.0], [0.0, -2.13295507200002, 0.0], [0.0, 0.5598720000016364, 4.973799150320701e-14], [0.025775869665832833, -0.011987060566264127, 0.4262767860572406, 0.904146015083106], [0.0853394259016436, -0.10379284072152167, -0.8926330819828099]),
];

#[test]
fn no_standstill_is_the_historical_trajectory_bit_for_bit() {
    for (name, t, p, v, a, q, w) in BEFORE_STANDSTILL {
        let s = Trajectory::from_scenario(name, Some(70.0), 0.0, &GustField::default())
            .unwrap()
            .sample(t);
        let c = s.q_W_B.coords;
        let got = [
            s.p_B_in_W.as_slice(),
            s.v_B_in_W.as_slice(),
            s.a_B_in_W.as_slice(),
            &[c.x, c.y, c.z, c.w][..],
            s.w_B.as_slice(),
        ]
        .concat();
        let want = [&p[..], &v[..], &a[..], &q[..], &w[..]].concat();
        assert_eq!(got, want, "{name} at {t} s");
    }
}

#[test]
fn standstill_is_exactly_at_rest_level_on_the_ground_then_takes_off() {
    let standstill_s = 5.0;
    for name in ["racetrack", "figure8", "hover"] {
        let tr = Trajectory::from_scenario(name, Some(40.0), standstill_s, &GustField::default()).unwrap();
        let mut t = -0.3;
        while t < standstill_s {
            let s = tr.sample(t);
            assert_eq!(s.p_B_in_W.norm(), 0.0, "{name} at {t}: {}", s.p_B_in_W);
            assert_eq!(s.v_B_in_W.norm(), 0.0, "{name} at {t}: {}", s.v_B_in_W);
            assert_eq!(s.a_B_in_W.norm(), 0.0, "{name} at {t}: {}", s.a_B_in_W);
            assert_eq!(s.w_B.norm(), 0.0, "{name} at {t}: {}", s.w_B);
            let z_b = s.q_W_B * Vector3::z();
            assert!((z_b - Vector3::z()).norm() < 1e-12, "{name} not level at {t}");
            t += 0.01;
        }
        // It has left the ground a few seconds after the take-off.
        let s = tr.sample(takeoff_start_s(standstill_s) + 2.0);
        assert!(s.p_B_in_W.z < -0.5 && s.v_B_in_W.norm() > 0.3, "{name}: {s:?}");
    }
    // The racetrack reaches its 15 m/s and its 5 m height after the
    // take-off, and keeps them.
    let tr = Trajectory::from_scenario("racetrack", Some(70.0), standstill_s, &GustField::default()).unwrap();
    let t_full = takeoff_start_s(standstill_s) + TAKEOFF_S;
    let mut t = t_full;
    while t < 70.0 {
        let s = tr.sample(t);
        let v = s.v_B_in_W.norm();
        assert!(v > 14.5 && v < 15.5, "speed {v} at {t}");
        assert!(
            s.p_B_in_W.z < -2.5 && s.p_B_in_W.z > -7.5,
            "height at {t}: {}",
            s.p_B_in_W
        );
        t += 0.1;
    }
    let s = tr.sample(t_full);
    assert!((s.v_B_in_W.xy().norm() - 15.0).abs() < 0.05, "{}", s.v_B_in_W);
}

/// The take-off goes through the same quintic splines: acceleration and
/// body rate have no jumps (their steps over 1 ms stay within a
/// multirotor's jerk), and the yaw does not snap when it starts moving.
#[test]
fn takeoff_is_smooth() {
    let dt = 1e-3;
    for name in ["racetrack", "figure8", "hover"] {
        let tr = Trajectory::from_scenario(name, Some(25.0), 5.0, &GustField::default()).unwrap();
        let (mut max_jerk, mut max_w_dot, mut max_w) = (0.0f64, 0.0f64, 0.0f64);
        let mut prev = tr.sample(0.0);
        let mut t = dt;
        while t < 25.0 {
            let s = tr.sample(t);
            max_jerk = max_jerk.max((s.a_B_in_W - prev.a_B_in_W).norm() / dt);
            max_w_dot = max_w_dot.max((s.w_B - prev.w_B).norm() / dt);
            max_w = max_w.max(s.w_B.norm());
            prev = s;
            t += dt;
        }
        assert!(max_jerk < 5.0, "{name}: jerk {max_jerk} m/s³");
        assert!(max_w_dot < 5.0, "{name}: angular acceleration {max_w_dot} rad/s²");
        assert!(max_w < 1.5, "{name}: body rate {max_w} rad/s");
    }
}
