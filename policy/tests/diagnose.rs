//! `mars diagnose` on real nav2d demos: the neighbour accounting and the spreads it reports.

mod common;

use candle_core::Device;
use mars_policy::config::PolicyKind;
use mars_policy::diagnose::diagnose;
use mars_policy::inference::MarsPolicy;
use mars_policy::train::init_model;
use mars_tasks::nav2d::expert::generate_demos;
use mars_tasks::nav2d::layout::Layout;

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

#[test]
fn the_fork_classifier_recovers_the_demos_passages_and_counts_every_draw() {
    let layout = Layout::default_four_passages();
    let demos = generate_demos(&layout, 24, 5).unwrap();
    let cfg = common::tiny_config(PolicyKind::Mars);
    let (model, _) = init_model(&cfg, &Device::Cpu).unwrap();
    let data = mars_policy::dataset::Dataset::from_demos(&demos, &cfg.model, 4).unwrap();
    let mut policy = MarsPolicy::new(model, data.normalizer.clone(), 0);
    let fork = mars_policy::diagnose::fork_choices(&mut policy, &demos, &layout, 3, 0).unwrap();
    assert_eq!((fork.states, fork.draws), (24, 3));
    // The classifier reads each demo's own chunk at the fork as the passage the demo went through.
    assert_eq!(fork.demos_classified, fork.demos_recorded, "{fork:?}");
    let total: f32 = fork.policy.iter().sum::<f32>();
    assert!(fork.unclassified == 1.0 || (total - 1.0).abs() < 1e-5, "shares of the classified draws: {fork:?}");

    // Headings: straight on is the passage in line with the gate; a steep drop is the lowest passage.
    let centre = |i: usize| 0.5 * (layout.passages[i].y[0] + layout.passages[i].y[1]);
    let lowest = (0..layout.n_passages()).min_by(|&a, &b| centre(a).total_cmp(&centre(b))).unwrap();
    let x_col = layout.passages[0].x[0];
    let from = [2.5, 4.0];
    let to_lowest = [3.5, 4.0 + (centre(lowest) - 4.0) / (x_col - 2.5)];
    assert_eq!(mars_policy::diagnose::heading_passage(&layout, from, to_lowest), Some(lowest));
    assert_eq!(mars_policy::diagnose::heading_passage(&layout, from, [2.4, 1.0]), None, "moving back is no heading");
}
