//! The scripted expert: follows a (perturbed) route through a chosen passage with a pure-pursuit target.
//! Demos are spread across the passages in the layout's shares (balanced by default), so the data is genuinely
//! multimodal at the junction.

use anyhow::{Context, bail};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};

use super::env::{Nav2dEnv, StepOutcome};
use super::layout::Layout;
use crate::demo::Demo;

/// A piecewise-linear path parametrised by arc length.
#[derive(Debug, Clone, PartialEq)]
pub struct Polyline {
    points: Vec<[f32; 2]>,
    /// `cum[i]` = arc length from `points[0]` to `points[i]`.
    cum: Vec<f32>,
}

impl Polyline {
    pub fn new(points: Vec<[f32; 2]>) -> anyhow::Result<Self> {
        if points.len() < 2 {
            bail!("a polyline needs at least 2 points, got {}", points.len());
        }
        if !points.iter().flatten().all(|v| v.is_finite()) {
            bail!("polyline has a non-finite point");
        }
        let mut cum = vec![0.0f32];
        for w in points.windows(2) {
            let last = cum[cum.len() - 1];
            cum.push(last + dist(w[0], w[1]));
        }
        Ok(Self { points, cum })
    }

    pub fn points(&self) -> &[[f32; 2]] {
        &self.points
    }

    pub fn length(&self) -> f32 {
        self.cum[self.cum.len() - 1]
    }

    /// The point at arc length `s`, clamped to the ends.
    pub fn point_at(&self, s: f32) -> [f32; 2] {
        let s = s.clamp(0.0, self.length());
        let i = self.cum.partition_point(|&c| c <= s).clamp(1, self.points.len() - 1);
        let (a, b) = (self.points[i - 1], self.points[i]);
        let seg = self.cum[i] - self.cum[i - 1];
        let t = if seg > 0.0 { (s - self.cum[i - 1]) / seg } else { 0.0 };
        [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]
    }

    /// Arc length of the point of the path nearest to `p`, among points at arc length ≥ `from`.
    /// Passing the previous projection as `from` keeps progress monotone, so the follower never turns back.
    pub fn project(&self, p: [f32; 2], from: f32) -> f32 {
        let mut best = (f32::INFINITY, from.clamp(0.0, self.length()));
        for (i, w) in self.points.windows(2).enumerate() {
            let (s0, s1) = (self.cum[i], self.cum[i + 1]);
            if s1 < from || s1 <= s0 {
                continue;
            }
            let (a, b) = (w[0], w[1]);
            let d = [b[0] - a[0], b[1] - a[1]];
            let t = ((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1]) / (d[0] * d[0] + d[1] * d[1]);
            let s = (s0 + t.clamp(0.0, 1.0) * (s1 - s0)).max(from);
            let q = self.point_at(s);
            let e = dist(p, q);
            if e < best.0 {
                best = (e, s);
            }
        }
        best.1
    }
}

fn dist(a: [f32; 2], b: [f32; 2]) -> f32 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The route through `passage` from `start`, with each interior waypoint shifted across the corridor by
/// U(±lateral_jitter). The corridors are horizontal at gates and passages, so the shift is in y. The last
/// waypoint (the goal centre) is kept so every demo ends the same way.
pub fn perturbed_route<R: Rng + ?Sized>(
    layout: &Layout,
    passage: usize,
    start: [f32; 2],
    rng: &mut R,
) -> anyhow::Result<Polyline> {
    let waypoints = layout.route(passage).with_context(|| format!("no route for passage index {passage}"))?;
    let j = layout.expert.lateral_jitter;
    let n = waypoints.len();
    let mut points = Vec::with_capacity(n + 1);
    points.push(start);
    for (i, w) in waypoints.iter().enumerate() {
        let dy = if i + 1 < n && j > 0.0 { rng.random_range(-j..=j) } else { 0.0 };
        points.push([w[0], w[1] + dy]);
    }
    Polyline::new(points)
}

/// Drives `route` through the simulator with pure pursuit plus target noise; returns the demo (its `mode` is
/// the passage actually entered) and how the episode ended.
pub fn follow_route<R: Rng + ?Sized>(
    layout: &Layout,
    route: &Polyline,
    rng: &mut R,
) -> anyhow::Result<(Demo, StepOutcome)> {
    let noise = Normal::new(0.0f32, layout.expert.target_noise).context("expert.target_noise")?;
    let start = route.points()[0];
    let mut env = Nav2dEnv::new(layout);
    env.reset(start);
    let (mut observations, mut actions) = (Vec::new(), Vec::new());
    let mut s = 0.0;
    let mut outcome = StepOutcome::Running;
    while !outcome.is_terminal() {
        let p = env.position();
        s = route.project(p, s);
        let aim = route.point_at(s + layout.expert.lookahead);
        let target = [aim[0] + noise.sample(rng), aim[1] + noise.sample(rng)];
        observations.push(p.to_vec());
        actions.push(target.to_vec());
        outcome = env.step(target);
    }
    let demo = Demo { observations, actions, rest_action: start.to_vec(), mode: env.mode() };
    Ok((demo, outcome))
}

/// The passage of each of `n` demos: smooth weighted round-robin over the shares, so every prefix of the
/// sequence is as close to the shares as whole demos allow (equal shares give 0, 1, …, k−1, 0, 1, …).
pub fn passage_schedule(shares: &[f32], n: usize) -> Vec<usize> {
    let total: f32 = shares.iter().sum();
    let mut credit = vec![0.0f32; shares.len()];
    (0..n)
        .map(|_| {
            for (c, s) in credit.iter_mut().zip(shares) {
                *c += s;
            }
            // The first of the largest credits: ties go to the lower passage index.
            let pick = (0..credit.len()).fold(0, |best, i| if credit[i] > credit[best] { i } else { best });
            credit[pick] -= total;
            pick
        })
        .collect()
}

/// `n` expert demos through the passages in the layout's shares (see [`passage_schedule`]), each verified in
/// the simulator to reach the goal without collision through its intended passage. Deterministic for a given
/// seed.
pub fn generate_demos(layout: &Layout, n: usize, seed: u64) -> anyhow::Result<Vec<Demo>> {
    layout.validate()?;
    let mut rng = StdRng::seed_from_u64(seed);
    let mut demos = Vec::with_capacity(n);
    for (i, passage) in passage_schedule(&layout.demo_shares(), n).into_iter().enumerate() {
        let mut last = None;
        for _ in 0..layout.expert.max_attempts {
            let start = layout.sample_start(&mut rng);
            let route = perturbed_route(layout, passage, start, &mut rng)?;
            let (demo, outcome) = follow_route(layout, &route, &mut rng)?;
            if outcome == StepOutcome::ReachedGoal && demo.mode == Some(passage) {
                demos.push(demo);
                last = None;
                break;
            }
            last = Some((outcome, demo.mode));
        }
        if let Some((outcome, mode)) = last {
            bail!(
                "expert demo {i} through `{}` failed {} times (last: {outcome:?}, entered passage {mode:?}); \
                 the route or expert noise in the layout leaves too little clearance",
                layout.passages[passage].name,
                layout.expert.max_attempts
            );
        }
    }
    Ok(demos)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polyline_point_at_and_project() {
        let p = Polyline::new(vec![[0.0, 0.0], [2.0, 0.0], [2.0, 1.0]]).expect("polyline");
        assert_eq!(p.length(), 3.0);
        assert_eq!(p.point_at(2.5), [2.0, 0.5]);
        assert_eq!(p.point_at(9.0), [2.0, 1.0]);
        assert!((p.project([1.0, 0.3], 0.0) - 1.0).abs() < 1e-6);
        assert!((p.project([1.0, 0.3], 1.5) - 1.5).abs() < 1e-6, "never projects behind `from`");
        assert!(Polyline::new(vec![[0.0, 0.0]]).is_err());
    }

    #[test]
    fn demos_are_balanced_successful_and_deterministic() {
        let layout = Layout::default_four_passages();
        let demos = generate_demos(&layout, 200, 7).expect("demos");
        assert_eq!(demos.len(), 200);
        let mut counts = [0usize; 4];
        for d in &demos {
            counts[d.mode.expect("mode")] += 1;
            assert_eq!(d.observations.len(), d.actions.len());
            assert_eq!(d.rest_action, d.observations[0]);
            assert!(d.len() < layout.agent.max_steps);
            // Replay the recorded actions: the demo must reach the goal without collision.
            let mut env = Nav2dEnv::new(&layout);
            env.reset([d.rest_action[0], d.rest_action[1]]);
            let mut outcome = StepOutcome::Running;
            for (o, a) in d.observations.iter().zip(&d.actions) {
                assert_eq!(o.as_slice(), env.position().as_slice());
                outcome = env.step([a[0], a[1]]);
            }
            assert_eq!(outcome, StepOutcome::ReachedGoal);
            assert_eq!(env.mode(), d.mode);
        }
        assert_eq!(counts, [50; 4]);
        assert_eq!(generate_demos(&layout, 200, 7).expect("demos"), demos);
        assert_ne!(generate_demos(&layout, 200, 8).expect("demos"), demos);
    }

    #[test]
    fn schedule_follows_the_shares_in_every_prefix() {
        assert_eq!(passage_schedule(&[1.0; 4], 9), vec![0, 1, 2, 3, 0, 1, 2, 3, 0]);
        let shares = [0.25, 0.45, 0.30];
        let plan = passage_schedule(&shares, 200);
        for n in [20, 100, 200] {
            for (p, s) in shares.iter().enumerate() {
                let got = plan[..n].iter().filter(|&&q| q == p).count() as f32;
                assert!((got - s * n as f32).abs() <= 1.0, "prefix {n}, passage {p}: {got} demos for share {s}");
            }
        }
    }

    #[test]
    fn the_family_layouts_give_demos_in_their_shares() {
        for name in ["three_passages", "four_passages", "five_passages"] {
            let path = format!("{}/../configs/nav2d_family/{name}.toml", env!("CARGO_MANIFEST_DIR"));
            let layout = Layout::load(std::path::Path::new(&path)).expect("family layout");
            let demos = generate_demos(&layout, 40, 3).expect("demos");
            for (p, s) in layout.demo_shares().iter().enumerate() {
                let got = demos.iter().filter(|d| d.mode == Some(p)).count() as f32;
                assert!((got - s * 40.0).abs() <= 1.0, "{name}: passage {p} has {got} of 40 demos, share {s}");
            }
        }
    }

    #[test]
    fn impossible_expert_fails_with_an_error() {
        let mut layout = Layout::default_four_passages();
        layout.expert.target_noise = 2.0;
        layout.expert.max_attempts = 3;
        let err = generate_demos(&layout, 4, 0).expect_err("too noisy").to_string();
        assert!(err.contains("failed 3 times"), "{err}");
    }
}
