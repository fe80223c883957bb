//! `marsd replay DATASET --episode N`: a recorded run's policy calls made again, offline, through the same
//! engine marsd ran — each call's observation and action history from the recording, its noise from the seed
//! marsd used for that very call, its step count the one marsd used — and the replayed chunks compared with the
//! actions the run executed. Bit for bit equal on the recording's checkpoint and this code; otherwise the first
//! call that differs, and by how much: "why did it pick left" answered after the fact.
//!
//! (In `marsd`, not `mars`: the engine is what ran, and the `mars` command has only the candle model, which equals
//! the engine to ~1e-6, not bit for bit.)

use std::path::PathBuf;

use anyhow::Context;
use mars_engine::{Engine, EngineConfig};
use mars_lerobot::{Keys, LeRobotDataset};
use serde::Deserialize;

use crate::record::{META_FILE, call_seed};

#[derive(clap::Args, Debug, Clone)]
pub struct ReplayArgs {
    /// A dataset recorded by `marsd --record`.
    pub dataset: PathBuf,
    /// The dataset's episode (0-based, as LeRobot numbers them).
    #[arg(long)]
    pub episode: usize,
    /// Replay with another checkpoint (default: the one the run used, from meta/mars.json).
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
}

#[derive(Deserialize)]
struct RunMeta {
    seed: u64,
    checkpoint: PathBuf,
    episodes: Vec<EpisodeMeta>,
}

#[derive(Deserialize)]
struct EpisodeMeta {
    marsd_episode: u64,
    rest: Vec<f32>,
}

/// Where replay first left the recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Divergence {
    /// The period (frame_index) of the call.
    pub frame: usize,
    /// The action of its chunk, and the value in it.
    pub action: usize,
    pub value: usize,
    pub recorded: f32,
    pub replayed: f32,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ReplayReport {
    pub episode: usize,
    pub checkpoint: PathBuf,
    pub calls: usize,
    pub actions_compared: usize,
    /// Every compared value equal bit for bit.
    pub identical: bool,
    pub max_abs_diff: f32,
    pub first_divergence: Option<Divergence>,
}

impl std::fmt::Display for ReplayReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "episode {}: {} policy calls replayed with {}, {} executed actions compared: ",
            self.episode,
            self.calls,
            self.checkpoint.display(),
            self.actions_compared
        )?;
        match &self.first_divergence {
            None => writeln!(f, "identical bit for bit"),
            Some(d) => writeln!(
                f,
                "they differ (max |Δ| {:.3e}); first at the call of period {}, action {} value {}: recorded {} replayed {}",
                self.max_abs_diff, d.frame, d.action, d.value, d.recorded, d.replayed
            ),
        }
    }
}

pub fn run(args: &ReplayArgs) -> anyhow::Result<ReplayReport> {
    let meta_path = args.dataset.join("meta").join(META_FILE);
    let meta: RunMeta = serde_json::from_str(
        &std::fs::read_to_string(&meta_path)
            .with_context(|| format!("{}: not a dataset recorded by marsd --record", meta_path.display()))?,
    )
    .with_context(|| format!("{}", meta_path.display()))?;
    let ds = LeRobotDataset::open(&args.dataset)?;
    let em = meta
        .episodes
        .get(args.episode)
        .with_context(|| format!("episode {}: the dataset has {} (0-based)", args.episode, meta.episodes.len()))?;
    let checkpoint = args.checkpoint.clone().unwrap_or(meta.checkpoint.clone());
    let mut engine = Engine::load(&checkpoint, EngineConfig::with_seed(0))
        .with_context(|| format!("checkpoint {}", checkpoint.display()))?;
    let (c, d) = (engine.chunk_len(), engine.action_dim());
    let images: Vec<String> = ds.info.features.iter().filter(|(_, f)| f.is_video()).map(|(k, _)| k.clone()).collect();
    let hw = match images.first() {
        Some(k) => ds.image_size(k)?,
        None => (0, 0),
    };
    // Before anything is read or decoded: the observation the recording makes must be the checkpoint's.
    let state_dim = ds.vector_len("observation.state")?;
    let pixels = (hw.0 as usize * hw.1 as usize * 3) * images.len();
    anyhow::ensure!(
        state_dim + pixels == engine.obs_dim(),
        "the recording's observation has {} values ({state_dim} of state and {} camera(s) of {}×{}), the \
         checkpoint {} takes {}",
        state_dim + pixels,
        images.len(),
        hw.0,
        hw.1,
        checkpoint.display(),
        engine.obs_dim()
    );
    let keys = Keys { state: "observation.state".into(), action: "action".into(), images };
    let ours = Keys { state: "mars.call".into(), action: "mars.k".into(), images: vec![] };
    anyhow::ensure!(
        ds.vector_len("mars.call")? == 1 && ds.vector_len("mars.k")? == 2,
        "{}: mars.call must have 1 value a frame and mars.k 2 (as marsd --record writes them)",
        args.dataset.display()
    );
    let (episodes, _) = ds.read(&keys, hw)?;
    let (extra, _) = ds.read(&ours, (0, 0))?;
    let (Some(e), Some(x)) = (episodes.get(args.episode), extra.get(args.episode)) else {
        anyhow::bail!(
            "episode {}: meta/{META_FILE} lists {} episodes but the dataset has {} (0-based)",
            args.episode,
            meta.episodes.len(),
            episodes.len()
        );
    };
    anyhow::ensure!(
        e.action.len() == e.len * d && em.rest.len() == d,
        "the recording's actions have {} values, the checkpoint's {d}",
        e.action.len() / e.len
    );
    let calls: Vec<usize> = (0..e.len).filter(|&t| x.state[t] == 1.0).collect();
    let mut obs = vec![0.0f32; engine.obs_dim()];
    let mut history: Vec<f32> = em.rest.iter().copied().cycle().take(c * d).collect();
    let mut report = ReplayReport {
        episode: args.episode,
        checkpoint: checkpoint.clone(),
        calls: calls.len(),
        actions_compared: 0,
        identical: true,
        max_abs_diff: 0.0,
        first_divergence: None,
    };
    for (n, &t) in calls.iter().enumerate() {
        obs[..state_dim].copy_from_slice(&e.state[t * state_dim..(t + 1) * state_dim]);
        let mut at = state_dim;
        for frames in &e.images {
            let len = frames.len() / e.len;
            mars_policy_format::observation::pixels_to_observation(
                &frames[t * len..(t + 1) * len],
                &mut obs[at..at + len],
            );
            at += len;
        }
        let k = x.action[t * 2 + 1];
        anyhow::ensure!(
            k.fract() == 0.0 && (1.0..=engine.k_max() as f32).contains(&k),
            "frame {t}: the recorded step count {k} is not in 1..={}",
            engine.k_max()
        );
        let k = k as usize;
        engine.reseed(call_seed(meta.seed, em.marsd_episode, t as u64));
        let out = engine.infer_with(&obs, &history, None, Some(k)).context("replaying a call")?;
        // The frames this chunk was in force for: up to C, until the next call.
        let end = calls.get(n + 1).copied().unwrap_or(e.len).min(t + c);
        for (i, frame) in (t..end).enumerate() {
            for j in 0..d {
                let (rec, rep) = (e.action[frame * d + j], out.chunk[i * d + j]);
                let diff = (rec - rep).abs();
                report.max_abs_diff = report.max_abs_diff.max(diff);
                if rec.to_bits() != rep.to_bits() {
                    report.identical = false;
                    report.first_divergence.get_or_insert(Divergence {
                        frame: t,
                        action: i,
                        value: j,
                        recorded: rec,
                        replayed: rep,
                    });
                }
            }
            report.actions_compared += 1;
        }
        // What the run fed its next call: this chunk as recorded (the run's own, not the replay's).
        if end - t == c {
            history.copy_from_slice(&e.action[t * d..(t + c) * d]);
        } else {
            history.copy_from_slice(out.chunk);
        }
    }
    Ok(report)
}
