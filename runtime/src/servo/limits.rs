//! The last check before a command leaves: inside the position limits, and — by finite differences over the
//! commands actually sent, the way the robot sees the stream — inside the velocity, acceleration and jerk
//! limits. The velocity bound is the robot's at the commanded position (the FR3's depends on it: see
//! `mars_profile::velocity_limits`). The smoother is built never to fail this; if it ever does, the command is not
//! sent and the watchdog trips.

use mars_ipc::MAX_JOINTS;
use mars_profile::Profile;
use mars_profile::velocity_limits::{JointVelocityBound, VelocityLimits};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Violation {
    NonFinite { joint: usize },
    Position { joint: usize },
    Velocity { joint: usize },
    Acceleration { joint: usize },
    Jerk { joint: usize },
}

pub struct LimitCheck {
    n: usize,
    dt: f64,
    q_min: [f64; MAX_JOINTS],
    q_max: [f64; MAX_JOINTS],
    velocity: [JointVelocityBound; MAX_JOINTS],
    /// Acceleration and jerk bounds, with a relative tolerance for floating-point rounding.
    bounds: [[f64; MAX_JOINTS]; 2],
    /// The last (up to) three positions sent, newest first.
    recent: [[f64; MAX_JOINTS]; 3],
    known: usize,
    pub violations: u64,
}

/// Finite differences of exactly-limited motion can exceed the limit by rounding only.
const ROUNDING: f64 = 1e-6;

impl LimitCheck {
    pub fn new(p: &Profile) -> Self {
        let n = p.joints;
        let mut c = Self {
            n,
            dt: p.period_s(),
            q_min: [0.0; MAX_JOINTS],
            q_max: [0.0; MAX_JOINTS],
            velocity: [JointVelocityBound::new(VelocityLimits::Constant, 0, 0.0); MAX_JOINTS],
            bounds: [[0.0; MAX_JOINTS]; 2],
            recent: [[0.0; MAX_JOINTS]; 3],
            known: 0,
            violations: 0,
        };
        let (q_min, q_max) = p.position_limits();
        c.q_min[..n].copy_from_slice(&q_min);
        c.q_max[..n].copy_from_slice(&q_max);
        c.velocity[..n].copy_from_slice(&p.velocity_bounds());
        for (k, lim) in [&p.ddq_max, &p.jerk_max].into_iter().enumerate() {
            for (bound, &l) in c.bounds[k][..n].iter_mut().zip(lim) {
                *bound = l * (1.0 + ROUNDING);
            }
        }
        c
    }

    /// Forget the stream (a gap in sending, or a new session): differences restart from the next command.
    pub fn restart(&mut self) {
        self.known = 0;
    }

    /// Continue the stream from a setpoint the robot applied (position, velocity, acceleration as finite
    /// differences, as the HAL reports them): the three previous positions are reconstructed from them.
    pub fn continue_from(&mut self, q: &[f64], v: &[f64], a: &[f64]) {
        let dt = self.dt;
        for j in 0..self.n {
            let q1 = q[j] - v[j] * dt;
            let v1 = v[j] - a[j] * dt;
            self.recent[0][j] = q[j];
            self.recent[1][j] = q1;
            self.recent[2][j] = q1 - v1 * dt;
        }
        // The acceleration before `a` is unknown, so the first jerk after a re-sync is checked against a
        // reconstructed history in which it was constant.
        self.known = 3;
    }

    /// The velocity of joint `j` over the last two commands accepted (a finite difference, as the robot takes it).
    pub fn last_velocity(&self, j: usize) -> Option<f64> {
        (self.known >= 2).then(|| (self.recent[0][j] - self.recent[1][j]) / self.dt)
    }

    /// The acceleration of joint `j` over the last three commands accepted (a second finite difference, as the
    /// robot takes it).
    pub fn last_acceleration(&self, j: usize) -> Option<f64> {
        (self.known >= 3)
            .then(|| (self.recent[0][j] - 2.0 * self.recent[1][j] + self.recent[2][j]) / (self.dt * self.dt))
    }

    /// Checks `q` as the next command after the ones accepted so far; accepted commands join the stream.
    pub fn admit(&mut self, q: &[f64]) -> Result<(), Violation> {
        let verdict = self.verdict(q);
        match verdict {
            Ok(()) => {
                self.recent.copy_within(0..2, 1);
                self.recent[0][..self.n].copy_from_slice(&q[..self.n]);
                self.known = (self.known + 1).min(3);
            }
            Err(_) => self.violations += 1,
        }
        verdict
    }

    fn verdict(&self, q: &[f64]) -> Result<(), Violation> {
        let (r, dt) = (&self.recent, self.dt);
        for j in 0..self.n {
            if !q[j].is_finite() {
                return Err(Violation::NonFinite { joint: j });
            }
            if q[j] < self.q_min[j] || q[j] > self.q_max[j] {
                return Err(Violation::Position { joint: j });
            }
            let (v_lo, v_hi) = self.velocity[j].hard(q[j]);
            let v = (q[j] - r[0][j]) / dt;
            if self.known >= 1 && (v > v_hi + ROUNDING * v_hi.abs() || v < v_lo - ROUNDING * v_lo.abs()) {
                return Err(Violation::Velocity { joint: j });
            }
            if self.known >= 2 && ((q[j] - 2.0 * r[0][j] + r[1][j]) / (dt * dt)).abs() > self.bounds[0][j] {
                return Err(Violation::Acceleration { joint: j });
            }
            let jerk = (q[j] - 3.0 * r[0][j] + 3.0 * r[1][j] - r[2][j]) / (dt * dt * dt);
            if self.known >= 3 && jerk.abs() > self.bounds[1][j] {
                return Err(Violation::Jerk { joint: j });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn profile() -> Profile {
        let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/fr3.toml")).unwrap();
        Profile::parse(&text, "fr3.toml").unwrap()
    }

    #[test]
    fn refuses_each_limit_and_keeps_the_stream_of_accepted_commands() {
        let p = profile();
        let mut c = LimitCheck::new(&p);
        let home = p.home.clone();
        for _ in 0..4 {
            assert_eq!(c.admit(&home), Ok(()));
        }
        let mut q = home.clone();
        q[0] += 0.01; // 10 rad/s in one 1 ms tick
        assert_eq!(c.admit(&q), Err(Violation::Velocity { joint: 0 }));
        q[0] = home[0] + 2e-6; // 2 mrad/s, but 2 rad/s² … fine; 2000 rad/s³: fine too
        assert_eq!(c.admit(&q), Ok(()));
        let mut q2 = q.clone();
        q2[1] += 2e-5; // from rest: 20 rad/s² at once
        assert_eq!(c.admit(&q2), Err(Violation::Acceleration { joint: 1 }));
        let mut out = q.clone(); // continues the accepted stream on every other joint
        out[3] = p.q_max[3] + 0.01;
        assert_eq!(c.admit(&out), Err(Violation::Position { joint: 3 }));
        out[3] = f64::NAN;
        assert_eq!(c.admit(&out), Err(Violation::NonFinite { joint: 3 }));
        assert_eq!(c.violations, 4);
    }

    #[test]
    fn jerk_is_checked_once_three_commands_are_known() {
        let p = profile();
        let mut c = LimitCheck::new(&p);
        let mut q = p.home.clone();
        c.admit(&q).unwrap();
        c.admit(&q).unwrap();
        c.admit(&q).unwrap();
        // 6e-6 rad in one tick from rest: v = 6 mrad/s, a = 6 rad/s², j = 6000 rad/s³ > 5000.
        q[2] += 6e-6;
        assert_eq!(c.admit(&q), Err(Violation::Jerk { joint: 2 }));
        c.restart();
        assert_eq!(c.admit(&q), Ok(()), "after a restart no difference is taken across the gap");
    }

    /// The FR3's velocity bound near a limit is far below `dq_max`: 1 rad/s is fine in the middle of joint 1's
    /// range and out of limits 0.05 rad from its end.
    #[test]
    fn the_velocity_bound_is_the_robots_at_the_commanded_position() {
        let p = profile();
        let mut c = LimitCheck::new(&p);
        let mut q = p.home.clone();
        c.admit(&q).unwrap();
        q[0] += 1e-3; // 1 rad/s
        assert_eq!(c.admit(&q), Ok(()));
        c.restart();
        q[0] = 2.69;
        c.admit(&q).unwrap();
        q[0] += 1e-3;
        assert_eq!(c.admit(&q), Err(Violation::Velocity { joint: 0 }));
        // Moving away from that limit, the other side of the bound applies: 1 rad/s is fine.
        q[0] -= 2e-3;
        c.restart();
        c.admit(&[2.69, q[1], q[2], q[3], q[4], q[5], q[6]]).unwrap();
        assert_eq!(c.admit(&q), Ok(()));
    }
}
