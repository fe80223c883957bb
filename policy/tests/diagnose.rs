//! `mars diagnose` on real nav2d demos: the neighbour accounting and the spreads it reports.

mod common;

use candle_core::Device;
use mars_policy::config::PolicyKind;
use mars_policy::diagnose::diagnose;
use mars_policy::inference::MarsPolicy;
use mars_policy::nav2d::expert::generate_demos;
use mars_policy::nav2d::layout::Layout;
use mars_policy::train::init_model;

#[test]
fn neighbours_cross_passages_at_the_fork_and_not_inside_a_passage() {
    let layout = Layout::default_four_passages();
    let demos = generate_demos(&layout, 24, 5).unwrap();
    let mut cfg = common::tiny_config(PolicyKind::Mars);
    cfg.train.knn_m = 8;
    // Untrained weights: the neighbour make-up and S_next depend on the demos only.
    let (model, _) = init_model(&cfg, &Device::Cpu).unwrap();
    let data = mars_policy::dataset::Dataset::from_demos(&demos, &cfg.model, 8).unwrap();
    let policy = MarsPolicy::new(model, data.normalizer.clone(), 0);
    let stats = diagnose(&policy, &demos, &data, &layout, 0).unwrap();
    let get = |name: &str| stats.iter().find(|s| s.region == name).unwrap_or_else(|| panic!("no {name} in {stats:?}"));

    let gate = get("entry_gate");
    assert!(gate.other_passage > 0.3, "at the fork most neighbours took another passage: {gate:?}");
    for p in &layout.passages {
        let s = get(&p.name);
        assert_eq!(s.other_passage, 0.0, "inside {} every neighbour took the same passage: {s:?}", p.name);
    }
    assert!(
        gate.s_next[1] > 2.0 * get("exit_gate").s_next[1],
        "the demos' next chunks spread more in y at the fork than at the exit: {stats:?}"
    );
    for s in &stats {
        assert!((0.0..=1.0).contains(&s.relu_active) && (0.0..=1.0).contains(&s.same_demo), "{s:?}");
        assert!(s.s_curr.iter().chain(&s.s_next).all(|v| v.is_finite() && *v >= 0.0), "{s:?}");
    }
}
