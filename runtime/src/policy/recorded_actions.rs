//! A recorded episode's actions as the policy's chunks (`marsd --replay-actions DATASET --replay-episode N`, what
//! `mars-hil replay` runs): the engine is not called; at each period where the run made a call, the chunk it
//! executed is handed to the servo again, and where it made none (a call over budget, no camera frame) the
//! chunk in force goes on, as it did. The episode runs with the run's seed and episode number, so it starts
//! from the same pose. What comes out is the plant's answer to the same commands.

use std::path::Path;

use anyhow::Context;
use mars_lerobot::{Keys, LeRobotDataset};
use serde::Deserialize;

use crate::record::META_FILE;

/// What `meta/mars.json` says of the run (see [`crate::record`]).
#[derive(Debug, Clone, Deserialize)]
pub struct RunMeta {
    pub seed: u64,
    pub checkpoint: std::path::PathBuf,
    /// Absent in recordings made before the configuration was kept.
    #[serde(default)]
    pub config: Option<std::path::PathBuf>,
    pub episodes: Vec<EpisodeMeta>,
}

#[derive(Debug, Clone, Deserialize)]
pub struct EpisodeMeta {
    pub marsd_episode: u64,
    pub success: bool,
    #[serde(default)]
    pub mode: Option<usize>,
    pub rest: Vec<f32>,
}

impl RunMeta {
    pub fn load(dataset: &Path) -> anyhow::Result<Self> {
        let path = dataset.join("meta").join(META_FILE);
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("{}: not a dataset recorded by marsd --record", path.display()))?;
        serde_json::from_str(&text).with_context(|| format!("{}", path.display()))
    }

    pub fn episode(&self, n: usize) -> anyhow::Result<&EpisodeMeta> {
        self.episodes.get(n).with_context(|| format!("episode {n}: the dataset has {} (0-based)", self.episodes.len()))
    }
}

/// One recorded episode's executed actions and where its calls were.
#[derive(Debug, Clone)]
pub struct RecordedActions {
    /// marsd's number of the episode (its start pose is drawn from the seed and this).
    pub marsd_episode: u64,
    pub seed: u64,
    /// `len × action_dim` values, the action in force in each period.
    actions: Vec<f32>,
    /// Per period: the run published a new chunk then.
    calls: Vec<bool>,
    action_dim: usize,
}

impl RecordedActions {
    /// Episode `n` (0-based, as LeRobot numbers them) of a dataset `marsd --record` wrote.
    pub fn load(dataset: &Path, n: usize) -> anyhow::Result<Self> {
        let meta = RunMeta::load(dataset)?;
        let em = meta.episode(n)?;
        let ds = LeRobotDataset::open(dataset)?;
        anyhow::ensure!(
            ds.vector_len("mars.call")? == 1,
            "{}: mars.call must have 1 value a frame (as marsd --record writes it)",
            dataset.display()
        );
        let keys = Keys { state: "mars.call".into(), action: "action".into(), images: vec![] };
        let (episodes, _) = ds.read(&keys, (0, 0))?;
        let e = episodes.get(n).with_context(|| {
            format!(
                "episode {n}: meta/{META_FILE} lists {} episodes but the dataset has {} (0-based)",
                meta.episodes.len(),
                episodes.len()
            )
        })?;
        anyhow::ensure!(e.len > 0, "episode {n} has no frames");
        Ok(Self {
            marsd_episode: em.marsd_episode,
            seed: meta.seed,
            action_dim: e.action.len() / e.len,
            actions: e.action.clone(),
            calls: e.state.iter().map(|c| *c == 1.0).collect(),
        })
    }

    pub fn action_dim(&self) -> usize {
        self.action_dim
    }

    /// The run published a chunk in period `k`.
    pub fn made_call(&self, k: u64) -> bool {
        self.calls.get(k as usize).is_some_and(|c| *c)
    }

    /// Period `k` is past the recording's end.
    pub fn past_end(&self, k: u64) -> bool {
        k as usize >= self.calls.len()
    }

    /// The chunk of `out.len() / action_dim` actions the run published in period `k`, into `out`; false if it
    /// published none then (the chunk in force goes on). Past the recording's end (the run's episode had ended
    /// there; the replay's may not have) the last action is held. Allocation-free.
    pub fn chunk_at(&self, k: u64, out: &mut [f32]) -> bool {
        let k = k as usize;
        let d = self.action_dim;
        let last = self.calls.len() - 1;
        if k <= last && !self.calls[k] {
            return false;
        }
        for (i, a) in out.chunks_exact_mut(d).enumerate() {
            let t = (k + i).min(last);
            a.copy_from_slice(&self.actions[t * d..(t + 1) * d]);
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn recorded() -> RecordedActions {
        // 5 periods of 1-D actions 10, 11, …; calls at 0 and 4 (the call at 2 was over budget).
        RecordedActions {
            marsd_episode: 1,
            seed: 0,
            actions: vec![10.0, 11.0, 12.0, 13.0, 14.0],
            calls: vec![true, false, false, false, true],
            action_dim: 1,
        }
    }

    #[test]
    fn chunks_come_where_the_run_published_them_and_the_last_action_holds_past_the_end() {
        let r = recorded();
        let mut out = [0.0f32; 2];
        assert!(r.chunk_at(0, &mut out));
        assert_eq!(out, [10.0, 11.0]);
        assert!(!r.chunk_at(2, &mut out), "no chunk where the run made no call");
        assert!(r.chunk_at(4, &mut out));
        assert_eq!(out, [14.0, 14.0]);
        assert!(r.chunk_at(7, &mut out));
        assert_eq!(out, [14.0, 14.0]);
    }
}
