//! MARS, FM and A2A trained on the same Push-T expert demos (state observations) and evaluated closed loop, over
//! several training seeds (each with its own demos): per seed success, successes by route, the routes' TV to the
//! demos', γ, mean K and the policy call's median latency (candle, this process); then the means over seeds with
//! their 95 % t intervals, and MARS − FM seed by seed with verdicts.
//!
//!     cargo run --release -p mars-tasks --example push_t_policies [-- demos epochs episodes seeds]

use mars_policy::config::{EncoderConfig, PolicyConfig, PolicyKind};
use mars_policy::inference::MarsPolicy;
use mars_policy::train::train;
use mars_tasks::push_t::PushTConfig;
use mars_tasks::push_t::episode::{Observe, Observer, expert_demos, run_episode, score};
use mars_tasks::stats::{Estimate, Verdict, mean_over_seeds, shares, tv_distance};

const KINDS: [PolicyKind; 3] = [PolicyKind::Mars, PolicyKind::Fm, PolicyKind::A2a];

/// One policy's figures on one seed.
struct Figures {
    success_pct: f64,
    upper_pct: f64,
    tv: f64,
    gamma: f64,
    mean_k: f64,
}

fn config(kind: PolicyKind, epochs: usize, seed: u64) -> anyhow::Result<PolicyConfig> {
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
    cfg.train.seed = seed + 1;
    Ok(cfg)
}

fn over_seeds(v: &[f64]) -> Estimate {
    mean_over_seeds(v).unwrap_or(Estimate::new(f64::NAN, f64::NAN, f64::NAN))
}

fn main() -> anyhow::Result<()> {
    let arg = |i: usize, default: usize| std::env::args().nth(i).and_then(|a| a.parse().ok()).unwrap_or(default);
    let (n_demos, epochs, episodes, seeds) = (arg(1, 40), arg(2, 60), arg(3, 50), arg(4, 5) as u64);
    let task = PushTConfig::default();
    println!(
        "Push-T (state): {n_demos} expert demos per seed, {epochs} epochs, {episodes} episodes each, {seeds} seeds"
    );
    println!(
        "| seed | demos upper/lower | policy | success | by route (upper, lower) | TV to the demos' routes | γ \
         | mean K | call p50 ms |"
    );
    println!("|---:|---|---|---:|---:|---:|---:|---:|---:|");
    let mut figures: Vec<Vec<Figures>> = KINDS.iter().map(|_| Vec::new()).collect();
    for seed in 0..seeds {
        // Demo episodes of different seeds never overlap (each seed's episodes count up from its own start).
        let demos = expert_demos(&task, n_demos, seed * 100_000, Observe::State);
        let by_route = [0, 1].map(|m| demos.iter().filter(|d| d.mode == Some(m)).count());
        let demo_shares = shares(&by_route).unwrap_or_default();
        for (k, kind) in KINDS.into_iter().enumerate() {
            let trained = train(&config(kind, epochs, seed)?, &demos, false)?;
            let mut policy = MarsPolicy::from_trained(trained, 7 + seed);
            let mut observer = Observer::new(Observe::State);
            let mut eps = Vec::new();
            for i in 0..episodes as u64 {
                policy.reseed(100 + seed * 100_000 + i);
                eps.push(run_episode(&task, &mut policy, &mut observer, 1000 + seed * 100_000 + i, 4)?);
            }
            let s = score(&eps);
            let mut ms: Vec<f64> = eps.iter().flat_map(|e| e.calls.iter().map(|c| c.2.as_secs_f64() * 1e3)).collect();
            ms.sort_by(f64::total_cmp);
            let route_shares = shares(&s.by_route);
            let f = Figures {
                success_pct: 100.0 * s.successes as f64 / s.episodes.max(1) as f64,
                upper_pct: route_shares.as_ref().map_or(f64::NAN, |r| 100.0 * r[0]),
                tv: route_shares.as_ref().map_or(1.0, |r| tv_distance(r, &demo_shares)),
                gamma: f64::from(s.gamma),
                mean_k: f64::from(s.mean_k),
            };
            println!(
                "| {seed} | {}/{} | {kind} | {}/{} | {}, {} | {:.2} | {:.2} | {:.2} | {:.2} |",
                by_route[0],
                by_route[1],
                s.successes,
                s.episodes,
                s.by_route[0],
                s.by_route[1],
                f.tv,
                s.gamma,
                s.mean_k,
                ms.get(ms.len() / 2).copied().unwrap_or(f64::NAN)
            );
            figures[k].push(f);
        }
    }
    summary(&figures);
    Ok(())
}

/// Means over seeds with their intervals, and MARS against FM seed by seed.
fn summary(figures: &[Vec<Figures>]) {
    let of = |k: usize, f: fn(&Figures) -> f64| over_seeds(&figures[k].iter().map(f).collect::<Vec<_>>());
    println!("\nMean over seeds with its 95 % t interval:\n");
    println!("| policy | success % | upper route % of successes | TV to the demos' routes | γ | mean K |");
    println!("|---|---|---|---|---|---|");
    for (k, kind) in KINDS.iter().enumerate() {
        println!(
            "| {kind} | {:.1} | {:.1} | {:.3} | {:.2} | {:.2} |",
            of(k, |f| f.success_pct),
            of(k, |f| f.upper_pct),
            of(k, |f| f.tv),
            of(k, |f| f.gamma),
            of(k, |f| f.mean_k)
        );
    }
    let paired = |f: fn(&Figures) -> f64| {
        over_seeds(&figures[0].iter().zip(&figures[1]).map(|(m, fm)| f(m) - f(fm)).collect::<Vec<_>>())
    };
    let success = paired(|f| f.success_pct);
    let tv = paired(|f| f.tv);
    println!("\nMARS − FM, seed by seed:");
    let verdict = Verdict::at_least(success, -2.0);
    println!("- MARS success at most 2 points below FM's: {success:.1} points — {verdict}");
    println!("- MARS's TV to the demos' routes at most 0.05 above FM's: {tv:.3} — {}", Verdict::at_most(tv, 0.05));
}
