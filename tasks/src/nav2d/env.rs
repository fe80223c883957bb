//! The nav2d simulator: a point that moves toward a commanded target at bounded speed.

use super::layout::Layout;

/// What one step did. Everything but `Running` ends the episode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StepOutcome {
    Running,
    ReachedGoal,
    /// The motion segment touched an obstacle or left the world.
    Collided,
    TimedOut,
    /// The target was NaN/inf: a failure of the policy, not of the motion, so it is not a collision.
    InvalidTarget,
}

impl StepOutcome {
    pub fn is_terminal(self) -> bool {
        self != StepOutcome::Running
    }
}

/// `v` scaled down so its length is at most `max`.
pub fn clip_norm(v: [f32; 2], max: f32) -> [f32; 2] {
    let n = v[0].hypot(v[1]);
    if n <= max { v } else { [v[0] * max / n, v[1] * max / n] }
}

/// One episode's state over a borrowed layout.
#[derive(Debug, Clone)]
pub struct Nav2dEnv<'a> {
    layout: &'a Layout,
    pos: [f32; 2],
    steps: usize,
    mode: Option<usize>,
    status: StepOutcome,
}

impl<'a> Nav2dEnv<'a> {
    /// An env at the layout's nominal (unjittered) start.
    pub fn new(layout: &'a Layout) -> Self {
        Self { layout, pos: layout.agent.start, steps: 0, mode: None, status: StepOutcome::Running }
    }

    /// Starts a new episode at `start`. A start inside an obstacle is not rejected here: the first step then
    /// reports a collision, which is what a policy evaluated from there would experience.
    pub fn reset(&mut self, start: [f32; 2]) {
        self.pos = start;
        self.steps = 0;
        self.mode = None;
        self.status = StepOutcome::Running;
    }

    /// Moves toward `target` by at most `max_speed`. After a terminal outcome further steps do nothing and
    /// repeat it.
    pub fn step(&mut self, target: [f32; 2]) -> StepOutcome {
        if self.status.is_terminal() {
            return self.status;
        }
        if !target.iter().all(|v| v.is_finite()) {
            self.status = StepOutcome::InvalidTarget;
            return self.status;
        }
        self.steps += 1;
        let old = self.pos;
        let d = clip_norm([target[0] - old[0], target[1] - old[1]], self.layout.agent.max_speed);
        let new = [old[0] + d[0], old[1] + d[1]];
        // Segment test, not endpoint test: a step must not tunnel through a thin wall or clip a corner.
        if let Some(t) = self.layout.first_collision(old, new) {
            // Stop at the contact point so plots show where the agent hit.
            self.pos = [old[0] + t * d[0], old[1] + t * d[1]];
            self.note_mode(old, self.pos);
            self.status = StepOutcome::Collided;
            return self.status;
        }
        self.pos = new;
        self.note_mode(old, new);
        self.status = if self.layout.goal.contains(new) {
            StepOutcome::ReachedGoal
        } else if self.steps >= self.layout.agent.max_steps {
            StepOutcome::TimedOut
        } else {
            StepOutcome::Running
        };
        self.status
    }

    fn note_mode(&mut self, a: [f32; 2], b: [f32; 2]) {
        if self.mode.is_none() {
            self.mode = self.layout.passage_on_segment(a, b);
        }
    }

    pub fn position(&self) -> [f32; 2] {
        self.pos
    }

    pub fn steps(&self) -> usize {
        self.steps
    }

    /// The passage (mode index) the agent entered first, once it has entered one.
    pub fn mode(&self) -> Option<usize> {
        self.mode
    }

    pub fn status(&self) -> StepOutcome {
        self.status
    }

    pub fn layout(&self) -> &'a Layout {
        self.layout
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout() -> Layout {
        Layout::default_four_passages()
    }

    #[test]
    fn cutting_a_wall_corner_collides_even_with_free_endpoints() {
        let l = layout();
        let (a, b) = ([1.95, 3.40], [2.15, 3.55]);
        assert!(l.obstacles.iter().all(|o| !o.rect().contains(a) && !o.rect().contains(b)));
        let mut env = Nav2dEnv::new(&l);
        env.reset(a);
        assert_eq!(env.step(b), StepOutcome::Collided);
        // The agent stops where it touched the wall (x = 2.0), not past it.
        assert!((env.position()[0] - 2.0).abs() < 1e-4, "{:?}", env.position());
        assert_eq!(env.step([2.3, 4.0]), StepOutcome::Collided, "terminal outcomes stick");
    }

    #[test]
    fn moving_through_the_gate_gap_is_free() {
        let l = layout();
        let mut env = Nav2dEnv::new(&l);
        env.reset([1.9, 4.0]);
        for _ in 0..4 {
            let p = env.position();
            assert_eq!(env.step([p[0] + 0.25, 4.0]), StepOutcome::Running);
        }
        assert!(env.position()[0] > 2.5);
        assert_eq!(env.steps(), 4);
    }

    #[test]
    fn speed_is_clipped_and_leaving_the_world_collides() {
        let l = layout();
        let mut env = Nav2dEnv::new(&l);
        env.reset([1.0, 4.0]);
        env.step([1.0, 10.0]);
        assert!((env.position()[1] - 4.25).abs() < 1e-6);
        env.reset([0.1, 4.0]);
        assert_eq!(env.step([-1.0, 4.0]), StepOutcome::Collided);
        assert!(env.position()[0].abs() < 1e-6, "stops at the world edge");
    }

    #[test]
    fn reaching_the_goal_succeeds_and_records_the_mode() {
        let l = layout();
        let mut env = Nav2dEnv::new(&l);
        env.reset([3.0, 4.0]);
        let route = [[4.2, 7.0], [7.8, 7.0], [9.3, 4.0], [10.2, 4.0], [11.5, 4.0]];
        let mut outcome = StepOutcome::Running;
        for w in route {
            while outcome == StepOutcome::Running {
                let p = env.position();
                if (p[0] - w[0]).hypot(p[1] - w[1]) < 1e-3 {
                    break;
                }
                outcome = env.step(w);
            }
        }
        assert_eq!(outcome, StepOutcome::ReachedGoal);
        assert!(l.goal.contains(env.position()));
        assert_eq!(env.mode(), Some(3));
    }

    #[test]
    fn times_out_after_max_steps() {
        let l = layout();
        let mut env = Nav2dEnv::new(&l);
        env.reset([1.0, 4.0]);
        for i in 1..l.agent.max_steps {
            assert_eq!(env.step([1.0, 4.0]), StepOutcome::Running, "step {i}");
        }
        assert_eq!(env.step([1.0, 4.0]), StepOutcome::TimedOut);
        assert_eq!(env.mode(), None);
    }

    #[test]
    fn nan_target_fails_cleanly() {
        let l = layout();
        let mut env = Nav2dEnv::new(&l);
        env.reset([1.0, 4.0]);
        assert_eq!(env.step([f32::NAN, 4.0]), StepOutcome::InvalidTarget);
        assert_eq!(env.position(), [1.0, 4.0]);
        assert_eq!(env.step([f32::INFINITY, 0.0]), StepOutcome::InvalidTarget);
    }
}
