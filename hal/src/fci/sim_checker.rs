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

use super::setpoint_sync::History;
use super::state::JOINTS;

/// franka-sim's limits (`limits/tables.py`: `MAX_JOINT_ACCELERATION`, `MAX_JOINT_JERK`), compared strictly.
pub const MAX_ACCELERATION: f64 = 10.0;
pub const MAX_JERK: f64 = 5000.0;

/// The open run of guessed cycles: the history before its first guess (or after the last late command of it
/// recorded), that history's id, and the ids of the guessed cycles still unanswered.
#[derive(Debug, Clone, Copy)]
struct Run {
    snapshot: History,
    snapshot_id: u64,
    first: u64,
    last: u64,
}

/// What franka-sim judged one command to be, the worst joint: its acceleration and jerk.
#[derive(Debug, Clone, Copy)]
pub struct Judged {
    pub id: u64,
    pub joint: usize,
    pub acceleration: f64,
    pub jerk: f64,
}

impl Judged {
    pub fn within_limits(&self) -> bool {
        self.acceleration.abs() <= MAX_ACCELERATION && self.jerk.abs() <= MAX_JERK
    }
}

/// One state as the HAL reads it: `q_d`, `dq_d`, `ddq_d` in float32, and the success rate.
#[derive(Debug, Clone, Copy)]
pub struct Shown {
    pub id: u64,
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

    /// The history franka-sim judges the next command against (as it stands now).
    pub fn history(&self) -> History {
        self.history
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
            id: self.published_id,
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
        if std::env::var("SIMDBG").is_ok() { eprintln!("recv id {id} fresh {fresh} rewound {rewound} cycles {cycles} applied {} hist q3 {} v3 {} c3 {} run {:?}", self.applied_id, self.history.q[3], self.history.v[3], c[3], self.run.map(|r| (r.snapshot_id, r.first, r.last, r.snapshot.q[3]))); }
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

    fn judge(&mut self, id: u64, c: &[f64; JOINTS], cycles: u64) {
        let step = cycles as f64 * 1e-3;
        let mut worst: Option<Judged> = None;
        for (joint, &c) in c.iter().enumerate() {
            let v = (c - self.history.q[joint]) / step;
            let acceleration = (v - self.history.v[joint]) / step;
            let jerk = (acceleration - self.history.a[joint]) / step;
            let score = |j: &Judged| (j.acceleration / MAX_ACCELERATION).abs().max((j.jerk / MAX_JERK).abs());
            let this = Judged { id, joint, acceleration, jerk };
            if worst.is_none_or(|w| score(&this) > score(&w)) {
                worst = Some(this);
            }
        }
        self.judged.extend(worst);
    }
}
