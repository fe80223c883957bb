//! Where the diversity loss acts, measured on a trained policy: for the demo samples whose observation lies in
//! each named region of a layout, the target spread S_next, the source spread S_curr that the trained scheduler
//! gives (built exactly as in training, averaged over noise draws), how often ReLU(S_next − S_curr) is active,
//! ‖w‖∞, and what the m neighbours are made of (the sample's own demo, another passage than the sample's).
//! This is the evidence behind "why does MARS keep (or lose) a mode".

use crate::dataset::Dataset;
use crate::inference::MarsPolicy;
use crate::losses;
use crate::model::MarsModel;
use crate::train::randn;
use candle_core::{Device, Tensor};
use mars_tasks::demo::Demo;
use mars_tasks::nav2d::layout::{Layout, Rect};
use rand::SeedableRng;
use rand::rngs::StdRng;

/// Noise draws S_curr is averaged over (each draw is one training-time estimate).
const DRAWS: usize = 16;

#[derive(Debug, Clone, serde::Serialize)]
pub struct RegionStats {
    pub region: String,
    pub samples: usize,
    pub w_inf: f32,
    /// Per action dimension, mean over the region's samples (normalised units).
    pub w: Vec<f32>,
    pub s_next: Vec<f32>,
    pub s_curr: Vec<f32>,
    /// Fraction of (sample, dimension) pairs where S_next > S_curr: the diversity loss pushes w up there.
    pub relu_active: f32,
    /// Fraction of the neighbours that come from the sample's own demo (time-shifted copies of itself).
    pub same_demo: f32,
    /// Fraction of the neighbours whose demo went through another passage than the sample's.
    pub other_passage: f32,
}

/// The regions diagnosed, in route order: the entry gate, the junction, the passages, the merge, the exit gate.
pub fn region_names(layout: &Layout) -> Vec<String> {
    let mut names: Vec<String> = ["entry_gate", "junction"].iter().map(|s| s.to_string()).collect();
    names.extend(layout.passages.iter().map(|p| p.name.clone()));
    names.extend(["merge", "exit_gate"].iter().map(|s| s.to_string()));
    names.retain(|n| layout.named_rect(n).is_some());
    names
}

/// `data` is `Dataset::from_demos(demos, …)` with the checkpoint's m (the caller builds it once: the kNN is
/// the slow part).
pub fn diagnose(
    policy: &MarsPolicy,
    demos: &[Demo],
    data: &Dataset,
    layout: &Layout,
    seed: u64,
) -> anyhow::Result<Vec<RegionStats>> {
    let model = policy.model();
    let cfg = &model.cfg;
    let (c, d, h) = (cfg.chunk_len, cfg.action_dim, cfg.history_len);
    // Sample index → (demo, its passage); the dataset lays demos out one after the other.
    let owner: Vec<(usize, Option<usize>)> =
        demos.iter().enumerate().flat_map(|(i, demo)| std::iter::repeat_n((i, demo.mode), demo.len())).collect();
    let positions: Vec<[f32; 2]> =
        demos.iter().flat_map(|demo| demo.observations.iter().map(|o| [o[0], o[1]])).collect();
    let mut rng = StdRng::seed_from_u64(seed);
    let dev = Device::Cpu;
    let mut out = Vec::new();
    for name in region_names(layout) {
        let rect: Rect = layout.named_rect(&name).expect("region_names keeps existing regions");
        let idx: Vec<u32> = (0..data.len as u32).filter(|&i| rect.contains(positions[i as usize])).collect();
        if idx.is_empty() {
            continue;
        }
        let n = idx.len();
        let obs = Tensor::from_vec(rows(&data.obs, &idx, cfg.obs_dim), (n, cfg.obs_dim), &dev)?;
        let hist = Tensor::from_vec(rows(&data.history, &idx, h * d), (n, h, d), &dev)?;
        let nbr_idx = rows(&data.neighbours, &idx, data.m);
        let nbr_hist = Tensor::from_vec(rows(&data.history, &nbr_idx, h * d), (n, data.m, h, d), &dev)?;
        let w = model.weights(&model.encode(&obs)?, &hist)?;
        let mut s_curr = Tensor::zeros((n, d), candle_core::DType::F32, &dev)?;
        for _ in 0..DRAWS {
            let own = MarsModel::source(&hist, &w, &randn(&mut rng, &[n, c, d], &dev)?)?;
            let others = losses::neighbour_sources(&nbr_hist, &w, &randn(&mut rng, &[n, data.m, c, d], &dev)?)?;
            s_curr = (s_curr + losses::dispersion(&own, &others)?)?;
        }
        let s_curr: Vec<f32> = (s_curr / DRAWS as f64)?.flatten_all()?.to_vec1()?;
        let s_next = rows(&data.s_next, &idx, d);
        let active = s_next.iter().zip(&s_curr).filter(|(a, b)| a > b).count() as f32 / (n * d) as f32;
        let (mut same, mut other) = (0usize, 0usize);
        for (k, &i) in idx.iter().enumerate() {
            let (demo_i, mode_i) = owner[i as usize];
            for &j in &nbr_idx[k * data.m..(k + 1) * data.m] {
                let (demo_j, mode_j) = owner[j as usize];
                same += usize::from(demo_j == demo_i);
                other += usize::from(mode_j != mode_i);
            }
        }
        let w_v: Vec<f32> = w.flatten_all()?.to_vec1()?;
        let nm = (n * data.m) as f32;
        out.push(RegionStats {
            region: name,
            samples: n,
            w_inf: w.max(1)?.mean_all()?.to_scalar()?,
            w: column_means(&w_v, d),
            s_next: column_means(&s_next, d),
            s_curr: column_means(&s_curr, d),
            relu_active: active,
            same_demo: same as f32 / nm,
            other_passage: other as f32 / nm,
        });
    }
    Ok(out)
}

/// Rows `idx` of the row-major table `src` whose rows are `width` wide, one after the other.
fn rows<T: Copy>(src: &[T], idx: &[u32], width: usize) -> Vec<T> {
    idx.iter().flat_map(|&i| src[i as usize * width..(i as usize + 1) * width].iter().copied()).collect()
}

fn column_means(v: &[f32], d: usize) -> Vec<f32> {
    let n = (v.len() / d).max(1) as f32;
    (0..d).map(|k| v.iter().skip(k).step_by(d).sum::<f32>() / n).collect()
}

/// Where the policy heads at the fork, before any later chunk can change its mind: from each demo's first
/// state past the entry gate (its own history), `draws` chunks are sampled and each is classified by the
/// passage its heading points at (the line from the agent through the chunk's last target, extended to the
/// passage column, nearest passage centre). The demos' own chunks at the same states go through the same
/// classifier, which checks it. Comparing these shares with the rollouts' separates "the fork's sample picks
/// the passage" from "a later chunk leaves it".
#[derive(Debug, Clone, serde::Serialize)]
pub struct ForkChoices {
    pub states: usize,
    pub draws: usize,
    /// Per passage, shares of the policy's chunks (unclassified chunks count in `unclassified` only).
    pub policy: Vec<f32>,
    pub unclassified: f32,
    /// Per passage, shares of the demos' own chunks at the same states, through the same classifier.
    pub demos_classified: Vec<f32>,
    /// Per passage, the demos' recorded passages.
    pub demos_recorded: Vec<f32>,
}

/// The passage a chunk heads for, or `None` if it does not move toward the passages.
pub fn heading_passage(layout: &Layout, from: [f32; 2], to: [f32; 2]) -> Option<usize> {
    let x_col = layout.passages.iter().map(|p| p.x[0]).fold(f32::INFINITY, f32::min);
    let dx = to[0] - from[0];
    if dx < 1e-3 || !x_col.is_finite() {
        return None;
    }
    let y_hit = from[1] + (to[1] - from[1]) * (x_col - from[0]) / dx;
    let centre = |i: usize| 0.5 * (layout.passages[i].y[0] + layout.passages[i].y[1]);
    (0..layout.passages.len()).min_by(|&a, &b| (centre(a) - y_hit).abs().total_cmp(&(centre(b) - y_hit).abs()))
}

pub fn fork_choices(
    policy: &mut MarsPolicy,
    demos: &[Demo],
    layout: &Layout,
    draws: usize,
    seed: u64,
) -> anyhow::Result<ForkChoices> {
    use mars_tasks::rollout::{ChunkPolicy, PolicyShape};
    let gate = layout.named_rect("entry_gate").ok_or_else(|| anyhow::anyhow!("layout has no `entry_gate` region"))?;
    let n = layout.n_passages();
    let (h, c) = (policy.history_len(), policy.chunk_len());
    let (mut mine, mut theirs, mut recorded) = (vec![0usize; n], vec![0usize; n], vec![0usize; n]);
    let (mut unclassified, mut states) = (0usize, 0usize);
    for (i, demo) in demos.iter().enumerate() {
        let Some(t) = demo.observations.iter().position(|o| o[0] >= gate.x[1]) else { continue };
        states += 1;
        let from = [demo.observations[t][0], demo.observations[t][1]];
        let mut hist = Vec::new();
        crate::dataset::history_window(&demo.actions, &demo.rest_action, t, h, &mut hist);
        let mut own = Vec::new();
        crate::dataset::future_window(&demo.actions, t, c, &mut own);
        let last = |chunk: &[f32]| [chunk[chunk.len() - 2], chunk[chunk.len() - 1]];
        if let Some(k) = heading_passage(layout, from, last(&own)) {
            theirs[k] += 1;
        }
        if let Some(m) = demo.mode.filter(|&m| m < n) {
            recorded[m] += 1;
        }
        policy.reseed(seed.wrapping_add(i as u64));
        for _ in 0..draws {
            let p = policy.predict(&demo.observations[t], &hist)?;
            match heading_passage(layout, from, last(&p.chunk)) {
                Some(k) => mine[k] += 1,
                None => unclassified += 1,
            }
        }
    }
    let shares = |v: &[usize]| crate::stats::proportions(v);
    Ok(ForkChoices {
        states,
        draws,
        policy: shares(&mine),
        unclassified: unclassified as f32 / (states * draws).max(1) as f32,
        demos_classified: shares(&theirs),
        demos_recorded: shares(&recorded),
    })
}

/// A markdown table of the diagnosis (dimensions shown as x / y).
pub fn table(stats: &[RegionStats]) -> String {
    let vec = |v: &[f32]| v.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>().join(" / ");
    let mut s = String::from(
        "| region | samples | ‖w‖∞ | w (x / y) | S_next (x / y) | S_curr (x / y) | ReLU active | neighbours from own demo | from another passage |\n\
         |---|---:|---:|---|---|---|---:|---:|---:|\n",
    );
    for r in stats {
        s += &format!(
            "| {} | {} | {:.2} | {} | {} | {} | {:.0} % | {:.0} % | {:.0} % |\n",
            r.region,
            r.samples,
            r.w_inf,
            vec(&r.w),
            vec(&r.s_next),
            vec(&r.s_curr),
            100.0 * r.relu_active,
            100.0 * r.same_demo,
            100.0 * r.other_passage
        );
    }
    s
}
