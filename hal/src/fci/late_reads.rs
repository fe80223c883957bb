//! Applied mode (franka-sim), no state unseen: which history franka-sim judges our next command against, from what
//! its states show.
//!
//! franka-sim 1.1.7 reads every command datagram, one per poll turn, in the order sent (`server/state_stream.py`).
//! A command that missed its cycle made it guess that cycle (the guess recorded and shown in `q_d`, `dq_d`, `ddq_d`);
//! when it reads the late command it rewinds the guesses of that run and records the command over the cycles since
//! the last one it recorded (`limits/checker.py`, `absorb_command`). So however late our commands come, the history
//! they are judged against is **ours**; the states in between show guesses from whichever of our commands it had
//! read by then ([`Unread`]). One exception: a late command read after franka-sim closed its cycle and before it
//! guessed it (its receive and publish threads race there) is judged but not recorded, and the guess stands
//! ([`Race`]): our next command is then recorded after the guess if it comes in its cycle, or over both cycles from
//! the last command recorded if it comes late too. Which, a later state may show; until then those histories are
//! the alternatives the filter keeps its step within the limits from, where it can.

use super::JOINTS;
use super::history::{History, RESYNC_RAD, RESYNC_RAD_S, distance};

/// A reported acceleration (rad/s²) this far from a history's is another history: above float32's rounding (at
/// most 4.8e-7 below 16 rad/s²).
const RESYNC_RAD_S2: f64 = 1e-6;

/// The most of our commands franka-sim may not have read yet that the model keeps (its drain gate holds a state
/// back at most 5 ms for a queued command; it stops guessing at 20 lost cycles).
const UNREAD: usize = 24;

/// The most histories a [`Race`] has before it is ours again (velocity and acceleration are differences of the last
/// three commands).
const AFTER: usize = 3;

/// The most race histories kept at once.
pub const MAX_RACES: usize = 4;

/// Whether the state `shown` is `h` extrapolated by franka-sim `n` times, for some `n ≤ n_max` (0: `h` itself).
fn shows(h: &History, n_max: u64, shown: &History) -> bool {
    if distance(&h.a, &shown.a) > RESYNC_RAD_S2 {
        return false; // the guesses keep the acceleration: none of them
    }
    let mut g = *h;
    for n in 0..=n_max {
        if n > 0 {
            g = g.extrapolated(1);
        }
        if distance(&g.v, &shown.v) <= RESYNC_RAD_S && distance(&g.q, &shown.q) <= RESYNC_RAD {
            return true;
        }
    }
    false
}

/// A state that shows our command `c` with `h`'s derivatives: a command read after the guess of its cycle was
/// dispatched, or before the state was packed.
fn shows_with(c: &[f64; JOINTS], h: &History, shown: &History) -> bool {
    distance(c, &shown.q) <= RESYNC_RAD
        && distance(&h.v, &shown.v) <= RESYNC_RAD_S
        && distance(&h.a, &shown.a) <= RESYNC_RAD_S2
}

/// Our histories after each of our commands since the last one a state showed franka-sim had read: a state shows
/// the newest (read in its cycle), or guesses from any of them (the later ones not read yet), or one of them as it
/// was (a state packed before the newest command was dispatched).
#[derive(Debug, Clone)]
pub struct Unread {
    ring: [History; UNREAD],
    /// Index of the oldest kept, and how many.
    start: usize,
    len: usize,
}

impl Unread {
    /// Only `h`: read.
    pub fn new(h: History) -> Self {
        Self { ring: [h; UNREAD], start: 0, len: 1 }
    }

    fn at(&self, i: usize) -> &History {
        &self.ring[(self.start + i) % UNREAD]
    }

    /// Ours after our next command.
    pub fn push(&mut self, h: History) {
        if self.len == UNREAD {
            (self.start, self.len) = ((self.start + 1) % UNREAD, UNREAD - 1);
        }
        self.ring[(self.start + self.len) % UNREAD] = h;
        self.len += 1;
    }

    /// The history before the newest.
    pub fn before_newest(&self) -> Option<&History> {
        (self.len >= 2).then(|| self.at(self.len - 2))
    }

    /// Whether ours explains the state: the newest read, or a guess from one of them after it was read (at most as
    /// many guesses as cycles since). Forgets those before the one shown (franka-sim had read them).
    pub fn explain(&mut self, shown: &History) -> bool {
        let found = (0..self.len).rev().find(|&i| shows(self.at(i), (self.len - 1 - i) as u64, shown));
        if let Some(i) = found {
            (self.start, self.len) = ((self.start + i) % UNREAD, self.len - i);
        }
        found.is_some()
    }
}

/// A history franka-sim may have kept instead of ours: it threw away our command after `applied` (and, rarer still,
/// the next ones too: `guessed` in all), its guesses standing for them, and recorded our commands after them into
/// `after` (up to [`AFTER`]: then it is ours again).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Race {
    applied: History,
    guessed: u64,
    after: [History; AFTER],
    after_len: usize,
}

impl Race {
    /// Our command after `applied` thrown away.
    pub fn new(applied: History) -> Self {
        Self { applied, guessed: 1, after: [applied; AFTER], after_len: 0 }
    }

    /// What franka-sim judges our next command against in this history, and over how many cycles: after the
    /// guesses if it comes in its cycle, over them from `applied` if late; after our last read command once one was.
    pub fn judged_from(&self) -> [Option<(History, u64)>; 2] {
        match self.after_len {
            0 => [Some((self.applied.extrapolated(self.guessed), 1)), Some((self.applied, self.guessed + 1))],
            n => [Some((self.after[n - 1], 1)), None],
        }
    }

    /// The robot's history for our next command where this one turns out to be the robot's: after its guesses (in
    /// its cycle; the late reading stays an alternative), or after our last command read.
    pub fn current(&self) -> History {
        match self.after_len {
            0 => self.applied.extrapolated(self.guessed),
            n => self.after[n - 1],
        }
    }

    fn with_after(mut self, h: History) -> Self {
        self.after[self.after_len] = h;
        self.after_len += 1;
        self
    }

    /// Whether the state is a guess from this history while our commands after the race are unread.
    fn shows_unread(&self, shown: &History) -> bool {
        let guessed_from_applied = shows(&self.applied.extrapolated(self.guessed), 20, shown);
        guessed_from_applied || self.after[..self.after_len].iter().any(|h| shows(h, 20, shown))
    }

    /// The histories this one becomes with our command `c` sent, those the state `shown` allows, into `out` (see
    /// [`Races`]); none once it is ours (`ours`) again. `lost`: franka-sim counted `c`'s cycle lost (the success rate
    /// fell), so it read `c` late or threw it away; where it did not, `c` came in its cycle (the guess of its cycle
    /// can be `c` itself: at a constant acceleration the guess is our own law).
    fn advance(&self, c: &[f64; JOINTS], ours: &History, shown: &History, lost: bool, out: &mut Races) {
        if self.after_len == 0 {
            let guesses = self.applied.extrapolated(self.guessed);
            let mut in_cycle = guesses;
            in_cycle.record(c, 1);
            let mut late = self.applied;
            late.record(c, self.guessed + 1);
            let next_guess = self.applied.extrapolated(self.guessed + 1);
            let in_its_cycle = shows(&in_cycle, 0, shown);
            if in_its_cycle && !lost {
                out.add(self.with_after(in_cycle));
            }
            let not_in_its_cycle = lost || !in_its_cycle;
            if not_in_its_cycle && (shows(&next_guess, 0, shown) || shows(&late, 0, shown)) {
                out.add(self.with_after(late));
            }
            if not_in_its_cycle && (shows(&next_guess, 0, shown) || shows_with(c, &next_guess, shown)) {
                out.add(Race { guessed: self.guessed + 1, ..*self });
            }
            return;
        }
        let mut next = self.after[self.after_len - 1];
        next.record(c, 1);
        if self.after_len == AFTER || distance(&next.v, &ours.v) + distance(&next.a, &ours.a) == 0.0 {
            return; // ours again
        }
        if shows(&next, 0, shown) || self.shows_unread(shown) {
            out.add(self.with_after(next));
        }
    }
}

/// The race histories still possible, single races before double ones (the likelier first).
#[derive(Debug, Clone, Default)]
pub struct Races {
    kept: [Option<Race>; MAX_RACES],
}

impl Races {
    fn add(&mut self, r: Race) {
        if self.kept.contains(&Some(r)) {
            return;
        }
        // In order of guesses; the last one falls off when all are taken.
        let at = self.kept.iter().position(|k| k.is_none_or(|k| k.guessed > r.guessed));
        if let Some(at) = at {
            self.kept[at..].rotate_right(1);
            self.kept[at] = Some(r);
        }
    }

    /// After `r` turned out to be the robot's: while our command after its guesses is unread, franka-sim may yet
    /// read it late and record it over their cycles too; that stays an alternative.
    pub fn keep_open(&mut self, r: Race) {
        if r.after_len == 0 {
            self.add(r);
        }
    }

    pub fn clear(&mut self) {
        self.kept = [None; MAX_RACES];
    }

    pub fn iter(&self) -> impl Iterator<Item = &Race> {
        self.kept.iter().flatten()
    }

    /// With our command `c` sent (ours after it: `ours`, ours before it `before`), the state `shown`, and whether
    /// `c`'s cycle was counted lost: each race history advanced, those the state rules out dropped, and a new one
    /// where the state is the guess of `c`'s cycle from `before` and `c` did not come in its cycle (franka-sim may
    /// have read it in the race window).
    pub fn advance(
        &mut self,
        c: &[f64; JOINTS],
        before: Option<&History>,
        ours: &History,
        shown: &History,
        lost: bool,
    ) {
        let mut next = Races::default();
        for r in self.iter() {
            r.advance(c, ours, shown, lost, &mut next);
        }
        if let Some(b) = before {
            let guess = b.extrapolated(1);
            let not_in_its_cycle = lost || !shows(ours, 0, shown);
            if not_in_its_cycle && (shows(&guess, 0, shown) || shows_with(c, &guess, shown)) {
                next.add(Race::new(*b));
            }
        }
        *self = next;
    }

    /// The first race history that shows the state (ours does not).
    pub fn showing(&self, c: &[f64; JOINTS], shown: &History) -> Option<Race> {
        self.iter().copied().find(|r| {
            shows(&r.current(), 0, shown)
                || shows_with(c, &r.current(), shown)
                || r.after_len > 0 && r.shows_unread(shown)
        })
    }
}
