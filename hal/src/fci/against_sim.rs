//! The HAL's model of franka-sim's history (`setpoint_sync`) and its filter (`safety`), driven against franka-sim's
//! own rules (`sim_checker`) cycle by cycle: when franka-sim reads each of our commands is the test's choice (a
//! schedule), and every command is judged as franka-sim judges it.

use std::path::Path;

use mars_ipc::MAX_JOINTS;

use super::JOINTS;
use super::history::History;
use super::setpoint_sync::RobotSetpoints;
use super::sim_checker::{Judged, Shown, SimChecker};
use crate::safety::SafetyFilter;
use mars_profile::Profile;

mod random;

/// When franka-sim reads our command answering state `k`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Read {
    /// In its cycle, before the next state goes out.
    Fresh,
    /// In the cycle of state `k + d` (after it went out): late, rewound and recorded.
    Late(u64),
    /// After franka-sim closed its cycle and before it guessed it: thrown away, the guess stands.
    Race,
}

/// Moments on franka-sim's clock, in half cycles: `2k + 1` during cycle `k` (after state `k` went out),
/// `2k` inside the tick that publishes state `k`, between closing the cycle before and guessing it.
fn moment(k: u64, r: Read) -> u64 {
    match r {
        Read::Fresh => 2 * k + 1,
        Read::Late(d) => 2 * (k + d) + 1,
        Read::Race => 2 * (k + 1),
    }
}

/// The target stream (what marsd sends) at state `k`, and which states the HAL sees.
pub struct Scenario<'a> {
    pub start: History,
    pub target: &'a dyn Fn(u64) -> [f64; MAX_JOINTS],
    pub read: &'a dyn Fn(u64) -> Read,
    pub seen: &'a dyn Fn(u64) -> bool,
    pub states: u64,
}

/// What a run left: every command as franka-sim judged it, and the HAL's resyncs.
pub struct Outcome {
    pub judged: Vec<Judged>,
    pub resyncs: u64,
    /// Steps kept within the limits from other histories too.
    pub judged_twice: u64,
}

impl Outcome {
    pub fn violations(&self) -> Vec<Judged> {
        self.judged.iter().filter(|j| !j.within_limits()).copied().collect()
    }
}

pub fn fr3() -> Profile {
    Profile::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/fr3.toml")).unwrap()
}

/// Runs the HAL (model and filter, as `fci::drive` wires them) against franka-sim from `start`, recorded for
/// state 0 and shown in it.
pub fn run(s: &Scenario) -> Outcome {
    let p = fr3();
    let mut sim = SimChecker::new(s.start, 0);
    let mut model = RobotSetpoints::new(true);
    let mut filter = SafetyFilter::new(&p, &s.start.q);
    filter.resync(&s.start.q, &s.start.v, &s.start.a);
    let mut pending: std::collections::VecDeque<(u64, u64, [f64; JOINTS])> = Default::default();
    let (mut last_seen, mut last_moment) = (None::<u64>, 0);
    let mut out = Outcome { judged: Vec::new(), resyncs: 0, judged_twice: 0 };
    let mut shown = sim.publish();
    for k in 0..=s.states {
        if k > 0 {
            read_until(&mut sim, &mut pending, 2 * k - 1);
            let lost = sim.close_cycle();
            read_until(&mut sim, &mut pending, 2 * k);
            if lost {
                sim.guess();
            }
            shown = sim.publish();
        }
        if !(s.seen)(k) && k > 0 {
            continue;
        }
        let missed = last_seen.map_or(0, |l| k - l - 1);
        last_seen = Some(k);
        let c = hal_tick(&mut model, &mut filter, &shown, missed, &(s.target)(k), &mut out);
        last_moment = last_moment.max(moment(k, (s.read)(k)));
        pending.push_back((last_moment, k, c));
    }
    out.judged = sim.judged;
    out
}

fn read_until(sim: &mut SimChecker, pending: &mut std::collections::VecDeque<(u64, u64, [f64; JOINTS])>, m: u64) {
    while let Some(&(at, id, c)) = pending.front().filter(|p| p.0 <= m) {
        let _ = at;
        sim.receive(id, &c);
        pending.pop_front();
    }
}

/// One HAL tick as `fci::drive` runs it: the model reads the state, the filter continues (from the robot's history
/// where the model says so), the command goes out.
fn hal_tick(
    model: &mut RobotSetpoints,
    filter: &mut SafetyFilter,
    s: &Shown,
    missed: u64,
    target: &[f64; MAX_JOINTS],
    out: &mut Outcome,
) -> [f64; JOINTS] {
    if let Some(r) = model.observe(&s.q, &s.v, &s.a, s.success_rate, missed) {
        filter.resync(&r.q, &r.v, &r.a);
        out.resyncs += 1;
    }
    let mut judged_twice = false;
    for (h, cycles) in model.alternatives() {
        filter.also_judged_from(&h.q, &h.v, &h.a, cycles);
        judged_twice = true;
    }
    out.judged_twice += u64::from(judged_twice);
    let mut c = [0.0; JOINTS];
    c.copy_from_slice(&filter.step(Some(target))[..JOINTS]);
    model.sent(c);
    c
}

/// The FR3's home pose, `q`'s joint `j` at `(q, v, a)`.
pub fn home_with(j: usize, (q, v, a): (f64, f64, f64)) -> History {
    let p = fr3();
    let mut h = History { q: [0.0; JOINTS], v: [0.0; JOINTS], a: [0.0; JOINTS] };
    h.q.copy_from_slice(&p.home[..JOINTS]);
    (h.q[j], h.v[j], h.a[j]) = (q, v, a);
    h
}

/// A stream from `start`: joint `j` follows `jerk(k)` (rad/s³) from its history with franka's law, within `a_max`.
pub fn stream_from(
    start: History,
    j: usize,
    jerk: &dyn Fn(u64, f64, f64) -> f64,
    states: u64,
) -> Vec<[f64; MAX_JOINTS]> {
    let mut h = start;
    let mut out = vec![[0.0; MAX_JOINTS]; states as usize + 1];
    for (k, c) in out.iter_mut().enumerate() {
        c[..JOINTS].copy_from_slice(&h.q);
        let a = h.a[j] + jerk(k as u64, h.v[j], h.a[j]) * 1e-3;
        h.v[j] += a * 1e-3;
        h.q[j] += h.v[j] * 1e-3;
        h.a[j] = a;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Joint `j` (from 0: 1 at its home, 4 at −2.3752 rad) from `v0` rad/s and `a0` rad/s² at state 0, marsd's
    /// stream adding `jerk(k)` rad/s³ to our command answering state `k`, our commands read as `read` says: how
    /// franka-sim judged them.
    fn joint(j: usize, (v0, a0): (f64, f64), jerk: &dyn Fn(u64) -> f64, read: &dyn Fn(u64) -> Read) -> Outcome {
        let q0 = if j == 3 { -2.3752 } else { fr3().home[j] };
        let start = home_with(j, (q0, v0, a0));
        let stream = stream_from(start, j, &|k, _, _| jerk(k), 40);
        let target = |k: u64| stream[(k as usize + 1).min(40)];
        run(&Scenario { start, target: &target, read, seen: &|_| true, states: 30 })
    }

    /// Joint 4 braking at about 9 rad/s² as logged before the reflex below (with marsd's jerk of 55 rad/s³, so ours
    /// and franka-sim's guesses differ, as logged).
    fn braking_at_9(read: &dyn Fn(u64) -> Read) -> Outcome {
        joint(3, (-0.1, 8.0), &|_| 55.0, read)
    }

    /// The reflex of 2026-11-27 under build load (`mars-hil faults`, run 1, trial 64: franka-sim named −9437 rad/s³
    /// on joint 4): marsd braking joint 4 at 9 rad/s²; our commands 6 and 7 both reached franka-sim after state 8
    /// went out (it showed its second guess), and franka-sim read them in turn, rewound, recorded both, and judged
    /// our command 8 against them. The model had read state 8 as 6 thrown away and continued from 7 recorded over
    /// two cycles.
    #[test]
    fn two_late_commands_read_together_are_both_recorded_and_ours_is_the_history() {
        let read = |k: u64| match k {
            11 => Read::Late(2),
            12 => Read::Late(1),
            _ => Read::Fresh,
        };
        let o = braking_at_9(&read);
        assert_eq!(o.violations().len(), 0, "{:?}", o.violations());
        assert_eq!(o.resyncs, 0);
    }

    /// franka-sim read our command 11 in its race window (thrown away, its guess stands) and 12 in its cycle
    /// (recorded after the guess); the state after 12 shows it, and the model continues from franka-sim's history.
    #[test]
    fn a_command_thrown_away_then_one_in_its_cycle() {
        let o = braking_at_9(&|k| if k == 11 { Read::Race } else { Read::Fresh });
        assert_eq!(o.violations().len(), 0, "{:?}", o.violations());
        assert_eq!(o.resyncs, 1);
    }

    /// The same with 12 late too: franka-sim rewinds the guess and records 12 over both cycles from 10. At 9 rad/s²
    /// that history's acceleration is 6.75 where ours is 9, and our command 13 (sent while the state still shows a
    /// guess: ours unread, or 12 unread after 11 thrown away) is kept within the limits from both.
    #[test]
    fn a_command_thrown_away_then_one_late() {
        for late in 1..=3 {
            let o = braking_at_9(&|k| match k {
                11 => Read::Race,
                12 => Read::Late(late),
                _ => Read::Fresh,
            });
            assert_eq!(o.violations().len(), 0, "12 late by {late}: {:?}", o.violations());
        }
    }

    /// franka-sim throws our command 11 away during a jerk phase (11's jerk `j` from ours) and reads 12 in its cycle:
    /// from its guess, 12 reads as 12's jerk from ours plus 3·`j`, and its acceleration plus 2·`j`·dt. Where some
    /// step is within the limits from both (here up to about 3000 rad/s³ at 5 rad/s²), 12 is; beyond, none is, and
    /// ours decides (the likelier: the same states show 11 merely late): the one command franka-sim judges out of its
    /// limits (its acceleration out of them too, the next one as well). The state after 12 shows franka-sim's
    /// history, and the model follows it.
    #[test]
    fn a_command_thrown_away_in_a_jerk_phase_then_one_in_its_cycle() {
        let read = |k: u64| if k == 11 { Read::Race } else { Read::Fresh };
        // A jerk phase of commands 9..=11 ending at ±5 rad/s², then a constant acceleration.
        let phase = |j: f64| {
            let a0 = 5.0 * j.signum() - 3.0 * j * 1e-3;
            joint(0, (0.0, a0), &move |k| if (9..=11).contains(&k) { j } else { 0.0 }, &read)
        };
        for jerk in [-3000.0, -1500.0, 1500.0, 3000.0] {
            let o = phase(jerk);
            assert_eq!(o.violations().len(), 0, "jerk {jerk}: {:?}", o.violations());
        }
        let o = phase(4500.0);
        let v = o.violations();
        assert_eq!(v[0].id, 12, "{v:?}");
        assert!(v[0].jerk > 5000.0, "{v:?}");
        assert!(v.iter().all(|j| j.id <= 13), "{v:?}");
        assert_eq!(o.resyncs, 1, "the model followed franka-sim's history once the state after 12 showed it");
    }
}
