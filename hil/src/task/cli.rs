//! What `mars-hil demos` and `mars-hil eval-sim` do, as library functions (tests drive the same code).

use std::path::Path;

use anyhow::Context;
use mars_profile::Profile;
use mars_tasks::demo::{Demo, DemoSet};

use super::eval::{EvalReport, evaluate};
use super::expert::generate_demos;
use super::pick::Pick;

/// The profile and the task checked against it.
pub fn load_task(task: &Path, profile: &Path) -> anyhow::Result<(Pick, Profile)> {
    let profile = Profile::load(profile)?;
    let task = Pick::load(task, &super::arm(&profile))?;
    Ok((task, profile))
}

/// Written to a temporary file first, so a crash never leaves half a file under the final name.
fn write_json(path: &Path, value: &impl serde::Serialize) -> anyhow::Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, serde_json::to_string(value)?).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))
}

/// `n` verified, balanced expert demos as a `DemoSet` JSON at `out`.
pub fn demos(task: &Path, profile: &Path, n: usize, seed: u64, out: &Path) -> anyhow::Result<()> {
    anyhow::ensure!(n > 0, "--n must be at least 1 demo");
    let (task, profile) = load_task(task, profile)?;
    let demos = generate_demos(&task, &profile, n, seed)?;
    let steps: usize = demos.iter().map(Demo::len).sum();
    // The demo file's `task` names what the demos are of: the task file's `name` (fr3_pick_cup, r1_lite_pick_vegetable).
    let name = task.cfg.name.clone();
    write_json(out, &DemoSet { task: name.clone(), demos })?;
    println!("wrote {n} {name} demos ({steps} steps at {} Hz) to {}", task.cfg.policy_rate_hz, out.display());
    Ok(())
}

/// `n` in-process episodes of the checkpoint in `checkpoint` (seeds `seed + i`); prints the summary (success
/// rate, mode counts, γ, mean K) and, given `out`, writes it with every episode there as JSON.
pub fn eval(
    checkpoint: &Path,
    task: &Path,
    profile: &Path,
    n: usize,
    seed: u64,
    out: Option<&Path>,
) -> anyhow::Result<EvalReport> {
    let (task, profile) = load_task(task, profile)?;
    let report = evaluate(checkpoint, &task, &profile, n, seed)?;
    println!("{report}");
    if let Some(out) = out {
        write_json(out, &report)?;
    }
    Ok(report)
}

/// A pick task (Pick Cup by default) as a task of the training-efficiency curves (`mars-hil curve`).
pub struct PickCurve {
    pub task: std::path::PathBuf,
    pub profile: std::path::PathBuf,
    pub demos: usize,
    pub episodes: usize,
}

impl mars_policy::curve::CurveTask for PickCurve {
    fn title(&self) -> String {
        let name = load_task(&self.task, &self.profile).map(|(t, _)| t.cfg.name).unwrap_or_else(|_| "pick".into());
        format!("{name}, {} demos, {} episodes per snapshot", self.demos, self.episodes)
    }

    fn demos(&self, seed: u64, path: &Path) -> anyhow::Result<()> {
        demos(&self.task, &self.profile, self.demos, seed, path)
    }

    fn evaluate(&self, dir: &Path, demos: &Path, seed: u64) -> anyhow::Result<mars_policy::curve::Score> {
        let (task, profile) = load_task(&self.task, &self.profile)?;
        let r = evaluate(dir, &task, &profile, self.episodes, seed)?;
        // The grasps' shares in the demos this checkpoint was trained on (the expert balances them).
        let mut demo_counts = vec![0usize; task.n_modes()];
        for m in mars_policy::demo_file::load_demos(demos)?.demos.iter().filter_map(|d| d.mode) {
            if let Some(c) = demo_counts.get_mut(m) {
                *c += 1;
            }
        }
        let tv =
            mars_tasks::stats::shares(&demo_counts).map(|s| mars_tasks::stats::modes::tv_to(&r.mode_counts, &s) as f32);
        let success_pct = 100.0 * r.success_rate();
        Ok(mars_policy::curve::Score { success_pct, gamma: r.gamma, mean_k: r.mean_k, tv })
    }
}
