//! Did each command reach the HAL before its next tick? The servo ticks 300 µs after the HAL's frame; a tick
//! that finishes after the HAL's next tick is no whole skipped period (not an overrun), yet the HAL had to hold
//! or smooth that tick without it. marsd sees it in the frames that follow: the first frame newer than the one
//! a command answered must show that command (or a later one) in `last_command_seq`.

use mars_ipc::{RobotState, status};

#[derive(Debug, Clone, Copy, Default)]
pub struct CommandTimeliness {
    /// (state frame seq, command seq) of the first command sent answering that frame, not yet judged.
    awaiting: Option<(u64, u64)>,
    late: u64,
}

impl CommandTimeliness {
    /// A command `cmd_seq` was sent answering frame `state_seq`. Only the first command per frame is judged
    /// (a second tick on the same frame answers the same HAL tick).
    pub fn sent(&mut self, state_seq: u64, cmd_seq: u64) {
        if self.awaiting.is_none_or(|(frame, _)| state_seq > frame) {
            self.awaiting = Some((state_seq, cmd_seq));
        }
    }

    /// Every frame received, in order (not only the newest of a tick: after a stall the first newer frame is
    /// the HAL tick that needed the command). Frames of other sessions, or while the HAL is not following
    /// this one, say nothing about its commands and are skipped.
    pub fn frame(&mut self, f: &RobotState, session: u64) {
        let Some((frame, cmd)) = self.awaiting else { return };
        if f.seq <= frame {
            return;
        }
        self.awaiting = None;
        if f.session == session && f.is(status::ACTIVE) && f.last_command_seq < cmd {
            self.late += 1;
        }
    }

    /// Commands that reached the HAL after the tick that needed them.
    pub fn late(&self) -> u64 {
        self.late
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SESSION: u64 = 7;

    fn frame(seq: u64, last_command_seq: u64) -> RobotState {
        RobotState { seq, last_command_seq, session: SESSION, status: status::ACTIVE, ..Default::default() }
    }

    #[test]
    fn a_command_missing_from_the_next_frame_was_late() {
        let mut t = CommandTimeliness::default();
        t.sent(10, 1);
        t.frame(&frame(11, 1), SESSION); // applied in time
        t.sent(11, 2);
        t.frame(&frame(12, 1), SESSION); // the HAL's tick 12 still had command 1: late
        t.frame(&frame(13, 2), SESSION); // already judged
        assert_eq!(t.late(), 1);
    }

    #[test]
    fn after_a_stall_the_first_newer_frame_decides_not_the_newest() {
        let mut t = CommandTimeliness::default();
        t.sent(20, 5);
        // The servo read frames 21 and 22 in one tick: 21 lacked the command, 22 had it.
        t.frame(&frame(21, 4), SESSION);
        t.frame(&frame(22, 5), SESSION);
        assert_eq!(t.late(), 1);
    }

    #[test]
    fn a_second_command_on_the_same_frame_does_not_move_the_bar() {
        let mut t = CommandTimeliness::default();
        t.sent(30, 8);
        t.sent(30, 9); // no new frame this tick: answers the same HAL tick
        t.frame(&frame(31, 8), SESSION);
        assert_eq!(t.late(), 0);
    }

    #[test]
    fn frames_not_following_this_session_are_not_judged() {
        let mut t = CommandTimeliness::default();
        t.sent(40, 1);
        let mut holding = frame(41, 0);
        holding.status = status::HOLDING;
        t.frame(&holding, SESSION);
        t.sent(41, 2);
        t.frame(&RobotState { session: 99, ..frame(42, 0) }, SESSION);
        assert_eq!(t.late(), 0);
    }
}
