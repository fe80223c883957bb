//! The FR3 Pick Cup task: its config is checked with clear errors, the expert's demos are valid and balanced,
//! the episode monitor tells the modes apart without allocating, and the committed MARS checkpoint solves the
//! task in-process with both grasps.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::{Path, PathBuf};

use mars_hil::task::eval::evaluate;
use mars_hil::task::expert::generate_demos;
use mars_profile::Profile;
use mars_runtime::task::{DoneReason, Pick, Progress, TaskError, arm};

/// Counts this thread's heap allocations, so a test can assert that a call makes none.
struct CountingAlloc;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

fn allocations() -> usize {
    ALLOCATIONS.with(Cell::get)
}

#[test]
fn the_allocation_counter_sees_allocations() {
    let before = allocations();
    std::hint::black_box(vec![1u8; 16]);
    assert_eq!(allocations(), before + 1);
}

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path)
}

fn fr3() -> Profile {
    Profile::load(&repo("configs/fr3.toml")).expect("FR3 profile")
}

fn task_text() -> String {
    std::fs::read_to_string(repo("configs/pick_cup.toml")).expect("task file")
}

fn task() -> Pick {
    Pick::load(&repo("configs/pick_cup.toml"), &arm(&fr3())).expect("shipped task is valid")
}

/// The shipped pick tasks, each with its robot: (task, profile, committed checkpoints).
const SHIPPED: [(&str, &str, &str); 2] = [
    ("configs/pick_cup.toml", "configs/fr3.toml", "assets/checkpoints/fr3_pick_cup"),
    ("configs/pick_vegetable.toml", "configs/r1_lite.toml", "assets/checkpoints/r1_lite_pick_vegetable"),
];

fn shipped(task: &str, profile: &str) -> (Pick, Profile) {
    let p = Profile::load(&repo(profile)).expect("shipped profile");
    (Pick::load(&repo(task), &arm(&p)).expect("shipped task is valid"), p)
}

fn refusal(text: &str) -> String {
    match Pick::parse(text, "test.toml", &arm(&fr3())) {
        Err(e @ (TaskError::Invalid { .. } | TaskError::Parse { .. })) => e.to_string(),
        other => panic!("expected a refusal, got {other:?}"),
    }
}

#[test]
fn config_errors_name_the_field_and_the_problem() {
    let t = task_text().replace("q = [0.35, -0.1, 0.15, -2.15, 0.0, 2.05, 0.25]", "q = [0.35, -0.1, 0.15]");
    let e = refusal(&t);
    assert!(e.contains("grasps[0] (rim)") && e.contains("has 3 values but the fr3 has 7 joints"), "{e}");

    // Joint 3's upper limit is -0.1169: -0.2 is inside it, but not 0.2 rad inside.
    let t = task_text().replace("retreat = [0.0, -0.55, 0.0, -2.45,", "retreat = [0.0, -0.55, 0.0, -0.2,");
    let e = refusal(&t);
    assert!(e.contains("`retreat`") && e.contains("joint 3 = -0.2") && e.contains("0.2 rad margin"), "{e}");

    let e = refusal(&task_text().replace("policy_rate_hz = 10.0", "policy_rate_hz = 3.0"));
    assert!(e.contains("policy_rate_hz") && e.contains("must divide the profile's rate_hz"), "{e}");

    let e = refusal(&task_text().replace("waypoint_jitter = 0.01", "waypoint_jitter = 0.03"));
    assert!(e.contains("expert.waypoint_jitter") && e.contains("tolerance / 2"), "{e}");

    let e = refusal(&task_text().replace("gripper_closed = 0.02", "gripper_closed = 0.09"));
    assert!(e.contains("gripper_closed") && e.contains("gripper range"), "{e}");

    let handle = "q = [-0.35, -0.1, -0.15, -2.15, 0.0, 2.05, 1.35]";
    let e = refusal(&task_text().replace(handle, "q = [0.33, -0.1, 0.15, -2.15, 0.0, 2.05, 0.27]"));
    assert!(e.contains("modes would be ambiguous"), "{e}");

    let one_grasp = task_text().replace(&format!("[[grasps]]\nname = \"handle\"\n{handle}\n"), "");
    assert!(refusal(&one_grasp).contains("has 1 entries; a multimodal task needs at least 2"));

    let e = refusal(&format!("speed = 3\n{}", task_text()));
    assert!(e.contains("test.toml") && e.contains("speed"), "{e}");

    let e = Pick::load(Path::new("no/such/task.toml"), &arm(&fr3())).expect_err("missing file").to_string();
    assert!(e.contains("cannot read task no/such/task.toml"), "{e}");
}

#[test]
fn start_pose_observation_and_rest_action() {
    let t = task();
    let (a, b) = (t.start_pose(7), t.start_pose(8));
    assert_eq!(a, t.start_pose(7), "a seed gives one start");
    assert_ne!(a, b);
    for s in [&a, &b] {
        let d = s.iter().zip(&t.home).map(|(x, h)| (x - h).abs()).fold(0.0, f64::max);
        assert!(d <= t.cfg.start_jitter && d > 0.0, "jitter {d}");
    }
    let mut obs = [0.0f32; 8];
    t.observation(&a, 0.05, &mut obs);
    assert_eq!(obs[..7], a.iter().map(|&x| x as f32).collect::<Vec<_>>()[..]);
    assert_eq!(obs[7], 0.05);
    let rest = t.rest_action(&a);
    assert_eq!(rest.len(), 8);
    assert_eq!((rest[..7].to_vec(), rest[7]), (obs[..7].to_vec(), t.cfg.gripper_open as f32));
}

#[test]
fn expert_demos_are_valid_balanced_and_deterministic() {
    for (task, profile, _) in SHIPPED {
        let (t, p) = shipped(task, profile);
        expert_demos_check(&t, &p);
    }
}

fn expert_demos_check(t: &Pick, p: &Profile) {
    let demos = generate_demos(t, p, 20, 3).expect("demos");
    // Joints, then the gripper at index n.
    let n = t.joints();
    let g = n;
    let mut counts = [0usize; 2];
    let slot_s = 1.0 / t.cfg.policy_rate_hz;
    for d in &demos {
        let mode = d.mode.expect("every demo has a mode");
        counts[mode] += 1;
        assert_eq!(d.observations.len(), d.actions.len());
        assert!(d.observations.iter().chain(&d.actions).chain([&d.rest_action]).all(|v| v.len() == n + 1));
        // The first observation is the start the rest action says (to within the plant's noise).
        let gap = d.observations[0].iter().zip(&d.rest_action).map(|(o, r)| (o - r).abs()).fold(0.0, f32::max);
        assert!(gap < 1e-3, "first observation vs rest action: {gap}");
        // Independent of the expert's own check: targets inside the limits, interpolated speed below dq_max.
        let mut prev = d.rest_action.clone();
        for a in &d.actions {
            for i in 0..n {
                let q = a[i] as f64;
                assert!(q > p.q_min[i] + 0.19 && q < p.q_max[i] - 0.19, "{}: joint {i} at {q}", t.cfg.name);
                assert!(((a[i] - prev[i]) as f64).abs() / slot_s < p.dq_max[i]);
            }
            assert!((p.gripper_min..=p.gripper_max).contains(&(a[g] as f64)));
            prev = a.clone();
        }
        // It reaches its own grasp: some action lies on it and the gripper closes there.
        let grasp = &t.cfg.grasps[mode].q;
        let at_grasp = |a: &Vec<f32>| a.iter().zip(grasp).all(|(x, g)| (*x as f64 - g).abs() < t.cfg.tolerance);
        assert!(d.actions.iter().any(|a| at_grasp(a) && (a[g] as f64) < t.cfg.gripper_closed + 1e-3));
    }
    assert_eq!(counts, [10, 10]);
    // The modes fork after the shared approach: the same in the two joints where the grasps differ most before
    // (Pick Cup: 0 and 6; Pick Vegetable: 0 and 5), far apart at the grasp.
    let (a, b) = (&demos[0].actions, &demos[1].actions);
    for j in t.most_distinct_joints() {
        assert!((a[15][j] - b[15][j]).abs() < 0.1, "{}: joint {j} before the fork", t.cfg.name);
        assert!((a[40][j] - b[40][j]).abs() > 0.5, "{}: joint {j} at the grasps", t.cfg.name);
    }
    assert_eq!(generate_demos(t, p, 20, 3).expect("demos"), demos);
    assert_ne!(generate_demos(t, p, 20, 4).expect("demos"), demos);
}

#[test]
fn an_expert_too_fast_for_the_robot_is_refused() {
    let t = Pick::parse(&task_text().replace("grasp_s = 1.5", "grasp_s = 0.1"), "fast.toml", &arm(&fr3())).unwrap();
    let e = format!("{:#}", generate_demos(&t, &fr3(), 2, 0).expect_err("0.57 rad in 0.1 s is too fast"));
    assert!(e.contains("expert demo 0 (grasp `rim`) is invalid") && e.contains("velocity: true"), "{e}");
}

#[test]
fn monitor_tells_the_grasps_apart_and_ends_on_retreat_or_timeout() {
    let t = task();
    let (open, closed) = (t.cfg.gripper_open, t.cfg.gripper_closed);
    let retreat = t.cfg.retreat.clone();
    let mut m = t.monitor();
    for mode in 0..2 {
        let grasp = t.cfg.grasps[mode].q.clone();
        let mut near = grasp.clone();
        near[6] += 0.9 * t.cfg.tolerance;
        m.reset();
        assert_eq!(m.update(&t.home, open, 0.0), Progress::Running);
        assert_eq!(m.update(&t.cfg.pregrasp, open, 1.0), Progress::Running);
        assert_eq!(m.update(&retreat, closed, 1.5), Progress::Running, "retreat before a grasp is no success");
        let before = allocations();
        assert_eq!(m.update(&near, open, 2.0), Progress::Running);
        assert_eq!(m.grasped(), Some(mode));
        assert_eq!(m.update(&retreat, open, 3.0), Progress::Running, "retreating without the cup is not done");
        let done = m.update(&retreat, closed, 4.0);
        assert_eq!(allocations(), before, "update allocated");
        assert_eq!(done, Progress::Done { success: true, mode: Some(mode), reason: DoneReason::Retreated });
        assert_eq!(m.update(&t.home, open, 5.0), done, "done stays done");
    }

    m.reset();
    let mut just_outside = t.cfg.grasps[1].q.clone();
    just_outside[0] += 1.1 * t.cfg.tolerance;
    assert_eq!(m.update(&just_outside, open, 1.0), Progress::Running);
    let timeout = t.cfg.timeout_s;
    assert_eq!(m.update(&t.home, open, timeout - 1e-3), Progress::Running);
    let want = Progress::Done { success: false, mode: None, reason: DoneReason::Timeout };
    assert_eq!(m.update(&t.home, open, timeout), want);

    m.reset();
    m.update(&t.cfg.grasps[0].q, closed, 1.0);
    let want = Progress::Done { success: true, mode: Some(0), reason: DoneReason::Timeout };
    assert_eq!(m.update(&t.cfg.grasps[0].q, closed, timeout), want, "grasped but never retreated: success");

    m.reset();
    let mut nan = t.home.clone();
    nan[2] = f64::NAN;
    let want = Progress::Done { success: false, mode: None, reason: DoneReason::InvalidState };
    assert_eq!(m.update(&nan, open, 0.1), want);
}

#[test]
fn committed_mars_checkpoint_solves_the_task_with_both_grasps() {
    for (task, profile, checkpoints) in SHIPPED {
        let (t, p) = shipped(task, profile);
        let dir = repo(checkpoints).join("mars");
        let report = evaluate(&dir, &t, &p, 10, 1000).expect("evaluation runs");
        println!("{task}: {report}");
        assert!(report.successes >= 9, "{task}: {report}");
        assert!(report.mode_counts.iter().all(|&c| c >= 2), "{task}: both grasps used: {report}");
        let k_max = mars_policy::checkpoint::load_meta(&dir).expect("checkpoint meta").model.k_max as f32;
        assert!(report.mean_k >= 1.0 && report.mean_k < 0.75 * k_max, "{task}: fewer ODE steps than FM's: {report}");
        assert_eq!(report.limit_violations, 0, "{task}: {report}");
        // Every call was timed, and the report's p50 and p99 are those times' nearest-rank percentiles (the run's
        // first calls, caches warming up, left out).
        assert!(report.episodes.iter().all(|e| e.call_ms.len() == e.k_per_call.len() && !e.call_ms.is_empty()));
        let all: Vec<f64> = report.episodes.iter().flat_map(|e| e.call_ms.iter().copied()).collect();
        let timed: Vec<f64> = all
            .iter()
            .skip(mars_tasks::nav2d::eval::WARMUP_CALLS)
            .map(|&m| std::time::Duration::from_secs_f64(m / 1e3).as_secs_f64() * 1e3)
            .collect();
        assert_eq!(report.call_p50_ms, Some(nearest_rank(&timed, 0.50)), "{task}: p50 of {timed:?}");
        assert_eq!(report.call_p99_ms, Some(nearest_rank(&timed, 0.99)), "{task}: p99 of {timed:?}");
    }
}

/// The least of `xs` that at least a share `p` of them do not exceed (the nearest-rank percentile), by counting.
fn nearest_rank(xs: &[f64], p: f64) -> f64 {
    let at_most = |v: f64| xs.iter().filter(|&&x| x <= v).count() as f64;
    xs.iter().copied().filter(|&v| at_most(v) >= p * xs.len() as f64).fold(f64::INFINITY, f64::min)
}
