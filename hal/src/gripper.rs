//! The gripper as what it is: a width to move to at a limited speed, not a 1 kHz stream.
//!
//! A Franka Hand takes one blocking move(width, speed) at a time; an R1 Lite gripper a target on a topic. So a
//! controller's gripper field is a *target*: this module passes a new one to the backend only when it moved by
//! more than the profile's deadband from the one sent last, or when it has stood still for an interval (so a
//! ramp's end arrives exactly), and at most once per the profile's interval (a target that keeps changing, e.g.
//! a policy's interpolated closing, is sent as it stands when the interval ends). The speed is the command's
//! `gripper_speed`, capped by the profile's `gripper_speed_max` (0 asks for the cap).

use mars_profile::Profile;

/// One move for the backend: go to `width` (m) at `speed` (m/s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GripperMove {
    pub width: f64,
    pub speed: f64,
}

pub struct GripperTarget {
    speed_max: f64,
    deadband: f64,
    interval_ticks: u64,
    /// The move the backend has (its target is where the gripper is going).
    sent: GripperMove,
    /// The newest admitted target not yet passed on, and for how many ticks it has not changed.
    pending: Option<GripperMove>,
    pending_steady_ticks: u64,
    ticks_since_sent: u64,
    /// Moves passed to the backend since start.
    pub moves_sent: u64,
}

impl GripperTarget {
    /// Starts at the measured opening `width`, which becomes the target: nothing moves until a controller asks.
    pub fn new(profile: &Profile, width: f64) -> Self {
        let interval_ticks = profile.gripper_interval_ticks();
        Self {
            speed_max: profile.gripper_speed_max,
            deadband: profile.gripper_deadband,
            interval_ticks,
            sent: GripperMove { width, speed: profile.gripper_speed_max },
            pending: None,
            pending_steady_ticks: 0,
            ticks_since_sent: interval_ticks,
            moves_sent: 0,
        }
    }

    /// The width the gripper is moving to (the target the backend has).
    pub fn target(&self) -> f64 {
        self.sent.width
    }

    /// A controller's admitted target: `width` (already within the profile's range) at `speed` (m/s, ≥ 0;
    /// 0 or more than the profile's cap means the cap).
    pub fn request(&mut self, width: f64, speed: f64) {
        let speed = if speed > 0.0 { speed.min(self.speed_max) } else { self.speed_max };
        // A new speed alone is no new move: the width is what the gripper is asked for.
        if self.pending.is_none_or(|p| p.width != width) {
            self.pending_steady_ticks = 0;
        }
        self.pending = (width != self.sent.width).then_some(GripperMove { width, speed });
    }

    /// Once per tick: the move to pass to the backend now, if any.
    pub fn tick(&mut self) -> Option<GripperMove> {
        self.ticks_since_sent = self.ticks_since_sent.saturating_add(1);
        let mv = self.pending?;
        self.pending_steady_ticks += 1;
        let far = (mv.width - self.sent.width).abs() > self.deadband;
        let settled = self.pending_steady_ticks >= self.interval_ticks;
        if self.ticks_since_sent < self.interval_ticks || !(far || settled) {
            return None;
        }
        self.pending = None;
        self.sent = mv;
        self.ticks_since_sent = 0;
        self.moves_sent += 1;
        Some(mv)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn fr3() -> Profile {
        Profile::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/fr3.toml")).unwrap()
    }

    #[test]
    fn starts_at_the_measured_width_and_sends_nothing_unasked() {
        let mut g = GripperTarget::new(&fr3(), 0.031);
        assert_eq!(g.target(), 0.031);
        assert!((0..100).all(|_| g.tick().is_none()));
        // A target within the deadband of where it is going waits until it has stood still for an interval.
        let interval = fr3().gripper_interval_ticks() as usize;
        g.request(0.0315, 0.0);
        let sent_at = (0..100).position(|_| g.tick().is_some());
        assert_eq!(sent_at, Some(interval - 1));
        assert_eq!((g.moves_sent, g.target()), (1, 0.0315));
    }

    #[test]
    fn a_step_is_one_move_at_the_capped_speed() {
        let p = fr3();
        let mut g = GripperTarget::new(&p, 0.07);
        g.request(0.02, 5.0);
        assert_eq!(g.tick(), Some(GripperMove { width: 0.02, speed: p.gripper_speed_max }));
        for _ in 0..1000 {
            g.request(0.02, 0.05);
            assert_eq!(g.tick(), None, "the same target again is no new move");
        }
        assert_eq!((g.moves_sent, g.target()), (1, 0.02));
        g.request(0.05, 0.05);
        assert_eq!(g.tick(), Some(GripperMove { width: 0.05, speed: 0.05 }));
    }

    /// A controller streaming a closing ramp at 1 kHz (0.07 → 0.02 m in 0.8 s): the backend gets a move per
    /// interval at most, each beyond the deadband, and the last one is the ramp's end.
    #[test]
    fn a_streamed_ramp_becomes_a_few_moves() {
        let p = fr3();
        let mut g = GripperTarget::new(&p, 0.07);
        let mut moves = Vec::new();
        let mut last_tick = None;
        for k in 0..=1000u64 {
            let w = 0.07 - 0.05 * (k as f64 / 800.0).min(1.0);
            g.request(w, 0.0);
            if let Some(m) = g.tick() {
                if let Some(t) = last_tick {
                    assert!(k - t >= p.gripper_interval_ticks(), "moves {} ticks apart", k - t);
                }
                last_tick = Some(k);
                moves.push(m.width);
            }
        }
        assert!(moves.len() <= 800 / p.gripper_interval_ticks() as usize + 1, "{} moves", moves.len());
        assert!(moves.len() >= 10, "{} moves", moves.len());
        // Each move but the ramp's settled end is beyond the deadband from the one before.
        let steps = &moves[..moves.len() - 1];
        assert!(steps.windows(2).all(|w| (w[0] - w[1]).abs() > p.gripper_deadband), "{moves:?}");
        assert!((g.target() - 0.02).abs() < 1e-12, "the ramp's end arrives: {}", g.target());
    }
}
