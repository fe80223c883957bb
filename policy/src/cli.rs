//! What the `mars` subcommands do, as library functions (so tests drive the same code the binary runs).

use crate::checkpoint;
use crate::config::{PolicyConfig, PolicyKind};
use crate::dataset::history_window;
use crate::demo_file::{load_demos, write_json};
use crate::evaluation::{DEFAULT_BATCH, Evaluation, evaluate_policy};
use crate::inference::MarsPolicy;
use crate::plots;
use crate::train::{Trained, progress_bar};
use anyhow::Context;
use candle_core::{Device, Tensor};
use mars_tasks::demo::{Demo, DemoSet};
use mars_tasks::nav2d::eval::EvalReport;
use mars_tasks::nav2d::evaluate_batched;
use mars_tasks::nav2d::expert::generate_demos;
use mars_tasks::nav2d::layout::{Layout, Rect};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The paper executes whole chunks; re-planning every chunk keeps one mode decision per chunk.
pub const DEFAULT_EXEC_HORIZON: usize = 8;
const TASK: &str = "nav2d";

/// Logging to stderr, and the thread setting candle needs on CPU: with `RAYON_NUM_THREADS` unset, every matmul
/// re-reads /proc/cpuinfo (~30 µs instead of ~4 µs). `jobs` trainings share the cores: for these small
/// matrices two threads were barely faster than one, so parallel jobs use the cores better.
///
/// Must run before any other thread starts (it sets an environment variable).
pub fn init_runtime_env(jobs: usize) {
    if std::env::var_os("RAYON_NUM_THREADS").is_none() {
        let n = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
        let per_job = (n / jobs.max(1)).max(1);
        // SAFETY: called from main before any thread exists.
        unsafe { std::env::set_var("RAYON_NUM_THREADS", per_job.to_string()) };
    }
    quiet_video_encoder();
}

/// The video encoder quiet ([`mars_lerobot::video_out::quiet_encoder`]) and the log set up. Called from main
/// before any thread exists (it sets an environment variable).
pub fn quiet_video_encoder() {
    mars_lerobot::video_out::quiet_encoder();
    // RustDDS (the HAL's ros2 backend, which `mars-hil hal` runs) warns tens of times a second against a peer on
    // loopback: only its errors by default, as `mars-hal` does.
    let default = "info,rustdds=error,ros2_client=error";
    let filter = tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| default.into());
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let _ = tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_ansi(ansi).try_init();
}

pub fn demos(layout: &Path, n: usize, seed: u64, out: &Path) -> anyhow::Result<()> {
    anyhow::ensure!(n > 0, "--n must be at least 1 demo");
    let layout = Layout::load(layout)?;
    let demos = generate_demos(&layout, n, seed)?;
    let steps: usize = demos.iter().map(Demo::len).sum();
    write_json(out, &DemoSet { task: TASK.into(), demos })?;
    println!("wrote {n} demos ({steps} steps) to {}", out.display());
    Ok(())
}

/// What `mars train` learns from.
pub enum TrainInput {
    /// A demo file written by `mars demos` (or `mars-hil demos`).
    Demos(PathBuf),
    /// A LeRobot v3.0 dataset.
    Dataset(crate::from_dataset::DatasetInput),
}

/// `mars train`: the config from `config`, or with none given the dataset's features on the shipped defaults
/// (printed), else configs/policy.toml; trains, and writes the checkpoint and the config it used (config.toml)
/// to `out`.
pub fn train(
    kind: PolicyKind,
    config: Option<&Path>,
    input: &TrainInput,
    out: &Path,
    epochs: Option<usize>,
    seed: Option<u64>,
    snapshot_every: Option<usize>,
) -> anyhow::Result<Trained> {
    let mut cfg = match (config, input) {
        (Some(path), _) => PolicyConfig::load(path)?,
        (None, TrainInput::Dataset(d)) => {
            let cfg = crate::dataset_features::config_for(d)?;
            println!(
                "no --config: the policy's features from {}, the rest the shipped defaults:\n{}",
                d.dir.join("meta/info.json").display(),
                cfg.to_toml()
            );
            cfg
        }
        (None, TrainInput::Demos(_)) => PolicyConfig::load(Path::new("configs/policy.toml"))?,
    };
    cfg.kind = kind;
    cfg.train.epochs = epochs.unwrap_or(cfg.train.epochs);
    cfg.train.seed = seed.unwrap_or(cfg.train.seed);
    cfg.validate()?;
    let (demos, given) = match input {
        TrainInput::Demos(path) => (load_demos(path)?.demos, None),
        TrainInput::Dataset(d) => {
            let (demos, report) = crate::from_dataset::load(d, &cfg.model)?;
            println!("{}", crate::from_dataset::describe(&d.dir, &demos, &report));
            let given = crate::from_dataset::given_normalizer(d, &cfg.model)?;
            if given.is_some() {
                println!("normalised by the dataset's meta/stats.json (mean, std of the state and action)");
            }
            (demos, given)
        }
    };
    let trained = train_on_normalised(&cfg, &demos, given.as_ref(), out, snapshot_every)?;
    let written = out.join("config.toml");
    std::fs::write(&written, cfg.to_toml()).with_context(|| format!("writing {}", written.display()))?;
    Ok(trained)
}

/// `mars train` on demos already in memory (a task that makes its own, e.g. Push-T's with camera images): trains
/// with a progress bar, saves the checkpoint to `out` (and snapshots every N epochs) and prints the summary line.
pub fn train_on(
    cfg: &PolicyConfig,
    demos: &[Demo],
    out: &Path,
    snapshot_every: Option<usize>,
) -> anyhow::Result<Trained> {
    train_on_normalised(cfg, demos, None, out, snapshot_every)
}

/// [`train_on`] normalised by `given` statistics (None: the demos').
pub fn train_on_normalised(
    cfg: &PolicyConfig,
    demos: &[Demo],
    given: Option<&crate::normalize::Normalizer>,
    out: &Path,
    snapshot_every: Option<usize>,
) -> anyhow::Result<Trained> {
    let kind = cfg.kind;
    let started = Instant::now();
    let snapshots = snapshot_every.map(|every| crate::train::Snapshots { every, dir: out.join("snapshots") });
    let bar = progress_bar(kind);
    let trained = crate::train::train_normalised_by(cfg, demos, given, bar, snapshots.as_ref())?;
    trained.save(out)?;
    let last = trained.log.last().context("training ran no epoch")?;
    println!(
        "{kind}: {} epochs in {:.1} s, final loss {:.4} (fm {:.4}, rec {:.4}, div {:.4}, mean ‖w‖∞ {:.3}) → {}",
        cfg.train.epochs,
        started.elapsed().as_secs_f32(),
        last.total,
        last.fm,
        last.rec,
        last.div,
        last.w_inf,
        out.display()
    );
    Ok(trained)
}

pub fn eval(
    checkpoint_dir: &Path,
    layout: &Path,
    rollouts: usize,
    seed: u64,
    exec_horizon: usize,
) -> anyhow::Result<Evaluation> {
    eval_with_steps(checkpoint_dir, layout, rollouts, seed, exec_horizon, DEFAULT_BATCH, StepsAblation::default())
}

/// How an ablation changes the step count of a checkpoint's K(w); the default changes nothing.
#[derive(Debug, Clone, Copy, Default)]
pub struct StepsAblation {
    /// Exactly this many Euler steps.
    pub steps: Option<usize>,
    /// K(w) with this `k_full_w` instead of the checkpoint's.
    pub k_full_w: Option<f32>,
}

/// `eval` under a step-count ablation; an ablated run writes `eval_k<steps>.json` or `eval_kfull<w>.json`, so
/// it never replaces the checkpoint's own evaluation.
pub fn eval_with_steps(
    checkpoint_dir: &Path,
    layout: &Path,
    rollouts: usize,
    seed: u64,
    exec_horizon: usize,
    batch: usize,
    ablation: StepsAblation,
) -> anyhow::Result<Evaluation> {
    anyhow::ensure!(rollouts > 0, "--rollouts must be at least 1");
    anyhow::ensure!(batch > 0, "--batch must be at least 1");
    anyhow::ensure!(ablation.steps != Some(0), "--steps must be at least 1");
    if let Some(w) = ablation.k_full_w {
        anyhow::ensure!(w > 0.0 && w <= 1.0, "--k-full-w is {w}, must lie in (0, 1]");
    }
    let layout = Layout::load(layout)?;
    let (mut policy, meta) = MarsPolicy::load(checkpoint_dir, seed)?;
    policy.force_steps(ablation.steps);
    if let Some(w) = ablation.k_full_w {
        policy.set_k_full_w(w);
    }
    let evaluation = evaluate_policy(&mut policy, &layout, rollouts, seed, exec_horizon, batch)?;
    let (name, file) = match (ablation.steps, ablation.k_full_w) {
        (Some(k), _) => (format!("{} (K = {k})", meta.kind.name()), format!("eval_k{k}.json")),
        (None, Some(w)) => (format!("{} (k_full_w = {w})", meta.kind.name()), format!("eval_kfull{w}.json")),
        (None, None) => (meta.kind.name().to_string(), "eval.json".to_string()),
    };
    println!("{}", EvalReport::table_header());
    println!("{}", evaluation.report.to_table_row(&name));
    println!("{}", evaluation.intervals);
    write_json(&checkpoint_dir.join(&file), &evaluation.report)?;
    write_json(&checkpoint_dir.join(file.replace(".json", "_intervals.json")), &evaluation.intervals)?;
    Ok(evaluation)
}

/// Mean ‖w‖∞ of a policy over the demo samples whose observation lies in `region`: where does the scheduler
/// think the task is multimodal? `None` if no sample lies there.
pub fn mean_w_in_region(policy: &MarsPolicy, demos: &[Demo], region: &Rect) -> anyhow::Result<Option<f32>> {
    let model = policy.model();
    let cfg = &model.cfg;
    let (mut obs, mut hist) = (Vec::new(), Vec::new());
    for d in demos {
        for (t, o) in d.observations.iter().enumerate() {
            if region.contains([o[0], o[1]]) {
                obs.extend_from_slice(o);
                history_window(&d.actions, &d.rest_action, t, cfg.history_len, &mut hist);
            }
        }
    }
    let n = obs.len() / cfg.obs_dim;
    if n == 0 {
        return Ok(None);
    }
    policy.normalizer().obs.normalize(&mut obs);
    policy.normalizer().action.normalize(&mut hist);
    let obs = Tensor::from_vec(obs, (n, cfg.obs_dim), &Device::Cpu)?;
    let hist = Tensor::from_vec(hist, (n, cfg.history_len, cfg.action_dim), &Device::Cpu)?;
    let w = model.weights(&model.encode(&obs)?, &hist)?;
    Ok(Some(w.max(1)?.mean_all()?.to_scalar::<f32>()?))
}

/// Where the diversity loss acts on a trained checkpoint: per region, S_next vs S_curr, ReLU activity, w and
/// the neighbours' make-up, as a table (also written to `<checkpoint>/diagnose.json`).
pub fn diagnose(checkpoint_dir: &Path, demos: &Path, layout: &Path, seed: u64) -> anyhow::Result<()> {
    let layout = Layout::load(layout)?;
    let set = load_demos(demos)?;
    let (policy, meta) = MarsPolicy::load(checkpoint_dir, seed)?;
    let model = policy.model();
    let mut data = crate::dataset::Dataset::from_demos(&set.demos, &model.cfg, meta.train.knn_m)?;
    if let Some(q) = meta.train.div_target_quantile {
        // The target this checkpoint was trained toward, not the paper's.
        data.rescale_target_spread(q);
    }
    let stats = crate::diagnose::diagnose(&policy, &set.demos, &data, &layout, seed)?;
    let mut w_inf = crate::train::w_inf_values(model, &data.tensors(&model.cfg, &Device::Cpu)?)?;
    let q: Vec<String> = [0.5, 0.9, 0.95, 0.99, 1.0]
        .iter()
        .map(|&q| format!("q{} {:.3}", q * 100.0, crate::stats::quantile(&mut w_inf, q)))
        .collect();
    println!(
        "{} on {} ({} demos), m = {}, S in normalised action units, S_curr averaged over noise draws.\n\
         ‖w‖∞ over the demo samples: {} (checkpoint's k_full_w {}).\n",
        meta.kind,
        layout.name,
        set.demos.len(),
        meta.train.knn_m,
        q.join(", "),
        model.cfg.k_full_w
    );
    println!("{}", crate::diagnose::table(&stats));
    let mut policy = policy;
    let fork = crate::diagnose::fork_choices(&mut policy, &set.demos, &layout, 10, seed)?;
    let pct = |v: &[f32]| v.iter().map(|x| format!("{:.0}", 100.0 * x)).collect::<Vec<_>>().join("/");
    println!(
        "Heading of the first chunk past the entry gate ({} demo states × {} draws, K(w) as deployed), passage shares %:\n\
         policy {} (unclassified {:.0} %); the demos' own chunks, same classifier: {}; the demos' recorded passages: {}",
        fork.states,
        fork.draws,
        pct(&fork.policy),
        100.0 * fork.unclassified,
        pct(&fork.demos_classified),
        pct(&fork.demos_recorded)
    );
    write_json(&checkpoint_dir.join("diagnose.json"), &(&stats, &fork))
}

pub fn plot(run: &Path, layout: &Path) -> anyhow::Result<()> {
    let layout = Layout::load(layout)?;
    let set = load_demos(&run.join("demos.json"))?;
    plots::plot_demos(&layout, &set.demos, &run.join("demos.png"))?;
    let (mut losses, mut k_series) = (Vec::new(), Vec::new());
    for kind in PolicyKind::ALL {
        let dir = run.join(kind.name());
        if !dir.join(checkpoint::META_FILE).exists() {
            continue;
        }
        let meta = checkpoint::load_meta(&dir)?;
        losses.push((kind.name().to_string(), meta.log.iter().map(|e| e.total).collect()));
        let eval_path = dir.join("eval.json");
        let text = match std::fs::read_to_string(&eval_path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                println!("{kind}: no {} (run `mars eval` on it): no rollout plot", eval_path.display());
                continue;
            }
            Err(e) => return Err(e).with_context(|| format!("cannot read {}", eval_path.display())),
        };
        let report: EvalReport =
            serde_json::from_str(&text).with_context(|| format!("{} is not a valid eval file", eval_path.display()))?;
        let title = format!("{kind}: {} rollouts, colour = ‖w‖∞", report.n);
        plots::plot_rollouts(&layout, &report.episodes, &title, &run.join(format!("rollouts_{kind}.png")))?;
        if let Some(e) = report.episodes.iter().find(|e| e.success()).or(report.episodes.first()) {
            k_series.push((kind.name().to_string(), e.k_per_step()));
        }
    }
    if !losses.is_empty() {
        plots::plot_losses(&losses, &run.join("losses.png"))?;
    }
    if !k_series.is_empty() {
        plots::plot_k_per_step(&k_series, &run.join("k_per_step.png"))?;
    }
    println!("plots written to {}", run.display());
    Ok(())
}

/// nav2d as a task of the training-efficiency curves (`mars curve`).
pub struct Nav2dCurve {
    pub layout: PathBuf,
    pub demos: usize,
    pub rollouts: usize,
    pub exec_horizon: usize,
}

impl crate::curve::CurveTask for Nav2dCurve {
    fn title(&self) -> String {
        let name = Layout::load(&self.layout).map(|l| l.name).unwrap_or_else(|_| self.layout.display().to_string());
        format!("nav2d {name}, {} demos, {} rollouts per snapshot", self.demos, self.rollouts)
    }

    fn demos(&self, seed: u64, path: &Path) -> anyhow::Result<()> {
        demos(&self.layout, self.demos, seed, path)
    }

    fn evaluate(&self, dir: &Path, _demos: &Path, seed: u64) -> anyhow::Result<crate::curve::Score> {
        let layout = Layout::load(&self.layout)?;
        let (mut policy, _) = MarsPolicy::load(dir, seed)?;
        let r = evaluate_batched(&layout, &mut policy, self.rollouts, seed, self.exec_horizon, DEFAULT_BATCH)?;
        let demo_shares: Vec<f64> = layout.demo_shares().iter().map(|&p| f64::from(p)).collect();
        let tv = mars_tasks::stats::modes::tv_to(&r.passage_counts, &demo_shares) as f32;
        Ok(crate::curve::Score {
            success_pct: 100.0 * r.success_rate(),
            gamma: r.modal_balance,
            mean_k: r.mean_k,
            tv: Some(tv),
        })
    }
}
