//! FR3 kinematics against a peer's model (MuJoCo on franky-sim's FR3), against itself (Jacobian vs finite
//! differences, IK round trips), and against bad targets (unreachable, singular, not finite: a reason, never a NaN).

use mars_kinematics::{Arm, IkError, IkParams, Joints, Plane, Pose, flange_pose, jacobian, solve};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng, rngs::StdRng};

fn random_q(arm: &Arm, rng: &mut StdRng, margin: f64) -> Joints {
    Joints::from_fn(|i, _| rng.random_range(arm.q_min[i] + margin..arm.q_max[i] - margin))
}

/// 64 configurations over the model's joint ranges (`tests/fixtures/fr3_mujoco_poses.py` says how they were made):
/// our DH table and MuJoCo's body tree agree on the flange to 1e-9.
#[test]
fn the_flange_pose_agrees_with_mujoco_on_franky_sims_fr3_model() {
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/fr3_mujoco_poses.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let arm = Arm::fr3();
    let poses = v["poses"].as_array().unwrap();
    assert_eq!(poses.len(), 64);
    let f = |x: &serde_json::Value| -> Vec<f64> { x.as_array().unwrap().iter().map(|y| y.as_f64().unwrap()).collect() };
    let (mut worst_p, mut worst_r) = (0.0f64, 0.0f64);
    for p in poses {
        let q = Joints::from_row_slice(&f(&p["q"]));
        let ours = flange_pose(&arm, &q);
        let pos = Vector3::from_row_slice(&f(&p["position"]));
        let rot = UnitQuaternion::from_matrix(&Matrix3::from_row_slice(&f(&p["rotation"])));
        worst_p = worst_p.max((ours.translation.vector - pos).norm());
        worst_r = worst_r.max(ours.rotation.angle_to(&rot));
    }
    eprintln!("64 poses: worst {worst_p:e} m, {worst_r:e} rad");
    assert!(worst_p < 1e-9 && worst_r < 1e-9, "{worst_p} m, {worst_r} rad");
}

/// libfranka's examples' start pose [0, −π/4, 0, −3π/4, 0, π/2, π/4]: the flange 0.307 m out and 0.590 m up,
/// pointing down (with a Franka Hand, whose TCP is 0.1034 m further, `O_T_EE` reads z = 0.487 there).
#[test]
fn the_start_pose_puts_the_flange_where_franka_documents_it() {
    let p = flange_pose(&Arm::fr3(), &start_pose());
    let t = p.translation.vector;
    assert!((t - Vector3::new(0.3069, 0.0, 0.5903)).norm() < 2e-4, "{t}");
    assert!((p.rotation * Vector3::z() + Vector3::z()).norm() < 1e-9, "flange z axis {}", p.rotation * Vector3::z());
}

/// The Jacobian is the derivative of the flange pose: each column against central differences.
#[test]
fn the_jacobian_is_the_derivative_of_the_flange_pose() {
    let arm = Arm::fr3();
    let mut rng = StdRng::seed_from_u64(3);
    let h = 1e-6;
    for _ in 0..50 {
        let q = random_q(&arm, &mut rng, 0.0);
        let (pose, j) = jacobian(&arm, &q);
        for i in 0..7 {
            let (mut up, mut down) = (q, q);
            up[i] += h;
            down[i] -= h;
            let (pu, pd) = (flange_pose(&arm, &up), flange_pose(&arm, &down));
            let v = (pu.translation.vector - pd.translation.vector) / (2.0 * h);
            let w = (pu.rotation * pd.rotation.inverse()).scaled_axis() / (2.0 * h);
            assert!((v - j.fixed_view::<3, 1>(0, i)).norm() < 1e-6, "joint {i} linear at {q:?}, {pose:?}");
            assert!((w - j.fixed_view::<3, 1>(3, i)).norm() < 1e-6, "joint {i} angular");
        }
    }
}

/// Random reachable poses (the flange pose of random configurations inside the limits): from a seed near the
/// answer (the servo seeds with the previous solution) every one is reached within the tolerances, in ~3
/// iterations; from the start pose, most (239 of 300 here: a far seed may settle against the joint limits or in
/// another arm configuration's basin, and then it says so).
#[test]
fn reachable_poses_round_trip() {
    let arm = Arm::fr3();
    let params = IkParams::default();
    let mut rng = StdRng::seed_from_u64(11);
    let home = start_pose();
    let (mut near_ok, mut far_ok, mut iterations) = (0, 0, 0);
    let n = 300;
    for _ in 0..n {
        let q = random_q(&arm, &mut rng, 0.1);
        let target = flange_pose(&arm, &q);
        let seed = q + Joints::from_fn(|_, _| rng.random_range(-0.2..0.2));
        if let Ok(s) = solve(&arm, &target, &seed, &params) {
            let at = flange_pose(&arm, &s.q);
            assert!((at.translation.vector - target.translation.vector).norm() <= params.position_tolerance * 1.0001);
            assert!(at.rotation.angle_to(&target.rotation) <= params.orientation_tolerance * 1.0001);
            near_ok += 1;
            iterations += s.iterations;
        }
        match solve(&arm, &target, &home, &params) {
            Ok(_) => far_ok += 1,
            Err(IkError::Unreachable { closest, .. }) => assert!(closest.iter().all(|x| x.is_finite())),
            Err(e) => panic!("{e}"),
        }
    }
    eprintln!(
        "{n} poses: from a near seed {near_ok} reached (mean {} iterations), from the start pose {far_ok}",
        iterations / near_ok.max(1)
    );
    assert_eq!(near_ok, n);
    assert!(far_ok * 10 >= n * 7, "{far_ok} of {n} from the start pose");
}

/// A pushing policy's path on a table plane (the flange 0.25 m up, pointing down): each point reached from the
/// previous solution, as the servo would, with the flange on the plane and pointing down at every point.
#[test]
fn a_planar_path_is_followed_point_by_point() {
    let arm = Arm::fr3();
    let params = IkParams::default();
    let plane = Plane::pointing_down(0.25);
    let mut q = start_pose();
    let mut reached = 0;
    for k in 0..=200 {
        let s = k as f64 / 200.0;
        let (x, y) =
            (0.45 + 0.15 * (2.0 * std::f64::consts::PI * s).cos(), 0.2 * (2.0 * std::f64::consts::PI * s).sin());
        let target = plane.pose(x, y);
        let sol = solve(&arm, &target, &q, &params).unwrap_or_else(|e| panic!("point {k} ({x:.3}, {y:.3}): {e}"));
        let at = flange_pose(&arm, &sol.q);
        let (ax, ay) = Plane::xy(&at);
        assert!((ax - x).hypot(ay - y) < 1e-4 && (at.translation.z - 0.25).abs() < 1e-4, "point {k}");
        assert!((at.rotation * Vector3::z() + Vector3::z()).norm() < 1e-3, "point {k}: not pointing down");
        q = sol.q;
        reached += 1;
    }
    assert_eq!(reached, 201);
}

/// Targets out of reach, beyond a stretched (singular) arm, or anywhere at random with random seeds: the solver
/// returns a solution within the joint limits, or refuses with how far off the closest configuration is — never a
/// NaN, never a joint outside its limits.
#[test]
fn bad_targets_are_refused_with_a_reason_and_never_a_nan() {
    let arm = Arm::fr3();
    let params = IkParams::default();
    let home = start_pose();
    let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    // 2 m away: out of reach.
    let far = Pose::from_parts(Vector3::new(2.0, 0.0, 0.5).into(), down);
    match solve(&arm, &far, &home, &params) {
        Err(IkError::Unreachable { position_error, closest, .. }) => {
            assert!(position_error > 1.0, "{position_error}");
            assert!(closest.iter().all(|x| x.is_finite()));
        }
        other => panic!("{other:?}"),
    }
    // Straight up past the stretched arm (the singular edge of the workspace).
    let up = Pose::from_parts(Vector3::new(0.0, 0.0, 1.3).into(), UnitQuaternion::identity());
    assert!(matches!(solve(&arm, &up, &home, &params), Err(IkError::Unreachable { .. })));
    // Not finite.
    let nan = Pose::from_parts(Vector3::new(f64::NAN, 0.0, 0.5).into(), down);
    assert_eq!(solve(&arm, &nan, &home, &params), Err(IkError::NotFinite("target pose")));
    let mut bad_seed = home;
    bad_seed[2] = f64::INFINITY;
    assert_eq!(solve(&arm, &flange_pose(&arm, &home), &bad_seed, &params), Err(IkError::NotFinite("seed")));
    // Anything at random.
    let mut rng = StdRng::seed_from_u64(13);
    let within = |q: &Joints| (0..7).all(|i| q[i].is_finite() && q[i] >= arm.q_min[i] && q[i] <= arm.q_max[i]);
    for _ in 0..300 {
        let p = Vector3::new(rng.random_range(-1.2..1.2), rng.random_range(-1.2..1.2), rng.random_range(-0.5..1.5));
        let r = UnitQuaternion::from_euler_angles(
            rng.random_range(-3.0..3.0),
            rng.random_range(-3.0..3.0),
            rng.random_range(-3.0..3.0),
        );
        let seed = random_q(&arm, &mut rng, 0.0);
        match solve(&arm, &Pose::from_parts(p.into(), r), &seed, &params) {
            Ok(s) => assert!(within(&s.q)),
            Err(IkError::Unreachable { closest, position_error, orientation_error, .. }) => {
                assert!(within(&closest) && position_error.is_finite() && orientation_error.is_finite());
            }
            Err(e) => panic!("{e}"),
        }
    }
}

/// libfranka's examples' start pose [0, −π/4, 0, −3π/4, 0, π/2, π/4].
fn start_pose() -> Joints {
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};
    Joints::from_row_slice(&[0.0, -FRAC_PI_4, 0.0, -3.0 * FRAC_PI_4, 0.0, FRAC_PI_2, FRAC_PI_4])
}
