//! Push-T's demos as MARS sees them: the two routes are in the data (about half each), and the target spread
//! S_next — how far the next chunks of samples with similar histories differ — is high where the routes part (at
//! the start, where every demo's history is the same) and low in the push, where both routes do the same thing:
//! where MARS is meant to inject noise and where not. (Trained policies: `cargo run --release -p mars-tasks
//! --example push_t_policies`.)

use mars_policy::config::{EncoderConfig, PolicyConfig, PolicyKind};
use mars_policy::dataset::Dataset;
use mars_tasks::push_t::PushTConfig;
use mars_tasks::push_t::episode::{Observe, expert_demos};

#[test]
fn the_routes_part_where_s_next_is_high_and_not_where_it_is_low() {
    let demos = expert_demos(&PushTConfig::default(), 30, 0, Observe::State);
    let by_route = [0, 1].map(|m| demos.iter().filter(|d| d.mode == Some(m)).count());
    assert!(by_route.iter().all(|&n| n >= 10), "routes {by_route:?}");
    let mut cfg =
        PolicyConfig::load(std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/policy.toml")))
            .unwrap();
    cfg.kind = PolicyKind::Mars;
    cfg.model.obs_dim = Observe::State.dim();
    cfg.model.encoder = EncoderConfig::StateMlp { hidden: 32 };
    let data = Dataset::from_demos(&demos, &cfg.model, cfg.train.knn_m).unwrap();
    // Row of (demo i, step t): demos are laid out one after another.
    let starts: Vec<usize> = demos.iter().scan(0, |row, d| Some(std::mem::replace(row, *row + d.len()))).collect();
    let s_next = &data.s_next;
    let y_spread = |steps: std::ops::Range<usize>| {
        let v: Vec<f32> = starts.iter().flat_map(|s| steps.clone().map(move |t| s_next[(s + t) * 2 + 1])).collect();
        v.iter().sum::<f32>() / v.len() as f32
    };
    let (parting, pushing) = (y_spread(0..2), y_spread(22..26));
    eprintln!(
        "mean S_next(y): {parting:.3} where the routes part (steps 0–1), {pushing:.3} in the push (22–25): {:.1}×",
        parting / pushing
    );
    assert!(parting > 3.0 * pushing, "S_next(y): {parting} at the start vs {pushing} in the push");
}
