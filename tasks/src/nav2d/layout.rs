//! The nav2d world, read from TOML: obstacles, passages (the modes), named regions, the goal and the
//! expert's routes. Geometry queries (segment vs rect) live here because both the simulator and the layout
//! validation need them.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// The default layout's TOML, compiled in so the shipped config and the code default cannot drift apart.
const DEFAULT_FOUR_PASSAGES: &str = include_str!("../../../configs/nav2d.toml");

/// A closed axis-aligned rectangle: `x = [min, max]`, `y = [min, max]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rect {
    pub x: [f32; 2],
    pub y: [f32; 2],
}

impl Rect {
    pub fn new(x: [f32; 2], y: [f32; 2]) -> Self {
        Self { x, y }
    }

    pub fn contains(&self, p: [f32; 2]) -> bool {
        self.x[0] <= p[0] && p[0] <= self.x[1] && self.y[0] <= p[1] && p[1] <= self.y[1]
    }

    pub fn center(&self) -> [f32; 2] {
        [(self.x[0] + self.x[1]) / 2.0, (self.y[0] + self.y[1]) / 2.0]
    }

    /// True when the two rects share positive area (touching edges do not count).
    pub fn overlaps(&self, other: &Rect) -> bool {
        self.x[0] < other.x[1] && other.x[0] < self.x[1] && self.y[0] < other.y[1] && other.y[0] < self.y[1]
    }

    /// True when `other` lies entirely inside `self`.
    pub fn encloses(&self, other: &Rect) -> bool {
        self.x[0] <= other.x[0] && other.x[1] <= self.x[1] && self.y[0] <= other.y[0] && other.y[1] <= self.y[1]
    }

    /// The part of segment `a → b` inside the rect, as parameters `(t_in, t_out)` in `[0, 1]`
    /// (Liang–Barsky). Touching the boundary counts as inside, so grazing a wall is a collision.
    pub fn clip_segment(&self, a: [f32; 2], b: [f32; 2]) -> Option<(f32, f32)> {
        let d = [b[0] - a[0], b[1] - a[1]];
        let (mut t0, mut t1) = (0.0f32, 1.0f32);
        let constraints =
            [(-d[0], a[0] - self.x[0]), (d[0], self.x[1] - a[0]), (-d[1], a[1] - self.y[0]), (d[1], self.y[1] - a[1])];
        for (p, q) in constraints {
            if p == 0.0 {
                // Parallel to this edge: either always on the inner side of it or never.
                if q < 0.0 {
                    return None;
                }
            } else {
                let r = q / p;
                if p < 0.0 {
                    if r > t1 {
                        return None;
                    }
                    t0 = t0.max(r);
                } else {
                    if r < t0 {
                        return None;
                    }
                    t1 = t1.min(r);
                }
            }
        }
        (t0 <= t1).then_some((t0, t1))
    }

    pub fn intersects_segment(&self, a: [f32; 2], b: [f32; 2]) -> bool {
        self.clip_segment(a, b).is_some()
    }

    fn check(&self, field: &str) -> Result<(), LayoutError> {
        let finite = self.x.iter().chain(&self.y).all(|v| v.is_finite());
        if !finite {
            return Err(invalid(field, "has a non-finite coordinate"));
        }
        if self.x[0] >= self.x[1] || self.y[0] >= self.y[1] {
            return Err(invalid(
                field,
                format!("is empty or inverted (x = {:?}, y = {:?}; need min < max)", self.x, self.y),
            ));
        }
        Ok(())
    }
}

/// A rect with a name (obstacles and passages), flattened in TOML as `name`, `x`, `y`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NamedRect {
    pub name: String,
    pub x: [f32; 2],
    pub y: [f32; 2],
}

impl NamedRect {
    pub fn rect(&self) -> Rect {
        Rect::new(self.x, self.y)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AgentSpec {
    pub start: [f32; 2],
    /// Half-width of the uniform start jitter, per axis.
    pub start_jitter: f32,
    /// Largest displacement per env step.
    pub max_speed: f32,
    pub max_steps: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExpertSpec {
    /// How far along the route, beyond the agent's projection, the expert's target lies.
    pub lookahead: f32,
    /// Half-width of the uniform per-demo offset of interior waypoints across the corridor.
    pub lateral_jitter: f32,
    /// Std of the per-step Gaussian noise on the target, per axis.
    pub target_noise: f32,
    /// Draws per demo before generation fails.
    pub max_attempts: usize,
}

/// The expert's nominal path through one passage: waypoints after the start, ending in the goal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Route {
    pub passage: String,
    /// This passage's share of the demos, relative to the other routes' (default 1: balanced demos).
    #[serde(default = "equal_share")]
    pub share: f32,
    pub waypoints: Vec<[f32; 2]>,
}

fn equal_share() -> f32 {
    1.0
}

/// A nav2d world. Fields are public for inspection and for tests that break one on purpose; anything
/// built or changed outside [`Layout::from_toml_str`] should go through [`Layout::validate`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Layout {
    pub name: String,
    pub world: Rect,
    pub goal: Rect,
    pub agent: AgentSpec,
    pub expert: ExpertSpec,
    #[serde(default)]
    pub regions: BTreeMap<String, Rect>,
    pub obstacles: Vec<NamedRect>,
    /// The modes, in mode-index order.
    pub passages: Vec<NamedRect>,
    /// One per passage, in any order (matched by `passage` name).
    pub routes: Vec<Route>,
}

#[derive(Debug, thiserror::Error)]
pub enum LayoutError {
    #[error("cannot parse nav2d layout: {0}")]
    Parse(#[from] toml::de::Error),
    #[error("invalid nav2d layout: `{field}` {problem}")]
    Invalid { field: String, problem: String },
}

fn invalid(field: impl Into<String>, problem: impl Into<String>) -> LayoutError {
    LayoutError::Invalid { field: field.into(), problem: problem.into() }
}

impl Layout {
    /// The shipped four-passage benchmark (`configs/nav2d.toml`).
    pub fn default_four_passages() -> Self {
        // The compiled-in file is checked by a unit test, so failing here is a build defect, not user input.
        Self::from_toml_str(DEFAULT_FOUR_PASSAGES).expect("configs/nav2d.toml is a valid layout")
    }

    pub fn from_toml_str(text: &str) -> Result<Self, LayoutError> {
        let layout: Layout = toml::from_str(text)?;
        layout.validate()?;
        Ok(layout)
    }

    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("reading layout {}", path.display()))?;
        Self::from_toml_str(&text).with_context(|| format!("loading layout {}", path.display()))
    }

    pub fn n_passages(&self) -> usize {
        self.passages.len()
    }

    /// A named region: an entry of `[regions]`, a passage by name, or `"goal"`.
    pub fn region(&self, name: &str) -> Option<&Rect> {
        if name == "goal" {
            return Some(&self.goal);
        }
        self.regions.get(name)
    }

    /// A passage's rect by name (passages are regions too, but stored with their mode order).
    pub fn passage(&self, name: &str) -> Option<(usize, Rect)> {
        self.passages.iter().enumerate().find(|(_, p)| p.name == name).map(|(i, p)| (i, p.rect()))
    }

    /// Any named rect: `[regions]`, passages, or `"goal"`.
    pub fn named_rect(&self, name: &str) -> Option<Rect> {
        self.region(name).copied().or_else(|| self.passage(name).map(|(_, r)| r))
    }

    /// The waypoints (after the start) of the route through passage `index`.
    pub fn route(&self, index: usize) -> Option<&[[f32; 2]]> {
        let name = &self.passages.get(index)?.name;
        self.routes.iter().find(|r| &r.passage == name).map(|r| r.waypoints.as_slice())
    }

    /// Each passage's share of the demos, in mode order, summing to 1.
    pub fn demo_shares(&self) -> Vec<f32> {
        let raw: Vec<f32> = (0..self.n_passages())
            .map(|i| self.routes.iter().find(|r| r.passage == self.passages[i].name).map_or(0.0, |r| r.share))
            .collect();
        let total: f32 = raw.iter().sum();
        raw.iter().map(|s| s / total).collect()
    }

    /// A start position: the nominal start with uniform per-axis jitter.
    pub fn sample_start<R: Rng + ?Sized>(&self, rng: &mut R) -> [f32; 2] {
        let j = self.agent.start_jitter;
        let s = self.agent.start;
        [s[0] + rng.random_range(-j..=j), s[1] + rng.random_range(-j..=j)]
    }

    /// Where along `a → b` (parameter in `[0, 1]`) the motion first becomes illegal: entering an obstacle
    /// or leaving the world. `None` when the whole segment is free.
    pub fn first_collision(&self, a: [f32; 2], b: [f32; 2]) -> Option<f32> {
        let obstacle_hit = self
            .obstacles
            .iter()
            .filter_map(|o| o.rect().clip_segment(a, b).map(|(t_in, _)| t_in))
            .fold(None, |best: Option<f32>, t| Some(best.map_or(t, |b| b.min(t))));
        // The world is convex, so the segment is inside it up to where its clip ends.
        let world_exit = match self.world.clip_segment(a, b) {
            None => Some(0.0),
            Some((t_in, _)) if t_in > 0.0 => Some(0.0),
            Some((_, t_out)) if t_out < 1.0 => Some(t_out),
            Some(_) => None,
        };
        match (obstacle_hit, world_exit) {
            (Some(x), Some(y)) => Some(x.min(y)),
            (x, y) => x.or(y),
        }
    }

    pub fn segment_is_free(&self, a: [f32; 2], b: [f32; 2]) -> bool {
        self.first_collision(a, b).is_none()
    }

    /// The first passage (mode index) the segment touches, if any.
    pub fn passage_on_segment(&self, a: [f32; 2], b: [f32; 2]) -> Option<usize> {
        self.passages.iter().position(|p| p.rect().intersects_segment(a, b))
    }

    /// Checks everything the simulator and expert rely on; errors name the offending field.
    pub fn validate(&self) -> Result<(), LayoutError> {
        self.world.check("world")?;
        self.goal.check("goal")?;
        let inside_world = |field: &str, r: &Rect| {
            if self.world.encloses(r) { Ok(()) } else { Err(invalid(field, "extends outside `world`")) }
        };
        inside_world("goal", &self.goal)?;
        for (name, r) in &self.regions {
            let field = format!("regions.{name}");
            r.check(&field)?;
            inside_world(&field, r)?;
        }
        for (i, o) in self.obstacles.iter().enumerate() {
            let field = format!("obstacles[{i}] ({})", o.name);
            o.rect().check(&field)?;
            inside_world(&field, &o.rect())?;
            if o.rect().overlaps(&self.goal) {
                return Err(invalid("goal", format!("overlaps obstacle `{}`", o.name)));
            }
        }
        self.validate_names()?;
        self.validate_agent()?;
        self.validate_expert()?;
        for (i, p) in self.passages.iter().enumerate() {
            let field = format!("passages[{i}] ({})", p.name);
            p.rect().check(&field)?;
            inside_world(&field, &p.rect())?;
            if let Some(o) = self.obstacles.iter().find(|o| o.rect().overlaps(&p.rect())) {
                return Err(invalid(field, format!("overlaps obstacle `{}`", o.name)));
            }
        }
        self.validate_routes()
    }

    fn validate_names(&self) -> Result<(), LayoutError> {
        if self.passages.is_empty() {
            return Err(invalid("passages", "is empty (need at least one mode)"));
        }
        let mut seen = std::collections::BTreeSet::new();
        let names =
            self.passages.iter().map(|p| ("passages", &p.name)).chain(self.regions.keys().map(|n| ("regions", n)));
        for (field, name) in names {
            if name == "goal" || !seen.insert(name.as_str()) {
                return Err(invalid(field, format!("reuses the region name `{name}`")));
            }
        }
        Ok(())
    }

    fn validate_agent(&self) -> Result<(), LayoutError> {
        let a = &self.agent;
        if !(a.max_speed.is_finite() && a.max_speed > 0.0) {
            return Err(invalid("agent.max_speed", format!("must be positive, got {}", a.max_speed)));
        }
        if a.max_steps == 0 {
            return Err(invalid("agent.max_steps", "must be positive"));
        }
        if !(a.start_jitter.is_finite() && a.start_jitter >= 0.0) {
            return Err(invalid("agent.start_jitter", format!("must be >= 0, got {}", a.start_jitter)));
        }
        if !a.start.iter().all(|v| v.is_finite()) {
            return Err(invalid("agent.start", "has a non-finite coordinate"));
        }
        // Every jittered start must be a legal position, so check the whole jitter box.
        let j = a.start_jitter;
        let start_box = Rect::new([a.start[0] - j, a.start[0] + j], [a.start[1] - j, a.start[1] + j]);
        if !self.world.encloses(&start_box) {
            return Err(invalid("agent.start", "(with start_jitter) is not inside `world`"));
        }
        if let Some(o) = self.obstacles.iter().find(|o| o.rect().overlaps(&start_box) || o.rect().contains(a.start)) {
            return Err(invalid("agent.start", format!("(with start_jitter) is inside obstacle `{}`", o.name)));
        }
        if self.goal.overlaps(&start_box) || self.goal.contains(a.start) {
            return Err(invalid("agent.start", "(with start_jitter) is inside `goal`"));
        }
        Ok(())
    }

    fn validate_expert(&self) -> Result<(), LayoutError> {
        let e = &self.expert;
        let checks = [
            ("expert.lookahead", e.lookahead, e.lookahead > 0.0),
            ("expert.lateral_jitter", e.lateral_jitter, e.lateral_jitter >= 0.0),
            ("expert.target_noise", e.target_noise, e.target_noise >= 0.0),
        ];
        for (field, v, ok) in checks {
            if !(v.is_finite() && ok) {
                return Err(invalid(field, format!("is out of range: {v}")));
            }
        }
        if e.max_attempts == 0 {
            return Err(invalid("expert.max_attempts", "must be positive"));
        }
        Ok(())
    }

    fn validate_routes(&self) -> Result<(), LayoutError> {
        if self.routes.len() != self.passages.len() {
            return Err(invalid(
                "routes",
                format!(
                    "has {} routes but there are {} passages (need one each)",
                    self.routes.len(),
                    self.passages.len()
                ),
            ));
        }
        for (i, route) in self.routes.iter().enumerate() {
            let field = format!("routes[{i}]");
            let Some((mode, _)) = self.passage(&route.passage) else {
                return Err(invalid(format!("{field}.passage"), format!("names unknown passage `{}`", route.passage)));
            };
            if self.routes[..i].iter().any(|r| r.passage == route.passage) {
                return Err(invalid(format!("{field}.passage"), format!("passage `{}` has two routes", route.passage)));
            }
            if !(route.share.is_finite() && route.share > 0.0) {
                return Err(invalid(format!("{field}.share"), format!("must be positive, got {}", route.share)));
            }
            let Some(last) = route.waypoints.last() else {
                return Err(invalid(format!("{field}.waypoints"), "is empty"));
            };
            if !self.goal.contains(*last) {
                return Err(invalid(format!("{field}.waypoints"), "must end inside `goal`"));
            }
            let mut prev = self.agent.start;
            for (j, &w) in route.waypoints.iter().enumerate() {
                if !w.iter().all(|v| v.is_finite()) {
                    return Err(invalid(format!("{field}.waypoints[{j}]"), "has a non-finite coordinate"));
                }
                if !self.segment_is_free(prev, w) {
                    return Err(invalid(
                        format!("{field}.waypoints[{j}]"),
                        format!("segment {prev:?} -> {w:?} crosses an obstacle or leaves the world"),
                    ));
                }
                prev = w;
            }
            // The mode label is the first passage touched, so the route must reach its own passage first.
            let first = std::iter::once(self.agent.start)
                .chain(route.waypoints.iter().copied())
                .collect::<Vec<_>>()
                .windows(2)
                .find_map(|s| self.passage_on_segment(s[0], s[1]));
            if first != Some(mode) {
                return Err(invalid(
                    format!("{field}.waypoints"),
                    format!("must pass through passage `{}` before any other passage", passage_name(self, mode)),
                ));
            }
        }
        Ok(())
    }
}

fn passage_name(layout: &Layout, mode: usize) -> &str {
    layout.passages.get(mode).map_or("?", |p| p.name.as_str())
}

impl crate::Task for Layout {
    fn name(&self) -> &str {
        &self.name
    }

    /// The agent's position.
    fn obs_dim(&self) -> usize {
        2
    }

    /// The next target position.
    fn action_dim(&self) -> usize {
        2
    }

    /// The passages, in mode order.
    fn mode_names(&self) -> Vec<String> {
        self.passages.iter().map(|p| p.name.clone()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err_text(layout: &Layout) -> String {
        layout.validate().expect_err("layout should be invalid").to_string()
    }

    #[test]
    fn default_layout_parses_and_has_named_regions() {
        let l = Layout::default_four_passages();
        assert_eq!(l.n_passages(), 4);
        for name in ["entry_gate", "junction", "exit_gate", "merge", "goal"] {
            assert!(l.region(name).is_some(), "{name}");
        }
        assert!(l.region("exit_gate").is_some_and(|r| r.contains([9.75, 4.0])));
        assert_eq!(l.passage("passage_2").map(|(i, _)| i), Some(2));
        assert!(l.named_rect("passage_3").is_some_and(|r| r.contains([6.0, 7.0])));
        for i in 0..4 {
            assert!(l.route(i).is_some());
        }
    }

    #[test]
    fn clip_segment_handles_crossing_grazing_and_missing() {
        let r = Rect::new([1.0, 2.0], [1.0, 2.0]);
        assert_eq!(r.clip_segment([0.0, 1.5], [3.0, 1.5]), Some((1.0 / 3.0, 2.0 / 3.0)));
        assert!(r.intersects_segment([0.0, 2.0], [3.0, 2.0]), "grazing the top edge counts");
        assert!(!r.intersects_segment([0.0, 2.1], [3.0, 2.1]));
        assert!(!r.intersects_segment([0.0, 0.0], [0.9, 0.9]), "stops short");
        assert!(r.intersects_segment([1.5, 1.5], [1.5, 1.5]), "a point inside");
    }

    #[test]
    fn validation_names_the_bad_field() {
        let base = Layout::default_four_passages();

        let mut l = base.clone();
        l.obstacles[0].y = [3.0, 1.0];
        assert!(err_text(&l).contains("obstacles[0] (entry_wall_low)"), "{}", err_text(&l));

        let mut l = base.clone();
        l.agent.start = [2.2, 2.0];
        assert!(err_text(&l).contains("agent.start"));

        let mut l = base.clone();
        l.goal = Rect::new([9.0, 10.5], [3.0, 4.0]);
        assert!(err_text(&l).contains("`goal` overlaps obstacle"), "{}", err_text(&l));

        let mut l = base.clone();
        l.routes[1].waypoints[2] = [4.2, 4.0];
        assert!(err_text(&l).contains("routes[1]"), "{}", err_text(&l));

        let mut l = base.clone();
        l.routes.pop();
        assert!(err_text(&l).contains("`routes` has 3 routes but there are 4 passages"));

        let mut l = base.clone();
        l.agent.max_speed = 0.0;
        assert!(err_text(&l).contains("agent.max_speed"));

        let mut l = base.clone();
        l.routes[0].passage = "passage_9".into();
        assert!(err_text(&l).contains("routes[0].passage"));

        let mut l = base.clone();
        l.routes[0].passage = "passage_1".into();
        assert!(err_text(&l).contains("two routes") || err_text(&l).contains("before any other"));

        let mut l = base;
        l.regions.insert("bad".into(), Rect::new([1.0, 1.0], [0.0, 1.0]));
        assert!(err_text(&l).contains("regions.bad"));
    }

    #[test]
    fn unknown_fields_are_rejected() {
        let text = DEFAULT_FOUR_PASSAGES.replace("max_steps = 120", "max_steps = 120\nmax_stepz = 3");
        let err = Layout::from_toml_str(&text).expect_err("unknown field").to_string();
        assert!(err.contains("max_stepz"), "{err}");
    }
}
