//! The whole round trip through a peer's writer: our Push-T expert's demos (the in-process ones `mars-hil
//! push-t-train` trains on), written as a dataset by LeRobot 0.6.1 (tests/fixtures/lerobot, see its README), read
//! back by `mars train --dataset`'s reader, equal the demos made again here: states, actions and the history's
//! padding exactly, camera images within AV1's loss.

use std::path::Path;

use mars_policy::config::PolicyConfig;
use mars_policy::from_dataset::{DatasetInput, load};
use mars_profile::Profile;
use mars_runtime::task::PushTHil;
use mars_tasks::push_t::episode::expert_demos;

#[test]
fn the_lerobot_fixture_holds_our_expert_demos() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let task =
        PushTHil::load(&root.join("configs/push_t.toml"), &Profile::load(&root.join("configs/fr3.toml")).unwrap())
            .unwrap();
    // The fixture's README: `push_t_demos_json -- 6 0`, i.e. 6 demos from seed 0.
    let made = expert_demos(&task.cfg.world, 6, 0, task.observe());
    let cfg = PolicyConfig::load(&root.join("configs/push_t_policy.toml")).unwrap();
    let input = DatasetInput {
        dir: root.join("tests/fixtures/lerobot/push_t"),
        state_key: "observation.state".into(),
        action_key: "action".into(),
        image_keys: vec![],
        rest: None,
        normalize: Default::default(),
    };
    let (read, _) = load(&input, &cfg.model).unwrap();
    assert_eq!(read.len(), made.len());
    let (mut diff, mut values, mut worst) = (0f64, 0usize, 0f32);
    for (i, (r, m)) in read.iter().zip(&made).enumerate() {
        assert_eq!(r.actions, m.actions, "demo {i}");
        assert_eq!(r.rest_action, m.rest_action, "demo {i}: the first state is the pusher's start");
        for (t, (ro, mo)) in r.observations.iter().zip(&m.observations).enumerate() {
            assert_eq!(ro.len(), mo.len());
            assert_eq!(ro[..2], mo[..2], "demo {i} step {t}: state");
            for (a, b) in ro[2..].iter().zip(&mo[2..]) {
                let d = (a - b).abs() * 255.0;
                (diff, values, worst) = (diff + f64::from(d), values + 1, worst.max(d));
            }
        }
    }
    let mean = diff / values as f64;
    println!("images after AV1: mean |difference| {mean:.3}, worst {worst:.0} (of 255)");
    // LeRobot's own decode of these frames is 2.61 on average from the render (its fixture README), and ours
    // equals LeRobot's byte for byte (mars-lerobot's fixture test).
    assert!(mean < 3.0, "images {mean:.3} levels from the render on average");
}
