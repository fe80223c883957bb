//! The paper's central behaviour on its own benchmark: a trained MARS scheduler puts its noise where the
//! task branches (the junction, before the passages) and not where it is unimodal (the exit gate).

mod common;

use mars_policy::cli::mean_w_in_region;
use mars_policy::config::PolicyKind;
use mars_policy::inference::MarsPolicy;
use mars_policy::train::train;
use mars_tasks::nav2d::expert::generate_demos;
use mars_tasks::nav2d::layout::Layout;

#[test]
fn trained_mars_w_is_higher_at_the_junction_than_in_the_exit_gate() {
    let layout = Layout::default_four_passages();
    let demos = generate_demos(&layout, 48, 0).unwrap();
    let mut cfg = common::tiny_config(PolicyKind::Mars);
    cfg.train.knn_m = 20;
    cfg.train.epochs = 12;
    let policy = MarsPolicy::from_trained(train(&cfg, &demos, false).unwrap(), 0);
    let w = |name: &str| mean_w_in_region(&policy, &demos, layout.region(name).unwrap()).unwrap().unwrap();
    let (junction, exit) = (w("junction"), w("exit_gate"));
    assert!(junction > exit, "mean ‖w‖∞: junction {junction:.3} vs exit gate {exit:.3}");
}
