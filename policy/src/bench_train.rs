//! `mars bench-train`: seconds per training epoch, ours by hand (`crate::grad`) and through candle's autograd,
//! beside the PyTorch peer (`policy/benches/torch_trainer.py`) on the same samples and sizes, taken in turns
//! (hand, autograd, PyTorch; again each round) so a slower minute of the machine falls on all three. Prints
//! the median seconds per epoch of each and PyTorch's speed-up ratio over it: the mean over rounds of each round's
//! ratio of medians (the two measured side by side), with its 95 % t interval, and the verdict on the issue's
//! target (ours by hand ≥ 2× PyTorch's speed) by that interval.

use crate::config::{Gradients, PolicyConfig, PolicyKind};
use crate::dataset::Dataset;
use anyhow::Context;
use candle_core::{DType, Device, Tensor};
use mars_tasks::stats::{Estimate, Verdict, mean_over_seeds};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

pub struct BenchTrainOptions {
    pub kind: PolicyKind,
    pub config: PathBuf,
    pub demos: PathBuf,
    pub epochs: usize,
    pub rounds: usize,
    /// The Python with torch and safetensors that runs the peer; none: ours only.
    pub python: Option<PathBuf>,
    /// Threads each trainer may use (ours: gemm's; PyTorch: `torch.set_num_threads`).
    pub threads: usize,
    pub out: PathBuf,
}

/// The peer's script, next to this crate's sources.
fn torch_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/torch_trainer.py")
}

pub fn run(opts: &BenchTrainOptions) -> anyhow::Result<()> {
    anyhow::ensure!(opts.epochs > 0 && opts.rounds > 0, "--epochs and --rounds must be at least 1");
    let mut cfg = PolicyConfig::load(&opts.config)?;
    cfg.kind = opts.kind;
    cfg.train.epochs = opts.epochs;
    anyhow::ensure!(crate::grad::supports(&cfg), "the hand-written gradients are for state policies");
    let demos = crate::demo_file::load_demos(&opts.demos)?.demos;
    std::fs::create_dir_all(&opts.out).with_context(|| format!("creating {}", opts.out.display()))?;
    if opts.python.is_some() {
        write_samples(&cfg, &demos, &opts.out)?;
    }
    // Per trainer, per round: the seconds of each epoch.
    let mut seconds: HashMap<&str, Vec<Vec<f64>>> = HashMap::new();
    for round in 0..opts.rounds {
        for gradients in [Gradients::Hand, Gradients::Autograd] {
            let mut c = cfg.clone();
            c.train.gradients = gradients;
            let trained = crate::train::train(&c, &demos, false)?;
            let name = if gradients == Gradients::Hand { "ours, by hand" } else { "ours, candle autograd" };
            eprintln!("round {}: {name}: {:?} s per epoch", round + 1, rounded(&trained.epoch_seconds));
            seconds.entry(name).or_default().push(trained.epoch_seconds.clone());
        }
        if let Some(python) = &opts.python {
            let s = torch_epochs(python, &opts.out, &cfg, opts.epochs, opts.threads)?;
            eprintln!("round {}: PyTorch: {:?} s per epoch", round + 1, rounded(&s));
            seconds.entry("PyTorch").or_default().push(s);
        }
    }
    println!("{}", table(&cfg, opts, &seconds));
    Ok(())
}

fn rounded(v: &[f64]) -> Vec<f64> {
    v.iter().map(|s| (s * 100.0).round() / 100.0).collect()
}

fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// PyTorch's seconds per epoch ÷ `ours`, round by round (each round's medians), as a mean over the rounds with
/// its 95 % t interval (unbounded with one round).
fn speed_up(torch: &[Vec<f64>], ours: &[Vec<f64>]) -> Estimate {
    let ratios: Vec<f64> = torch.iter().zip(ours).map(|(t, o)| median(t) / median(o)).collect();
    mean_over_seeds(&ratios).unwrap_or(Estimate::new(f64::NAN, f64::NAN, f64::NAN))
}

/// The target: by hand on one thread, at least twice PyTorch's speed.
const TARGET_SPEED_UP: f64 = 2.0;

fn table(cfg: &PolicyConfig, opts: &BenchTrainOptions, seconds: &HashMap<&str, Vec<Vec<f64>>>) -> String {
    let mut out = format!(
        "{} training, {} threads, {} epochs × {} rounds each (median seconds per epoch; PyTorch's seconds ÷ ours \
         per round, mean over rounds with its 95 % t interval):\n\n| trainer | s/epoch | PyTorch ÷ it |\n|---|---:|---:|\n",
        cfg.kind, opts.threads, opts.epochs, opts.rounds
    );
    let torch = seconds.get("PyTorch");
    for name in ["ours, by hand", "ours, candle autograd", "PyTorch"] {
        let Some(rounds) = seconds.get(name) else { continue };
        let all: Vec<f64> = rounds.iter().flatten().copied().collect();
        let ratio = torch.map_or("–".to_string(), |t| format!("{:.2}", speed_up(t, rounds)));
        out += &format!("| {name} | {:.2} | {ratio} |\n", median(&all));
    }
    if let (Some(t), Some(hand)) = (torch, seconds.get("ours, by hand")) {
        let e = speed_up(t, hand);
        let verdict = Verdict::at_least(e, TARGET_SPEED_UP);
        out += &format!("\nBy hand ≥ {TARGET_SPEED_UP}× PyTorch's speed: PyTorch ÷ ours = {e:.2} — {verdict}\n");
    }
    out
}

/// The training samples as ours builds them (kNN, normalisation, the diversity target's rescaling), for the
/// peer: `samples.safetensors` and `config.json` in `dir`.
fn write_samples(cfg: &PolicyConfig, demos: &[mars_tasks::demo::Demo], dir: &Path) -> anyhow::Result<()> {
    let mut data = Dataset::from_demos_with(demos, &cfg.model, cfg.train.knn_m, None)?;
    if let (Some(q), PolicyKind::Mars) = (cfg.train.div_target_quantile, cfg.kind) {
        data.rescale_target_spread(q);
    }
    let t = data.tensors(&cfg.model, &Device::Cpu)?;
    let tensors: HashMap<String, Tensor> = [
        ("obs", t.obs),
        ("history", t.history),
        ("next", t.next),
        ("neighbours", t.neighbours.to_dtype(DType::I64)?),
        ("s_next", t.s_next),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    candle_core::safetensors::save(&tensors, dir.join("samples.safetensors"))?;
    std::fs::write(dir.join("config.json"), serde_json::to_string_pretty(cfg)?)?;
    Ok(())
}

/// Runs the peer for `epochs` epochs; its seconds per epoch.
fn torch_epochs(
    python: &Path,
    dir: &Path,
    cfg: &PolicyConfig,
    epochs: usize,
    threads: usize,
) -> anyhow::Result<Vec<f64>> {
    let out = Command::new(python)
        .arg(torch_script())
        .arg(dir)
        .args(["--kind", cfg.kind.name(), "--epochs", &epochs.to_string(), "--threads", &threads.to_string()])
        .output()
        .with_context(|| format!("running {}", python.display()))?;
    anyhow::ensure!(
        out.status.success(),
        "the PyTorch trainer failed ({}): {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let seconds: Vec<f64> = text
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok()?.get("seconds")?.as_f64())
        .collect();
    anyhow::ensure!(
        seconds.len() == epochs,
        "the PyTorch trainer reported {} epochs of {epochs}:\n{text}",
        seconds.len()
    );
    Ok(seconds)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_speed_up_pairs_rounds_and_gives_an_interval() {
        let torch = vec![vec![6.0, 6.2, 5.8], vec![6.5, 6.4, 6.6]];
        let ours = vec![vec![3.0, 3.1, 2.9], vec![3.0, 3.2, 3.1]];
        let e = speed_up(&torch, &ours);
        // Rounds: 6.0 / 3.0 = 2.0 and 6.5 / 3.1.
        assert!((e.value - (2.0 + 6.5 / 3.1) / 2.0).abs() < 1e-12, "{e:?}");
        assert!(e.lo < e.value && e.value < e.hi);
        assert_eq!(Verdict::at_least(e, TARGET_SPEED_UP), Verdict::Undecided);
        assert!(speed_up(&torch[..1], &ours[..1]).hi.is_infinite());
    }
}
