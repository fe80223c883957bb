//! franka-sim 1.1.7's handling of joint position commands, restated for the tests of the HAL's model of it
//! (`setpoint_sync`) and the filter's steps: what it records, what it judges each command against, what each state
//! shows. From its source (`server/state_stream.py`, `server/motion_session.py`, `limits/checker.py`,
//! `limits/differencing.py`, `comm_constraints.py`):
//! - The receive thread reads **every** command datagram, one per poll turn, in the order sent.
//! - A command is *fresh* when it echoes the id of the newest state published (`command_received`); it is judged
//!   against the history as it stands over the ids since the last command recorded, recorded, and dispatched.
//! - Before each state goes out the publish thread closes the cycle (`comm.tick`); a cycle with no fresh command is
//!   lost, and franka-sim guesses it (`extrapolate`: `v += a·dt; q += v·dt`, the acceleration frozen), records the
//!   guess and dispatches it, so the state shows it in `q_d`, `dq_d`, `ddq_d`. The first guess of a run snapshots
//!   the history before it.
//! - A late command (not fresh) answering a guessed cycle of the open run rewinds the history to the snapshot, is
//!   judged over the ids since the last command recorded, recorded, and the snapshot moves onto it; the run stays
//!   open while guessed cycles after it remain. So however late our commands come, in order, the history they are
//!   judged against is ours; only the states in between show guesses.
//! - A late command read after the publish thread closed its cycle and before it guessed it (the two threads race
//!   there) is outside every run: judged, dispatched, **not** recorded; the guess that follows stands.
//! - A state shows the last command dispatched and the history's derivatives at that moment, in float32.

use super::JOINTS;
use super::history::History;

/// franka-sim's limits (`limits/tables.py`: `MAX_JOINT_ACCELERATION`, `MAX_JOINT_JERK`), compared strictly.
pub const MAX_ACCELERATION: f64 = 10.0;
pub const MAX_JERK: f64 = 5000.0;

/// The FR3's velocity limits by position (`limits/tables.py`: `POSITION_BASED_VELOCITY_LIMITS` as (max, offset,
/// deceleration), `JOINT_POSITION_LIMITS`, less `LIMIT_EPS`).
const VELOCITY_BY_POSITION: [(f64, f64, f64); JOINTS] = [
    (2.62, 0.30, 6.0),
    (2.62, 0.20, 2.585),
    (2.62, 0.20, 3.5),
    (2.62, 0.30, 4.0),
    (5.26, 0.35, 17.0),
    (4.18, 0.35, 5.5),
    (5.26, 0.35, 17.0),
];
const POSITION_LIMITS: [(f64, f64); JOINTS] = [
    (-2.7501, 2.7501),
    (-1.7918, 1.7918),
    (-2.9065, 2.9065),
    (-3.0481, -0.1458),
    (-2.8101, 2.8101),
    (0.54092, 4.5205),
    (-3.0196, 3.0196),
];
const LIMIT_EPS: f64 = 1e-3;

/// Joint `j`'s velocity range at `q` (`upper_joint_velocity_limits`, `lower_joint_velocity_limits`).
fn velocity_range(j: usize, q: f64) -> (f64, f64) {
    let ((max, offset, deceleration), (lower, upper)) = (VELOCITY_BY_POSITION[j], POSITION_LIMITS[j]);
    let up = (max.min((-offset + (2.0 * deceleration * (upper - q)).max(0.0).sqrt()).max(0.0)) - LIMIT_EPS).max(0.0);
    let down =
        ((-max).max((offset - (2.0 * deceleration * (q - lower)).max(0.0).sqrt()).min(0.0)) + LIMIT_EPS).min(0.0);
    (down, up)
}

/// The open run of guessed cycles: the history before its first guess (or after the last late command of it
/// recorded), that history's id, and the ids of the guessed cycles still unanswered.
#[derive(Debug, Clone, Copy)]
struct Run {
    snapshot: History,
    snapshot_id: u64,
    first: u64,
    last: u64,
}

/// What franka-sim judged one command to be, the worst joint: its velocity (and the range allowed there),
/// acceleration and jerk.
#[derive(Debug, Clone, Copy)]
pub struct Judged {
    pub id: u64,
    pub joint: usize,
    pub velocity: f64,
    pub velocity_range: (f64, f64),
    pub acceleration: f64,
    pub jerk: f64,
}

impl Judged {
    pub fn within_limits(&self) -> bool {
        let (down, up) = self.velocity_range;
        self.acceleration.abs() <= MAX_ACCELERATION
            && self.jerk.abs() <= MAX_JERK
            && (down..=up).contains(&self.velocity)
    }

    /// How far out of its limits, as a fraction of them (above 1: out).
    fn score(&self) -> f64 {
        let (down, up) = self.velocity_range;
        let velocity = if self.velocity >= 0.0 { self.velocity / up } else { self.velocity / down };
        (self.acceleration / MAX_ACCELERATION).abs().max((self.jerk / MAX_JERK).abs()).max(velocity)
    }
}

/// One state as the HAL reads it: `q_d`, `dq_d`, `ddq_d` in float32, and the success rate.
#[derive(Debug, Clone, Copy)]
pub struct Shown {
    pub q: [f64; JOINTS],
    pub v: [f64; JOINTS],
    pub a: [f64; JOINTS],
    pub success_rate: f64,
}

#[derive(Debug)]
pub struct SimChecker {
    history: History,
    applied_id: u64,
    published_id: u64,
    run: Option<Run>,
    received_in_cycle: bool,
    /// The last 100 cycles, answered or not.
    window: std::collections::VecDeque<bool>,
    /// The last dispatched command and the derivatives published with it.
    shown: History,
    pub judged: Vec<Judged>,
}

impl SimChecker {
    /// A motion under way: `start` recorded for the state `id`, which was just published.
    pub fn new(start: History, id: u64) -> Self {
        Self {
            history: start,
            applied_id: id,
            published_id: id,
            run: None,
            received_in_cycle: false,
            window: std::collections::VecDeque::new(),
            shown: start,
            judged: Vec::new(),
        }
    }

    /// `comm.tick` and `note_published`: closes the cycle of the last state and opens the next one's. Returns
    /// whether the closed one was lost (its guess comes with [`Self::guess`]).
    pub fn close_cycle(&mut self) -> bool {
        let lost = !self.received_in_cycle;
        if self.window.len() == 100 {
            self.window.pop_front();
        }
        self.window.push_back(!lost);
        self.received_in_cycle = false;
        self.published_id += 1;
        lost
    }

    /// `extrapolate(closed_id)` and its dispatch: the lost cycle (the one before the state now going out) guessed.
    pub fn guess(&mut self) {
        let closed = self.published_id - 1;
        match &mut self.run {
            Some(r) => r.last = closed,
            None => {
                self.run =
                    Some(Run { snapshot: self.history, snapshot_id: self.applied_id, first: closed, last: closed })
            }
        }
        self.history = self.history.extrapolated(1);
        self.applied_id = self.applied_id.max((self.applied_id + 1).min(closed));
        self.shown = self.history;
    }

    /// The state going out: what was dispatched last, in float32.
    pub fn publish(&self) -> Shown {
        let f32s = |x: [f64; JOINTS]| x.map(|x| x as f32 as f64);
        let answered = self.window.iter().filter(|&&a| a).count();
        Shown {
            q: f32s(self.shown.q),
            v: f32s(self.shown.v),
            a: f32s(self.shown.a),
            success_rate: if self.window.is_empty() { 1.0 } else { answered as f64 / self.window.len() as f64 },
        }
    }

    /// One command datagram, answering state `id`, read now (`_handle_commands` → `absorb_command` → dispatch).
    pub fn receive(&mut self, id: u64, c: &[f64; JOINTS]) {
        let fresh = id == self.published_id;
        self.received_in_cycle |= fresh;
        let in_run = self.run.is_some_and(|r| r.first <= id && id <= r.last);
        let rewound = !fresh && in_run;
        if let (true, Some(r)) = (rewound, self.run) {
            (self.history, self.applied_id) = (r.snapshot, r.snapshot_id);
        }
        let cycles = id.saturating_sub(self.applied_id).min(self.published_id.saturating_sub(self.applied_id)).max(1);
        self.judge(id, c, cycles);
        if fresh || rewound {
            self.history.record(c, cycles);
            self.applied_id = id;
            self.run = match self.run {
                Some(mut r) if in_run => {
                    (r.snapshot, r.snapshot_id, r.first) = (self.history, id, id + 1);
                    (r.first <= r.last).then_some(r)
                }
                _ => None,
            };
        }
        self.shown = History { q: *c, ..self.history };
    }

    /// `_check_position` (the velocity range at the command's position: the arm tracks it closely here).
    fn judge(&mut self, id: u64, c: &[f64; JOINTS], cycles: u64) {
        let step = cycles as f64 * 1e-3;
        let mut worst: Option<Judged> = None;
        for (joint, &c) in c.iter().enumerate() {
            let velocity = (c - self.history.q[joint]) / step;
            let acceleration = (velocity - self.history.v[joint]) / step;
            let jerk = (acceleration - self.history.a[joint]) / step;
            let velocity_range = velocity_range(joint, c);
            let this = Judged { id, joint, velocity, velocity_range, acceleration, jerk };
            if worst.is_none_or(|w| this.score() > w.score()) {
                worst = Some(this);
            }
        }
        self.judged.extend(worst);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The checker can fail: from rest, a step of 10 µrad is a jerk of 10 000 rad/s³; one of 5 µrad, a jerk of
    /// 5000 (within the limit, not strictly above it) and an acceleration of 5 rad/s².
    #[test]
    fn a_step_from_rest_is_judged_by_its_jerk() {
        let rest = History { q: [0.0; JOINTS], v: [0.0; JOINTS], a: [0.0; JOINTS] };
        let mut sim = SimChecker::new(rest, 0);
        let mut c = [0.0; JOINTS];
        c[1] = 10e-6;
        sim.receive(0, &c);
        let mut sim_within = SimChecker::new(rest, 0);
        c[1] = 5e-6;
        sim_within.receive(0, &c);
        let (out, within) = (sim.judged[0], sim_within.judged[0]);
        assert!(!out.within_limits() && out.joint == 1 && (out.jerk - 1e4).abs() < 1e-6, "{out:?}");
        assert!(within.within_limits() && (within.acceleration - 5.0).abs() < 1e-9, "{within:?}");
    }

    /// Near its stop a joint may move toward it only slowly (joint 4's upper stop at −0.1458 rad).
    #[test]
    fn the_velocity_range_narrows_toward_a_joint_s_stop() {
        assert_eq!(velocity_range(0, 0.0), (-2.62 + LIMIT_EPS, 2.62 - LIMIT_EPS));
        let (down, up) = velocity_range(3, -0.1458);
        assert_eq!(up, 0.0);
        assert!(down < -2.0);
    }
}
