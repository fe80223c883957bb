//! Who the HAL is following, and when it stops following: the session state machine.
//!
//! Idle → Active(s) on the first valid command of session s. Active(s) → Holding(s, timeout) when no valid
//! command arrived within the profile's timeout; → Holding(s, controller lost) when the liveness watch reports a
//! controller process gone and s has gone quiet; → Holding(s, requested) on a `Hold` command. While holding,
//! commands of session s are ignored: only a command with a *different* session id resumes, so a stream that
//! stalled and came back is never silently followed again.

use mars_ipc::HoldReason;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    Idle,
    Active { session: u64 },
    Holding { session: u64, reason: HoldReason },
}

/// What to do with a command that passed the safety filter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Decision {
    Follow,
    /// Its session already ended; it is dropped.
    StaleSession,
}

pub struct Supervisor {
    mode: Mode,
    timeout_ns: u64,
    last_valid_ns: u64,
}

impl Supervisor {
    pub fn new(timeout_ns: u64) -> Self {
        Self { mode: Mode::Idle, timeout_ns, last_valid_ns: 0 }
    }

    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// A valid command of `session` (non-zero) arrived at `now_ns`; `hold` if it asks to end the session.
    pub fn on_command(&mut self, session: u64, hold: bool, now_ns: u64) -> Decision {
        match self.mode {
            Mode::Holding { session: s, .. } if s == session => return Decision::StaleSession,
            Mode::Active { session: s } if s != session => {
                // A second controller must not take over a running session mid-stream.
                return Decision::StaleSession;
            }
            _ => {}
        }
        self.last_valid_ns = now_ns;
        self.mode = if hold {
            Mode::Holding { session, reason: HoldReason::ControllerRequested }
        } else {
            Mode::Active { session }
        };
        Decision::Follow
    }

    /// A controller's process was found dead (or closed its heartbeat) at `now_ns`: the active session ends at
    /// once, without waiting for the command timeout, unless it sent a valid command within the last
    /// `quiet_ns`. The liveness watch cannot say *which* controller died, and a dead one has been silent for at
    /// least the heartbeat deadline, so a session still commanding belongs to a live controller (e.g. one that
    /// just replaced the dead one) and is kept; if the dead one was missed this way, the command timeout still
    /// catches it. Returns true if a session was ended.
    pub fn on_controller_lost(&mut self, now_ns: u64, quiet_ns: u64) -> bool {
        if let Mode::Active { session } = self.mode
            && now_ns.saturating_sub(self.last_valid_ns) > quiet_ns
        {
            self.mode = Mode::Holding { session, reason: HoldReason::ControllerLost };
            return true;
        }
        false
    }

    /// Called once per tick; returns true when the session just timed out.
    pub fn on_tick(&mut self, now_ns: u64) -> bool {
        if let Mode::Active { session } = self.mode
            && now_ns.saturating_sub(self.last_valid_ns) > self.timeout_ns
        {
            self.mode = Mode::Holding { session, reason: HoldReason::CommandTimeout };
            return true;
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn timeout_holds_and_only_a_new_session_resumes() {
        let mut s = Supervisor::new(20 * MS);
        assert_eq!(s.mode(), Mode::Idle);
        assert_eq!(s.on_command(7, false, 0), Decision::Follow);
        assert!(!s.on_tick(20 * MS));
        assert!(s.on_tick(21 * MS));
        assert_eq!(s.mode(), Mode::Holding { session: 7, reason: HoldReason::CommandTimeout });
        assert!(!s.on_tick(100 * MS), "a timeout is reported once");
        assert_eq!(s.on_command(7, false, 22 * MS), Decision::StaleSession);
        assert_eq!(s.mode(), Mode::Holding { session: 7, reason: HoldReason::CommandTimeout });
        assert_eq!(s.on_command(8, false, 23 * MS), Decision::Follow);
        assert_eq!(s.mode(), Mode::Active { session: 8 });
    }

    #[test]
    fn a_lost_controller_ends_its_session_and_only_a_new_one_resumes() {
        let mut s = Supervisor::new(20 * MS);
        assert!(!s.on_controller_lost(MS, 2 * MS), "nothing to end while idle");
        s.on_command(4, false, 10 * MS);
        assert!(!s.on_controller_lost(11 * MS, 2 * MS), "a session that is still commanding has a live controller");
        assert_eq!(s.mode(), Mode::Active { session: 4 });
        assert!(s.on_controller_lost(13 * MS, 2 * MS));
        assert_eq!(s.mode(), Mode::Holding { session: 4, reason: HoldReason::ControllerLost });
        assert!(!s.on_controller_lost(14 * MS, 2 * MS));
        assert_eq!(s.on_command(4, false, MS), Decision::StaleSession);
        assert_eq!(s.on_command(5, false, MS), Decision::Follow);
    }

    #[test]
    fn a_second_controller_cannot_hijack_and_hold_ends_a_session() {
        let mut s = Supervisor::new(20 * MS);
        s.on_command(1, false, 0);
        assert_eq!(s.on_command(2, false, MS), Decision::StaleSession);
        assert_eq!(s.on_command(1, true, 2 * MS), Decision::Follow);
        assert_eq!(s.mode(), Mode::Holding { session: 1, reason: HoldReason::ControllerRequested });
        assert_eq!(s.on_command(1, false, 3 * MS), Decision::StaleSession);
    }
}
