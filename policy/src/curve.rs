//! Training-efficiency curves (the paper's Fig. 1(e) and Table S2): each policy is trained with a snapshot
//! every N epochs, every snapshot is evaluated, and the success rate and γ are reported per epoch as mean ±
//! std over training seeds, with the epochs each policy needs to reach X % success. The task is a parameter
//! (demos and evaluation come as closures), so nav2d (`mars curve`) and Pick Cup (`mars-hil curve`) share it.

use crate::config::{PolicyConfig, PolicyKind};
use crate::plots::{Area, FONT, LINE_SIZE, legend, palette, plot_err, to_png};
use crate::stats::MeanStd;
use crate::train::{Snapshots, train_with_snapshots};
use anyhow::Context;
use mars_tasks::stats::{Estimate, mean_over_seeds};
use plotters::prelude::*;
use serde::{Deserialize, Serialize};
use std::fmt::Write;
use std::path::{Path, PathBuf};

/// What one evaluation of one snapshot gives.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Score {
    /// Success rate in percent.
    pub success_pct: f32,
    pub gamma: f32,
    pub mean_k: f32,
    /// Total-variation distance between the successful rollouts' mode shares and the demos' (nav2d's passages
    /// against the layout's shares; a pick task's grasps against its demo file's); `None` where the demos have
    /// no mode.
    #[serde(default)]
    pub tv: Option<f32>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SnapshotScore {
    pub kind: PolicyKind,
    pub seed: u64,
    pub epoch: usize,
    pub score: Score,
}

#[derive(Debug, Clone, Serialize)]
pub struct CurvePoint {
    pub epoch: usize,
    pub success_pct: MeanStd,
    pub gamma: MeanStd,
    pub mean_k: MeanStd,
}

/// The first snapshot epoch at which each seed reached `threshold_pct` success (`None`: it never did).
#[derive(Debug, Clone, Serialize)]
pub struct EpochsTo {
    pub threshold_pct: f32,
    pub per_seed: Vec<Option<usize>>,
}

impl EpochsTo {
    /// "12.0 ± 2.0 (3/3 seeds)", or "not reached (0/3 seeds)".
    pub fn summary(&self) -> String {
        let reached: Vec<f32> = self.per_seed.iter().flatten().map(|&e| e as f32).collect();
        let n = self.per_seed.len();
        if reached.is_empty() {
            return format!("not reached (0/{n} seeds)");
        }
        format!("{:.1} ({}/{n} seeds)", MeanStd::of(&reached), reached.len())
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct PolicyCurve {
    pub kind: PolicyKind,
    pub points: Vec<CurvePoint>,
    pub epochs_to: Vec<EpochsTo>,
    /// Over the last quarter of the snapshots (epoch > ¾ of the last): each seed's mean, then the mean over seeds
    /// with its 95 % t interval (unbounded with one seed). One snapshot's γ swings with the seed; this is the
    /// stable summary of where training ends up.
    pub late_success_pct: Estimate,
    pub late_gamma: Estimate,
    /// The same for the TV distance to the demos' shares, when the task gives it.
    pub late_tv: Option<Estimate>,
}

/// The command-line arguments every `curve` subcommand shares (`mars curve`, `mars-hil curve`).
#[derive(Debug, Clone, clap::Args)]
pub struct CurveArgs {
    /// Policy config every training starts from.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Training seeds 0..N (each also seeds its demos).
    #[arg(long, default_value_t = 5)]
    pub seeds: u64,
    #[arg(long, default_value_t = 100)]
    pub demos: usize,
    #[arg(long, default_value_t = 40)]
    pub epochs: usize,
    /// A snapshot (and its evaluation) every N epochs, and at the last.
    #[arg(long, default_value_t = 5)]
    pub every: usize,
    /// Evaluation episodes per snapshot.
    #[arg(long, default_value_t = 50)]
    pub episodes: usize,
    /// Seed of the evaluation episodes (the same for every snapshot).
    #[arg(long, default_value_t = 1000)]
    pub eval_seed: u64,
    /// Policies to compare.
    #[arg(long, value_parser = crate::kind_arg::policy_kind_parser(), value_delimiter = ',', default_value = "mars,fm,a2a")]
    pub policies: Vec<PolicyKind>,
    /// Success rates (percent) whose epochs-to are reported.
    #[arg(long, value_delimiter = ',', default_value = "50,80,90")]
    pub thresholds: Vec<f32>,
    /// Trainings (then evaluations) at the same time (default: one per core).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Score the snapshots an earlier run left in --out again, without training (e.g. with more episodes).
    #[arg(long)]
    pub rescore: bool,
}

impl CurveArgs {
    pub fn options(&self) -> CurveOptions {
        let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
        CurveOptions {
            policies: self.policies.clone(),
            seeds: self.seeds,
            epochs: self.epochs,
            every: self.every,
            jobs: self.jobs.unwrap_or(cores).max(1),
            thresholds: self.thresholds.clone(),
            eval_seed: self.eval_seed,
            rescore: self.rescore,
        }
    }

    /// The flags as given, for the report's "Command:" line.
    pub fn command_line(&self, program: &str, extra: &str) -> String {
        let policies: Vec<&str> = self.policies.iter().map(|k| k.name()).collect();
        let rescore = if self.rescore { " --rescore" } else { "" };
        let thresholds: Vec<String> = self.thresholds.iter().map(|t| format!("{t}")).collect();
        let paths: String = [("--config", &self.config), ("--out", &self.out)]
            .iter()
            .filter_map(|(flag, p)| p.as_ref().map(|p| format!(" {flag} {}", p.display())))
            .collect();
        format!(
            "{program} curve{extra}{paths}{} --seeds {} --demos {} --epochs {} --every {} --episodes {} --eval-seed {} \
             --policies {} --thresholds {}",
            rescore,
            self.seeds,
            self.demos,
            self.epochs,
            self.every,
            self.episodes,
            self.eval_seed,
            policies.join(","),
            thresholds.join(",")
        )
    }
}

pub struct CurveOptions {
    pub policies: Vec<PolicyKind>,
    /// Training seeds 0..seeds (each seed also seeds its demos).
    pub seeds: u64,
    pub epochs: usize,
    /// A snapshot every this many epochs (and at the last).
    pub every: usize,
    /// Trainings (then evaluations) run at the same time.
    pub jobs: usize,
    /// Success rates (percent) whose epochs-to are reported.
    pub thresholds: Vec<f32>,
    /// Seed of the evaluation episodes, the same for every snapshot: the curves differ by the model only.
    pub eval_seed: u64,
    /// Do not train: score the snapshots already under `out` (same seeds, policies and epochs).
    pub rescore: bool,
}

/// Means and spreads per policy and epoch, and epochs-to-X per seed.
pub fn aggregate(scores: &[SnapshotScore], policies: &[PolicyKind], thresholds: &[f32]) -> Vec<PolicyCurve> {
    policies
        .iter()
        .map(|&kind| {
            let mine: Vec<&SnapshotScore> = scores.iter().filter(|s| s.kind == kind).collect();
            let mut epochs: Vec<usize> = mine.iter().map(|s| s.epoch).collect();
            epochs.sort_unstable();
            epochs.dedup();
            let points = epochs
                .iter()
                .map(|&epoch| {
                    let at: Vec<&Score> = mine.iter().filter(|s| s.epoch == epoch).map(|s| &s.score).collect();
                    let of = |f: fn(&Score) -> f32| MeanStd::of(&at.iter().map(|s| f(s)).collect::<Vec<_>>());
                    CurvePoint {
                        epoch,
                        success_pct: of(|s| s.success_pct),
                        gamma: of(|s| s.gamma),
                        mean_k: of(|s| s.mean_k),
                    }
                })
                .collect();
            let mut seeds: Vec<u64> = mine.iter().map(|s| s.seed).collect();
            seeds.sort_unstable();
            seeds.dedup();
            let epochs_to = thresholds
                .iter()
                .map(|&threshold_pct| EpochsTo {
                    threshold_pct,
                    per_seed: seeds
                        .iter()
                        .map(|&seed| {
                            mine.iter()
                                .filter(|s| s.seed == seed && s.score.success_pct >= threshold_pct)
                                .map(|s| s.epoch)
                                .min()
                        })
                        .collect(),
                })
                .collect();
            let last = mine.iter().map(|s| s.epoch).max().unwrap_or(0);
            let late = |seed: u64, f: &dyn Fn(&Score) -> Option<f32>| {
                let late = mine.iter().filter(|s| s.seed == seed && 4 * s.epoch > 3 * last);
                let v: Option<Vec<f32>> = late.map(|s| f(&s.score)).collect();
                v.map(|v| f64::from(MeanStd::of(&v).mean))
            };
            let over_seeds = |f: &dyn Fn(&Score) -> Option<f32>| {
                let v: Option<Vec<f64>> = seeds.iter().map(|&s| late(s, f)).collect();
                v.and_then(|v| mean_over_seeds(&v))
            };
            let nan = Estimate::new(f64::NAN, f64::NAN, f64::NAN);
            PolicyCurve {
                kind,
                points,
                epochs_to,
                late_success_pct: over_seeds(&|s| Some(s.success_pct)).unwrap_or(nan),
                late_gamma: over_seeds(&|s| Some(s.gamma)).unwrap_or(nan),
                late_tv: over_seeds(&|s| s.tv),
            }
        })
        .collect()
}

/// The snapshot directories under `dir` (`epoch_NNNN`), by epoch.
pub fn snapshot_dirs(dir: &Path) -> anyhow::Result<Vec<(usize, PathBuf)>> {
    let mut out: Vec<(usize, PathBuf)> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read the snapshot folder {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter_map(|p| {
            let epoch = p.file_name()?.to_str()?.strip_prefix("epoch_")?.parse().ok()?;
            Some((epoch, p))
        })
        .collect();
    out.sort();
    Ok(out)
}

/// A task the curves run on: where its demos come from and how a checkpoint is scored.
pub trait CurveTask: Sync {
    /// A title for the table and plot.
    fn title(&self) -> String;
    /// Writes the demos that training seed `seed` uses to `path`.
    fn demos(&self, seed: u64, path: &Path) -> anyhow::Result<()>;
    /// Scores the checkpoint in `dir`, trained on the demos at `demos`, on episodes seeded from `seed`.
    fn evaluate(&self, dir: &Path, demos: &Path, seed: u64) -> anyhow::Result<Score>;
}

/// How a policy is trained with snapshots.
pub enum Trainer {
    /// In this process (the `mars` binary, whose allocator suits candle).
    InProcess,
    /// As `<mars> train … --snapshot-every N`, one process per training, its log in `<dir>/train.log`: for
    /// binaries whose global allocator is not the one training should run on (`mars-hil` counts allocations).
    Command(PathBuf),
}

impl Trainer {
    fn train(&self, config: &Path, cfg: &PolicyConfig, demos: &Path, dir: &Path, every: usize) -> anyhow::Result<()> {
        let snaps = Snapshots { every, dir: dir.join("snapshots") };
        match self {
            Trainer::InProcess => {
                let set = crate::demo_file::load_demos(demos)?;
                let t = train_with_snapshots(cfg, &set.demos, indicatif::ProgressBar::hidden(), Some(&snaps))?;
                t.save(dir)?;
            }
            Trainer::Command(mars) => {
                std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
                let log = std::fs::File::create(dir.join("train.log"))
                    .with_context(|| format!("cannot write {}", dir.join("train.log").display()))?;
                let status = std::process::Command::new(mars)
                    .args(["train", "--policy", cfg.kind.name()])
                    .arg("--config")
                    .arg(config)
                    .arg("--demos")
                    .arg(demos)
                    .arg("--out")
                    .arg(dir)
                    .args(["--epochs", &cfg.train.epochs.to_string(), "--seed", &cfg.train.seed.to_string()])
                    .args(["--snapshot-every", &every.to_string()])
                    .env("RAYON_NUM_THREADS", "1")
                    .stdout(log.try_clone()?)
                    .stderr(log)
                    .status()
                    .with_context(|| format!("cannot start {}", mars.display()))?;
                anyhow::ensure!(
                    status.success(),
                    "{} failed ({status}); see {}",
                    mars.display(),
                    dir.join("train.log").display()
                );
            }
        }
        Ok(())
    }
}

/// Trains every policy × seed with snapshots under `out/seed<s>/<policy>/` (the seed's demos in
/// `out/seed<s>/demos.json`), scores every snapshot, then writes `out/curves.md`, `out/curves.json` and
/// `out/curves.png`. `config` is the policy config every training starts from.
pub fn run(
    out: &Path,
    config: &Path,
    o: &CurveOptions,
    task: &dyn CurveTask,
    trainer: &Trainer,
    command: &str,
) -> anyhow::Result<Vec<PolicyCurve>> {
    anyhow::ensure!(o.seeds >= 1, "--seeds must be at least 1");
    anyhow::ensure!(o.every >= 1 && o.every <= o.epochs, "--every must lie in 1..=--epochs ({})", o.epochs);
    anyhow::ensure!(!o.policies.is_empty(), "--policies names no policy");
    let base = PolicyConfig::load(config)?;
    let mut jobs = Vec::new();
    for seed in 0..o.seeds {
        let demos = out.join(format!("seed{seed}")).join("demos.json");
        if !o.rescore {
            task.demos(seed, &demos)?;
        }
        for &kind in &o.policies {
            let mut cfg = base.clone();
            cfg.kind = kind;
            cfg.train.seed = seed;
            cfg.train.epochs = o.epochs;
            cfg.validate()?;
            jobs.push((cfg, demos.clone(), out.join(format!("seed{seed}")).join(kind.name())));
        }
    }
    if !o.rescore {
        let bar = progress(jobs.len(), "trainings");
        crate::jobs::parallel(&jobs, o.jobs, &|(cfg, demos, dir)| {
            trainer.train(config, cfg, demos, dir, o.every)?;
            bar.inc(1);
            Ok(())
        })?;
        bar.finish_and_clear();
    }
    let mut evals = Vec::new();
    for (cfg, demos, dir) in &jobs {
        let snaps = snapshot_dirs(&dir.join("snapshots"))?;
        // A rescore must find the run the flags describe, not a shorter or sparser one.
        let expected: Vec<usize> = (1..=o.epochs).filter(|e| e % o.every == 0 || *e == o.epochs).collect();
        let found: Vec<usize> = snaps.iter().map(|(e, _)| *e).collect();
        anyhow::ensure!(
            found == expected,
            "{}: snapshots at epochs {found:?}, but --epochs {} --every {} means {expected:?}",
            dir.display(),
            o.epochs,
            o.every
        );
        for (epoch, snap) in snaps {
            evals.push((cfg.kind, cfg.train.seed, epoch, snap, demos.clone()));
        }
    }
    let bar = progress(evals.len(), "snapshots scored");
    let scores = crate::jobs::parallel(&evals, o.jobs, &|(kind, seed, epoch, snap, demos)| {
        let score = task.evaluate(snap, demos, o.eval_seed)?;
        std::fs::write(snap.join("score.json"), serde_json::to_string_pretty(&score)?)
            .with_context(|| format!("cannot write {}", snap.display()))?;
        bar.inc(1);
        Ok(SnapshotScore { kind: *kind, seed: *seed, epoch: *epoch, score })
    })?;
    bar.finish_and_clear();
    let curves = aggregate(&scores, &o.policies, &o.thresholds);
    let title = task.title();
    let md = render(&curves, &title, command, o) + &paired_against_first(&scores, &o.policies);
    std::fs::write(out.join("curves.md"), &md).with_context(|| format!("cannot write {}", out.display()))?;
    std::fs::write(out.join("curves.json"), serde_json::to_string_pretty(&(&curves, &scores))?)
        .with_context(|| format!("cannot write {}", out.display()))?;
    plot_curves(&curves, &title, &out.join("curves.png"))?;
    println!("\n{md}");
    Ok(curves)
}

fn progress(n: usize, what: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(n as u64);
    let style = indicatif::ProgressStyle::with_template(&format!("[{{bar:30}}] {{pos}}/{{len}} {what} ({{elapsed}})"))
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .progress_chars("=> ");
    bar.set_style(style);
    bar
}

/// The table per epoch and the epochs-to-X table, as markdown.
pub fn render(curves: &[PolicyCurve], title: &str, command: &str, o: &CurveOptions) -> String {
    let mut s = format!("# Training efficiency: {title}\n\n");
    let _ = writeln!(
        s,
        "Command: `{command}`; per epoch the mean ± std over training seeds 0..{} (each seed also seeds its \
         demos); over the last quarter each seed's mean, then the mean over seeds with its 95 % t interval. Every \
         snapshot evaluated on the same episode seeds from {}.\n",
        o.seeds, o.eval_seed
    );
    let names: Vec<&str> = curves.iter().map(|c| c.kind.name()).collect();
    let _ = writeln!(
        s,
        "| epoch | {} |",
        names.iter().map(|n| format!("{n} success % | {n} γ")).collect::<Vec<_>>().join(" | ")
    );
    let _ = writeln!(s, "|---:|{}", "---:|".repeat(2 * names.len()));
    let epochs: Vec<usize> = {
        let mut e: Vec<usize> = curves.iter().flat_map(|c| c.points.iter().map(|p| p.epoch)).collect();
        e.sort_unstable();
        e.dedup();
        e
    };
    for epoch in epochs {
        let cells: Vec<String> = curves
            .iter()
            .map(|c| match c.points.iter().find(|p| p.epoch == epoch) {
                Some(p) => format!("{:.1} | {:.2}", p.success_pct, p.gamma),
                None => "– | –".into(),
            })
            .collect();
        let _ = writeln!(s, "| {epoch} | {} |", cells.join(" | "));
    }
    let _ = writeln!(s);
    let thresholds: Vec<f32> =
        curves.first().map(|c| c.epochs_to.iter().map(|e| e.threshold_pct).collect()).unwrap_or_default();
    let _ = writeln!(
        s,
        "| policy | {} | success % over the last quarter | γ over the last quarter | TV to the demos over the last \
         quarter | mean K at the last epoch |",
        thresholds.iter().map(|t| format!("epochs to {t:.0} % success")).collect::<Vec<_>>().join(" | ")
    );
    let _ = writeln!(s, "|---|{}---:|---:|---:|---:|", "---:|".repeat(thresholds.len()));
    for c in curves {
        let to: Vec<String> = c.epochs_to.iter().map(EpochsTo::summary).collect();
        let k = c.points.last().map(|p| format!("{:.2}", p.mean_k)).unwrap_or_else(|| "–".into());
        let tv = c.late_tv.map_or_else(|| "–".into(), |e| format!("{e:.2}"));
        let (success, gamma) = (c.late_success_pct, c.late_gamma);
        let _ = writeln!(s, "| {} | {} | {success:.1} | {gamma:.2} | {tv} | {k} |", c.kind, to.join(" | "));
    }
    s
}

/// Every policy after the first against the first, per snapshot epoch: the success difference paired by training
/// seed (the two were trained on that seed's demos and scored on the same episodes), its mean over the seeds with
/// the 95 % t interval, and whether they differ. "Converges faster" is a claim about these early epochs.
pub fn paired_against_first(scores: &[SnapshotScore], policies: &[PolicyKind]) -> String {
    let Some((&base, others)) = policies.split_first().filter(|(_, others)| !others.is_empty()) else {
        return String::new();
    };
    let mut epochs: Vec<usize> = scores.iter().map(|s| s.epoch).collect();
    epochs.sort_unstable();
    epochs.dedup();
    let success = |kind: PolicyKind, seed: u64, epoch: usize| {
        scores.iter().find(|s| s.kind == kind && s.seed == seed && s.epoch == epoch).map(|s| s.score.success_pct)
    };
    let mut s = format!("\nSuccess against {base}, paired by seed (points, mean over seeds, 95 % t interval):\n\n");
    let _ =
        writeln!(s, "| epoch | {} |", others.iter().map(|k| format!("{k} − {base}")).collect::<Vec<_>>().join(" | "));
    let _ = writeln!(s, "|---:|{}", "---|".repeat(others.len()));
    for epoch in epochs {
        let cells: Vec<String> = others
            .iter()
            .map(|&kind| {
                let diffs: Vec<f64> = scores
                    .iter()
                    .filter(|x| x.kind == base && x.epoch == epoch)
                    .filter_map(|x| Some(f64::from(success(kind, x.seed, epoch)? - x.score.success_pct)))
                    .collect();
                match mean_over_seeds(&diffs) {
                    Some(e) => format!("{e:.1} {}", crate::family_diff::verdict(e)),
                    None => "–".into(),
                }
            })
            .collect();
        let _ = writeln!(s, "| {epoch} | {} |", cells.join(" | "));
    }
    s
}

/// Success rate and γ against training epochs, one line per policy with its ± std band shaded (paper
/// Fig. 1(e)): the training-efficiency curves of `curve::run`.
pub fn plot_curves(curves: &[PolicyCurve], title: &str, path: &Path) -> anyhow::Result<()> {
    to_png(path, (LINE_SIZE.0, 2 * LINE_SIZE.1), |root| {
        root.fill(&WHITE).map_err(plot_err)?;
        let (top, bottom) = root.split_vertically(LINE_SIZE.1);
        draw_curve_panel(&top, curves, &format!("{title}: success rate"), "success %", 100.0, |p| p.success_pct)?;
        draw_curve_panel(&bottom, curves, &format!("{title}: modal balance γ"), "γ", 1.0, |p| p.gamma)
    })
}

fn draw_curve_panel(
    root: &Area,
    curves: &[PolicyCurve],
    caption: &str,
    y_desc: &str,
    y_max: f32,
    value: fn(&CurvePoint) -> MeanStd,
) -> anyhow::Result<()> {
    let last = curves.iter().flat_map(|c| c.points.iter().map(|p| p.epoch)).max().unwrap_or(1).max(1) as f32;
    let mut chart = ChartBuilder::on(root)
        .caption(caption, (FONT, 22))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f32..last, 0f32..y_max * 1.05)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("epoch")
        .y_desc(y_desc)
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 16))
        .light_line_style(WHITE)
        .x_label_formatter(&|e| format!("{e:.0}"))
        .y_label_formatter(&|v| if y_max > 1.0 { format!("{v:.0}") } else { format!("{v:.1}") })
        .draw()
        .map_err(plot_err)?;
    for (i, c) in curves.iter().enumerate() {
        let color = palette(i);
        let pts: Vec<(f32, MeanStd)> = c.points.iter().map(|p| (p.epoch as f32, value(p))).collect();
        // The band: mean + std forward, mean − std back, clipped to the axis.
        let band: Vec<(f32, f32)> = pts
            .iter()
            .map(|(e, v)| (*e, (v.mean + v.std).min(y_max)))
            .chain(pts.iter().rev().map(|(e, v)| (*e, (v.mean - v.std).max(0.0))))
            .collect();
        chart.draw_series(std::iter::once(Polygon::new(band, color.mix(0.2).filled()))).map_err(plot_err)?;
        chart
            .draw_series(LineSeries::new(pts.iter().map(|(e, v)| (*e, v.mean)), color.stroke_width(2)))
            .map_err(plot_err)?
            .label(c.kind.name())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3)));
        chart.draw_series(pts.iter().map(|(e, v)| Circle::new((*e, v.mean), 3, color.filled()))).map_err(plot_err)?;
    }
    legend(&mut chart, SeriesLabelPosition::LowerRight)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn score(kind: PolicyKind, seed: u64, epoch: usize, success_pct: f32, gamma: f32) -> SnapshotScore {
        SnapshotScore { kind, seed, epoch, score: Score { success_pct, gamma, mean_k: 2.0, tv: Some(gamma / 2.0) } }
    }

    #[test]
    fn points_average_over_seeds_and_epochs_to_takes_each_seeds_first_crossing() {
        let scores = vec![
            score(PolicyKind::Mars, 0, 5, 40.0, 0.5),
            score(PolicyKind::Mars, 1, 5, 60.0, 0.7),
            score(PolicyKind::Mars, 0, 10, 90.0, 0.8),
            score(PolicyKind::Mars, 1, 10, 70.0, 0.6),
            // A later dip does not undo the crossing.
            score(PolicyKind::Mars, 0, 15, 85.0, 0.8),
            score(PolicyKind::Mars, 1, 15, 95.0, 0.8),
            score(PolicyKind::Fm, 0, 5, 10.0, 0.2),
        ];
        let c = aggregate(&scores, &[PolicyKind::Mars, PolicyKind::Fm], &[50.0, 80.0]);
        let mars = &c[0];
        assert_eq!(mars.points.iter().map(|p| p.epoch).collect::<Vec<_>>(), [5, 10, 15]);
        assert_eq!(mars.points[0].success_pct.mean, 50.0);
        assert!((mars.points[0].success_pct.std - 200f32.sqrt()).abs() < 1e-4);
        assert_eq!(mars.epochs_to[0].per_seed, [Some(10), Some(5)]);
        assert_eq!(mars.epochs_to[1].per_seed, [Some(10), Some(15)]);
        assert_eq!(mars.epochs_to[1].summary(), "12.5 ± 3.5 (2/2 seeds)");
        assert_eq!(c[1].epochs_to[0].per_seed, [None]);
        assert_eq!(c[1].epochs_to[0].summary(), "not reached (0/1 seeds)");
        // Last quarter = epoch > 11.25, i.e. epoch 15 only: seeds 85 and 95, so 90 ± t₀.₉₇₅(1)·5 ≈ 90 ± 63.53.
        let late = mars.late_success_pct;
        assert_eq!(late.value, 90.0);
        assert!((late.hi - 90.0 - 12.706 * 5.0).abs() < 1e-2 && (late.lo + late.hi - 180.0).abs() < 1e-9);
        assert!((mars.late_gamma.value - 0.8).abs() < 1e-6 && (mars.late_gamma.hi - 0.8).abs() < 1e-5);
        assert!((mars.late_tv.unwrap().value - 0.4).abs() < 1e-6);
        // One seed: the interval is unbounded (undecided), never a spread of zero.
        assert!(c[1].late_success_pct.hi.is_infinite());
    }

    #[test]
    fn the_paired_table_differences_each_seed_against_the_first_policy() {
        let mut scores = Vec::new();
        for (seed, mars, fm) in [(0, 60.0, 20.0), (1, 70.0, 25.0), (2, 65.0, 30.0)] {
            scores.push(score(PolicyKind::Mars, seed, 5, mars, 0.5));
            scores.push(score(PolicyKind::Fm, seed, 5, fm, 0.5));
            // At epoch 10 the two are alike: FM ahead on one seed, behind on the others (0 ± 4.303·√7/√3 = ±6.57).
            scores.push(score(PolicyKind::Mars, seed, 10, 90.0, 0.5));
            scores.push(score(PolicyKind::Fm, seed, 10, 90.0 + [-2.0, 3.0, -1.0][seed as usize], 0.5));
        }
        let md = paired_against_first(&scores, &[PolicyKind::Mars, PolicyKind::Fm]);
        // FM − MARS at epoch 5: −40, −45, −35 → −40 ± 4.303·5/√3 = −40 ± 12.42.
        assert!(md.contains("| 5 | -40.0 (-52.4–-27.6) differ |"), "{md}");
        assert!(md.contains("| 10 | 0.0 (-6.6–6.6) undecided |"), "{md}");
        // A policy alone has nothing to be paired with.
        assert_eq!(paired_against_first(&scores, &[]), "");
        assert_eq!(paired_against_first(&scores, &[PolicyKind::Mars]), "");
    }

    #[test]
    fn snapshot_dirs_are_found_by_name_and_sorted_by_epoch() {
        let dir = std::env::temp_dir().join(format!("mars_curve_snaps_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        for name in ["epoch_0010", "epoch_0002", "notes", "epoch_x"] {
            std::fs::create_dir_all(dir.join(name)).unwrap();
        }
        let found: Vec<usize> = snapshot_dirs(&dir).unwrap().into_iter().map(|(e, _)| e).collect();
        assert_eq!(found, [2, 10]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
