//! Every task answers the questions a policy and the runtime ask of it through the one `Task` trait.

use std::path::Path;

use mars_tasks::Task;
use mars_tasks::nav2d::layout::Layout;
use mars_tasks::pick_cup::{Arm, PickCup, TaskError};

/// The FR3's facts as `configs/fr3.toml` gives them (`mars_runtime::task::arm` reads them from the profile).
fn fr3() -> Arm {
    let p: toml::Table = std::fs::read_to_string(repo("configs/fr3.toml")).unwrap().parse().unwrap();
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

fn repo(rel: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

#[test]
fn each_task_names_itself_its_sizes_and_its_modes() {
    let tasks: Vec<Box<dyn Task>> = vec![
        Box::new(Layout::default_four_passages()),
        Box::new(PickCup::load(&repo("configs/pick_cup.toml"), &fr3()).unwrap()),
    ];
    let seen: Vec<_> =
        tasks.iter().map(|t| (t.name().to_owned(), t.obs_dim(), t.action_dim(), t.mode_names())).collect();
    let nav2d = Layout::default_four_passages();
    assert_eq!(seen[0], (nav2d.name.clone(), 2, 2, nav2d.passages.iter().map(|p| p.name.clone()).collect()));
    // Pick Cup: 7 joints and the gripper, in and out; grasped by the rim or by the handle.
    assert_eq!(seen[1], ("fr3_pick_cup".to_owned(), 8, 8, vec!["rim".to_owned(), "handle".to_owned()]));
}

#[test]
fn pick_cup_is_checked_against_the_arm_it_runs_on() {
    // A grasp pose the FR3 cannot reach within its limits less the margin: refused, naming the field.
    let text = std::fs::read_to_string(repo("configs/pick_cup.toml")).unwrap();
    let mut narrow = fr3();
    narrow.q_max[3] = -2.2;
    match PickCup::parse(&text, "pick_cup.toml", &narrow) {
        Err(TaskError::Invalid { field, problem, .. }) => {
            assert!(field.starts_with("home") || field.starts_with("grasps") || field == "pregrasp", "{field}");
            assert!(problem.contains("joint 3"), "{problem}");
        }
        other => panic!("{other:?}"),
    }
}
