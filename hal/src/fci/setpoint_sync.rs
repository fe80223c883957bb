//! Keeping the HAL's setpoint continuous with what the robot actually applied.
//!
//! When a command does not reach the robot in its cycle (or we never see a state), the robot extrapolates its
//! own setpoint at constant acceleration ("a linear extrapolation ... for the missed time step", libfranka's
//! `docs/system_requirements.rst`) and reports it as `q_d`. Our next command, continuing a trajectory whose
//! acceleration changed meanwhile, then differs from the extrapolation by about jerk·dt³, which the robot's
//! differencing reads as a step in acceleration: with marsd planning at 90 % of the limits it tripped franka-sim's
//! velocity-discontinuity reflex. libfranka's rate limiter avoids this by always continuing from the robot's
//! reported `q_d`/`dq_d`/`ddq_d`; but those are rounded (franka-sim sends float32), and continuing from a rounded
//! position every cycle is itself ~500 rad/s³ of jerk noise. So the HAL continues from the robot only when the
//! robot applied something else, and then from the robot's *applied positions* differenced exactly as the robot
//! differences them, our own exact values wherever the robot applied them.

use super::state::JOINTS;

/// A reported setpoint this far (rad) from our last command means the robot applied another one: above float32
/// rounding (at most 2.4e-7 rad below 4.6 rad), below the jerk·dt³ (4.5e-6 rad at 4500 rad/s³) that matters.
pub const RESYNC_RAD: f64 = 5e-7;

/// The FCI cycle (s).
const DT: f64 = 1e-3;

/// The state the filter continues from after the robot applied another setpoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Resync {
    pub q: [f64; JOINTS],
    pub v: [f64; JOINTS],
    pub a: [f64; JOINTS],
}

/// The robot's applied setpoints of its last three cycles (oldest first), and our last command.
#[derive(Debug, Default)]
pub struct RobotSetpoints {
    applied: Vec<[f64; JOINTS]>,
    sent: Option<[f64; JOINTS]>,
}

impl RobotSetpoints {
    pub fn new() -> Self {
        // Capacity 4: pushing the fourth before dropping the first never reallocates.
        Self { applied: Vec::with_capacity(4), sent: None }
    }

    /// Our command for this cycle.
    pub fn sent(&mut self, command: [f64; JOINTS]) {
        self.sent = Some(command);
    }

    /// One state: `q_d`, `dq_d`, `ddq_d` (the setpoint applied last cycle and the robot's derivatives of it) and
    /// whether states were skipped since the last one. Returns where to continue from when the robot applied
    /// something else than our last command.
    pub fn observe(
        &mut self,
        q_d: &[f64; JOINTS],
        dq_d: &[f64; JOINTS],
        ddq_d: &[f64; JOINTS],
        skipped: bool,
    ) -> Option<Resync> {
        let sent = self.sent.take();
        let matched = sent.filter(|s| s.iter().zip(q_d).all(|(a, b)| (a - b).abs() <= RESYNC_RAD));
        if skipped {
            // The cycles between are unknown: no differences across them.
            self.applied.clear();
        }
        if self.applied.len() == 3 {
            self.applied.remove(0);
        }
        self.applied.push(matched.unwrap_or(*q_d));
        if matched.is_some() || sent.is_none() {
            return None;
        }
        if let [q0, q1, q2] = self.applied[..] {
            let mut r = Resync { q: q2, v: [0.0; JOINTS], a: [0.0; JOINTS] };
            for j in 0..JOINTS {
                r.v[j] = (q2[j] - q1[j]) / DT;
                r.a[j] = (r.v[j] - (q1[j] - q0[j]) / DT) / DT;
            }
            Some(r)
        } else {
            Some(Resync { q: *q_d, v: *dq_d, a: *ddq_d })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A joint-1 trajectory with jerk 4500 rad/s³ from rest: the command of cycle k.
    fn traj(k: usize) -> [f64; JOINTS] {
        let t = k as f64 * DT;
        let mut q = [0.5; JOINTS];
        q[0] = 0.5 + 4500.0 * t * t * t / 6.0;
        q
    }

    /// The robot's constant-acceleration extrapolation after cycles k−2, k−1 (as franka-sim does it).
    fn extrapolated(k: usize) -> [f64; JOINTS] {
        let (q0, q1, q2) = (traj(k - 3), traj(k - 2), traj(k - 1));
        let mut e = q2;
        for j in 0..JOINTS {
            let v = (q2[j] - q1[j]) / DT;
            let a = (v - (q1[j] - q0[j]) / DT) / DT;
            e[j] = q2[j] + (v + a * DT) * DT;
        }
        e
    }

    #[test]
    fn a_command_the_robot_applied_needs_no_resync_even_rounded_to_float32() {
        let mut s = RobotSetpoints::new();
        let zero = [0.0; JOINTS];
        for k in 0..10 {
            s.sent(traj(k));
            let reported = traj(k).map(|q| q as f32 as f64);
            assert_eq!(s.observe(&reported, &zero, &zero, false), None, "cycle {k}");
        }
    }

    #[test]
    fn after_a_lost_command_it_continues_from_the_extrapolation_differenced_like_the_robot() {
        let mut s = RobotSetpoints::new();
        let zero = [0.0; JOINTS];
        for k in 0..10 {
            s.sent(traj(k));
            assert_eq!(s.observe(&traj(k), &zero, &zero, false), None);
        }
        // Command 10 is lost: the robot reports its extrapolation, and a velocity one cycle stale (what the
        // HAL must not take).
        s.sent(traj(10));
        let e = extrapolated(10);
        let stale = [9.0; JOINTS];
        let r = s.observe(&e, &stale, &stale, false).expect("a resync");
        assert_eq!(r.q, e);
        let v = (e[0] - traj(9)[0]) / DT;
        let a = (v - (traj(9)[0] - traj(8)[0]) / DT) / DT;
        assert!((r.v[0] - v).abs() < 1e-9 && (r.a[0] - a).abs() < 1e-6, "{r:?}");
        // The extrapolation kept the acceleration of the last two real commands.
        let a_before = ((traj(9)[0] - traj(8)[0]) - (traj(8)[0] - traj(7)[0])) / (DT * DT);
        assert!((r.a[0] - a_before).abs() < 1e-6, "{} vs {a_before}", r.a[0]);
    }

    #[test]
    fn after_skipped_states_it_takes_the_robots_own_derivatives() {
        let mut s = RobotSetpoints::new();
        let zero = [0.0; JOINTS];
        for k in 0..5 {
            s.sent(traj(k));
            s.observe(&traj(k), &zero, &zero, false);
        }
        s.sent(traj(5));
        let (dq, ddq) = ([0.1; JOINTS], [0.2; JOINTS]);
        let r = s.observe(&traj(7), &dq, &ddq, true).expect("a resync");
        assert_eq!((r.q, r.v, r.a), (traj(7), dq, ddq));
    }
}
