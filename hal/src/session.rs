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

/// The clock the [`Supervisor`] judges silence by: the HAL loop's own running time. It advances by the time
/// between two ticks, but by at most `max_step_ns` per tick, so a stall of the HAL's loop itself (a VM that
/// froze both processes, a page fault) does not count as silence of the controller: after such a stall the
/// controller gets its ticks to answer, as a robot counts lost packets in its own cycles (libfranka's
/// "communication constraints" reflex is 20 lost cycles, not 20 ms of wall time).
#[derive(Debug, Clone, Copy)]
pub struct LoopClock {
    last_wall_ns: Option<u64>,
    now_ns: u64,
    max_step_ns: u64,
}

impl LoopClock {
    pub fn new(max_step_ns: u64) -> Self {
        Self { last_wall_ns: None, now_ns: 0, max_step_ns }
    }

    /// Advance to this tick's wall time; returns the loop time.
    pub fn tick(&mut self, wall_ns: u64) -> u64 {
        if let Some(last) = self.last_wall_ns {
            self.now_ns += wall_ns.saturating_sub(last).min(self.max_step_ns);
        }
        self.last_wall_ns = Some(wall_ns);
        self.now_ns
    }
}

pub struct Supervisor {
    mode: Mode,
    timeout_ns: u64,
    last_valid_ns: u64,
    /// A controller's death reported while the session was still commanding, not yet judged.
    loss: Option<Loss>,
}

#[derive(Debug, Clone, Copy)]
struct Loss {
    at_ns: u64,
    quiet_ns: u64,
}

impl Supervisor {
    pub fn new(timeout_ns: u64) -> Self {
        Self { mode: Mode::Idle, timeout_ns, last_valid_ns: 0, loss: None }
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

    /// A controller's process was found dead (or closed its heartbeat) at `now_ns`: the active session ends as
    /// soon as it has sent no valid command for `quiet_ns`, without waiting for the command timeout. The liveness
    /// watch cannot say *which* controller died, and it may say so a millisecond after the death (the kernel's
    /// word, by pidfd), while the dead controller's last command is still fresh. So the loss is kept and judged
    /// again each tick ([`Self::on_tick_after_loss`]): a session that goes quiet ends; one that still commands
    /// `quiet_ns` after the loss belongs to a live controller (e.g. one that just replaced the dead one) and is
    /// kept, the loss forgotten; if the dead one was missed this way, the command timeout still catches it.
    /// Returns true if a session was ended.
    pub fn on_controller_lost(&mut self, now_ns: u64, quiet_ns: u64) -> bool {
        if matches!(self.mode, Mode::Active { .. }) {
            self.loss = Some(Loss { at_ns: now_ns, quiet_ns });
        }
        self.on_tick_after_loss(now_ns)
    }

    /// Judges a loss still open (see [`Self::on_controller_lost`]); called once per tick. Returns true if it
    /// ended the session now.
    pub fn on_tick_after_loss(&mut self, now_ns: u64) -> bool {
        let (Some(loss), Mode::Active { session }) = (self.loss, self.mode) else {
            self.loss = None;
            return false;
        };
        if now_ns.saturating_sub(self.last_valid_ns) > loss.quiet_ns {
            self.mode = Mode::Holding { session, reason: HoldReason::ControllerLost };
            self.loss = None;
            return true;
        }
        if self.last_valid_ns > loss.at_ns + loss.quiet_ns {
            self.loss = None;
        }
        false
    }

    /// An error of the HAL itself (its backend or its ports): the active session ends at once, braking to rest
    /// and holding with [`HoldReason::HalError`]; a new session resumes as after any hold. Returns true if a
    /// session was ended.
    pub fn on_hal_error(&mut self) -> bool {
        if let Mode::Active { session } = self.mode {
            self.mode = Mode::Holding { session, reason: HoldReason::HalError };
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
    #[test]
    fn the_loop_clock_counts_a_stall_of_the_loop_as_one_step() {
        let mut c = LoopClock::new(2_000_000);
        assert_eq!(c.tick(100_000_000), 0);
        assert_eq!(c.tick(101_000_000), 1_000_000);
        // The loop itself was stalled for 50 ms: the controller was not silent for 50 ms of the HAL's time.
        assert_eq!(c.tick(151_000_000), 3_000_000);
        assert_eq!(c.tick(152_000_000), 4_000_000);
        // So a 20 ms command timeout judged on it does not fire across the stall…
        let mut sup = Supervisor::new(20_000_000);
        let mut c = LoopClock::new(2_000_000);
        sup.on_command(1, false, c.tick(0));
        assert!(!sup.on_tick(c.tick(50_000_000)));
        // …but does after 20 ms of the loop's ticks without a command.
        let fired = (1..=30).map(|k| sup.on_tick(c.tick(50_000_000 + k * 1_000_000))).position(|f| f);
        assert_eq!(fired, Some(18), "2 ms for the stall + 19 ticks of 1 ms > 20 ms");
    }

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
    fn a_loss_reported_while_the_session_commands_ends_it_once_it_goes_quiet() {
        let mut s = Supervisor::new(20 * MS);
        s.on_command(4, false, 10 * MS);
        // The kernel's word of the death came before the dead controller's last command went stale.
        assert!(!s.on_controller_lost(10 * MS + MS / 2, 2 * MS));
        assert!(!s.on_tick_after_loss(11 * MS));
        assert!(!s.on_tick_after_loss(12 * MS));
        assert!(s.on_tick_after_loss(12 * MS + 1), "quiet for more than 2 ms after the loss: ended");
        assert_eq!(s.mode(), Mode::Holding { session: 4, reason: HoldReason::ControllerLost });
        assert!(!s.on_tick_after_loss(13 * MS), "ended once");
    }

    #[test]
    fn a_loss_is_forgotten_when_the_session_commands_on_past_the_quiet_time() {
        let mut s = Supervisor::new(20 * MS);
        s.on_command(4, false, 10 * MS);
        assert!(!s.on_controller_lost(10 * MS, 2 * MS));
        for t in 11..=13 {
            s.on_command(4, false, t * MS);
            assert!(!s.on_tick_after_loss(t * MS));
        }
        // Commanding 3 ms after the loss: a live controller's session. A later pause is no loss.
        assert!(!s.on_tick_after_loss(16 * MS));
        assert_eq!(s.mode(), Mode::Active { session: 4 });
    }

    #[test]
    fn a_hal_error_ends_the_session_and_a_new_one_resumes() {
        let mut s = Supervisor::new(20 * MS);
        assert!(!s.on_hal_error(), "nothing to end while idle");
        s.on_command(3, false, 0);
        assert!(s.on_hal_error());
        assert_eq!(s.mode(), Mode::Holding { session: 3, reason: HoldReason::HalError });
        assert!(!s.on_hal_error(), "reported once");
        assert_eq!(s.on_command(3, false, MS), Decision::StaleSession);
        assert_eq!(s.on_command(4, false, MS), Decision::Follow);
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
