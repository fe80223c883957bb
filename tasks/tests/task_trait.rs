//! Every task answers the questions a policy and the runtime ask of it through the one `Task` trait.

use std::path::Path;

use mars_tasks::Task;
use mars_tasks::nav2d::layout::Layout;
use mars_tasks::pick::{Arm, Pick, TaskError};

/// An arm's facts as its profile gives them (`mars_runtime::task::arm` reads them from the profile).
fn arm(profile: &str) -> Arm {
    let p: toml::Table = std::fs::read_to_string(repo(profile)).unwrap().parse().unwrap();
    let floats = |k: &str| -> Vec<f64> { p[k].as_array().unwrap().iter().map(|v| v.as_float().unwrap()).collect() };
    Arm {
        name: p["name"].as_str().unwrap().into(),
        joints: p["joints"].as_integer().unwrap() as usize,
        rate_hz: p["rate_hz"].as_float().unwrap(),
        home: floats("home"),
        q_min: floats("q_min"),
        q_max: floats("q_max"),
        gripper_min: p["gripper_min"].as_float().unwrap(),
        gripper_max: p["gripper_max"].as_float().unwrap(),
    }
}

fn fr3() -> Arm {
    arm("configs/fr3.toml")
}

fn r1_lite() -> Arm {
    arm("configs/r1_lite.toml")
}

fn repo(rel: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

#[test]
fn each_task_names_itself_its_sizes_and_its_modes() {
    let tasks: Vec<Box<dyn Task>> = vec![
        Box::new(Layout::default_four_passages()),
        Box::new(Pick::load(&repo("configs/pick_cup.toml"), &fr3()).unwrap()),
        Box::new(Pick::load(&repo("configs/pick_vegetable.toml"), &r1_lite()).unwrap()),
    ];
    let seen: Vec<_> =
        tasks.iter().map(|t| (t.name().to_owned(), t.obs_dim(), t.action_dim(), t.mode_names())).collect();
    let nav2d = Layout::default_four_passages();
    assert_eq!(seen[0], (nav2d.name.clone(), 2, 2, nav2d.passages.iter().map(|p| p.name.clone()).collect()));
    // Pick Cup: 7 joints and the gripper, in and out; grasped by the rim or by the handle.
    assert_eq!(seen[1], ("fr3_pick_cup".to_owned(), 8, 8, vec!["rim".to_owned(), "handle".to_owned()]));
    // Pick Vegetable: the R1 Lite's 6 joints and its gripper; the carrot or the daikon.
    let vegetables = vec!["carrot".to_owned(), "daikon".to_owned()];
    assert_eq!(seen[2], ("r1_lite_pick_vegetable".to_owned(), 7, 7, vegetables));
}

#[test]
fn the_episodes_plot_shows_the_joints_where_the_grasps_differ_most() {
    // Pick Cup's grasps differ by 0.7 rad in joint 0, 1.1 in joint 6 and 0.3 in joint 2.
    assert_eq!(Pick::load(&repo("configs/pick_cup.toml"), &fr3()).unwrap().most_distinct_joints(), [0, 6]);
    // Pick Vegetable's by 0.9 rad in joint 0 and 1.2 in joint 5 (the R1 Lite's last).
    assert_eq!(Pick::load(&repo("configs/pick_vegetable.toml"), &r1_lite()).unwrap().most_distinct_joints(), [0, 5]);
}

#[test]
fn a_task_written_for_one_arm_is_refused_on_the_other() {
    // Pick Cup's 7-joint poses on the 6-joint R1 Lite, Pick Vegetable's wide opening on the FR3's 8 cm hand:
    // refused before anything moves, saying why.
    let cases = [("pick_cup", r1_lite(), "the r1_lite has 6 joints"), ("pick_vegetable", fr3(), "≤ 0.08")];
    for (task, arm, why) in cases {
        match Pick::load(&repo(&format!("configs/{task}.toml")), &arm) {
            Err(TaskError::Invalid { problem, .. }) => assert!(problem.contains(why), "{task}: {problem}"),
            other => panic!("{task}: {other:?}"),
        }
    }
}

#[test]
fn pick_cup_is_checked_against_the_arm_it_runs_on() {
    // A grasp pose the FR3 cannot reach within its limits less the margin: refused, naming the field.
    let text = std::fs::read_to_string(repo("configs/pick_cup.toml")).unwrap();
    let mut narrow = fr3();
    narrow.q_max[3] = -2.2;
    match Pick::parse(&text, "pick_cup.toml", &narrow) {
        Err(TaskError::Invalid { field, problem, .. }) => {
            assert!(field.starts_with("home") || field.starts_with("grasps") || field == "pregrasp", "{field}");
            assert!(problem.contains("joint 3"), "{problem}");
        }
        other => panic!("{other:?}"),
    }
}
