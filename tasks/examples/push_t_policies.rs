//! MARS, FM and A2A trained on the same Push-T expert demos (state observations) and evaluated closed loop:
//! success, successes by route, γ, mean K and the policy call's median latency (candle, this process).
//!
//!     cargo run --release -p mars-tasks --example push_t_policies [-- demos epochs episodes]

use mars_policy::config::{EncoderConfig, PolicyConfig, PolicyKind};
use mars_policy::inference::MarsPolicy;
use mars_policy::train::train;
use mars_tasks::push_t::PushTConfig;
use mars_tasks::push_t::episode::{Observe, Observer, expert_demos, run_episode, score};

fn main() -> anyhow::Result<()> {
    let arg = |i: usize, default: usize| std::env::args().nth(i).and_then(|a| a.parse().ok()).unwrap_or(default);
    let (n_demos, epochs, episodes) = (arg(1, 40), arg(2, 60), arg(3, 50));
    let task = PushTConfig::default();
    let demos = expert_demos(&task, n_demos, 0, Observe::State);
    let by_route = [0, 1].map(|m| demos.iter().filter(|d| d.mode == Some(m)).count());
    println!(
        "Push-T (state): {} expert demos, routes upper/lower {by_route:?}; {epochs} epochs; {episodes} episodes each",
        demos.len()
    );
    println!("| policy | success | by route (upper, lower) | γ | mean K | call p50 ms |");
    println!("|---|---:|---:|---:|---:|---:|");
    for kind in [PolicyKind::Mars, PolicyKind::Fm, PolicyKind::A2a] {
        let mut cfg = PolicyConfig::load(std::path::Path::new("configs/policy.toml"))?;
        cfg.kind = kind;
        cfg.model.obs_dim = Observe::State.dim();
        cfg.model.action_dim = 2;
        cfg.model.encoder = EncoderConfig::StateMlp { hidden: 64 };
        cfg.model.obs_embed_dim = 64;
        cfg.model.scheduler_hidden = 64;
        cfg.model.dit_width = 64;
        cfg.model.dit_depth = 2;
        cfg.model.dit_heads = 4;
        cfg.model.dit_mlp_ratio = 2;
        cfg.train.epochs = epochs;
        cfg.train.seed = 1;
        let trained = train(&cfg, &demos, false)?;
        let mut policy = MarsPolicy::from_trained(trained, 7);
        let mut observer = Observer::new(Observe::State);
        let mut eps = Vec::new();
        for i in 0..episodes as u64 {
            policy.reseed(100 + i);
            eps.push(run_episode(&task, &mut policy, &mut observer, 1000 + i, 4)?);
        }
        let s = score(&eps);
        let mut ms: Vec<f64> = eps.iter().flat_map(|e| e.calls.iter().map(|c| c.2.as_secs_f64() * 1e3)).collect();
        ms.sort_by(f64::total_cmp);
        println!(
            "| {kind} | {}/{} | {}, {} | {:.2} | {:.2} | {:.2} |",
            s.successes,
            s.episodes,
            s.by_route[0],
            s.by_route[1],
            s.gamma,
            s.mean_k,
            ms.get(ms.len() / 2).copied().unwrap_or(f64::NAN)
        );
    }
    Ok(())
}
