//! Which state frames the controller may act on. A refused frame is counted and ignored: the smoother keeps
//! running from its own state, and the watchdog trips if no usable frame arrives for too long.

use mars_ipc::RobotState;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// `num_joints` differs from the profile's.
    WrongDof,
    /// A NaN or infinite position, velocity or gripper value.
    NonFinite,
    /// The HAL flagged a sensor fault (frozen or NaN sensor, non-finite measurement).
    SensorFault,
    /// Older than the configured limit when read.
    Stale,
    /// Not newer than the last frame used (a replay or a restarted HAL's old frame).
    OutOfOrder,
}

impl Refusal {
    /// Refused for what the frame says (its measurements or shape), not for when it came.
    pub fn is_content(self) -> bool {
        matches!(self, Self::WrongDof | Self::NonFinite | Self::SensorFault)
    }
}

/// Counts of refused frames, by reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct FrameCounts {
    pub used: u64,
    pub wrong_dof: u64,
    pub non_finite: u64,
    pub sensor_fault: u64,
    pub stale: u64,
    pub out_of_order: u64,
}

impl FrameCounts {
    pub fn refused(&self) -> u64 {
        self.wrong_dof + self.non_finite + self.sensor_fault + self.stale + self.out_of_order
    }
}

pub struct FrameCheck {
    joints: usize,
    max_age_ns: u64,
    last_seq: u64,
    pub counts: FrameCounts,
}

impl FrameCheck {
    pub fn new(joints: usize, max_age_ns: u64) -> Self {
        Self { joints, max_age_ns, last_seq: 0, counts: FrameCounts::default() }
    }

    /// Judges `s`, read at `now_ns` (same clock as the HAL's stamp), and counts the verdict.
    pub fn judge(&mut self, s: &RobotState, now_ns: u64) -> Result<(), Refusal> {
        let verdict = self.verdict(s, now_ns);
        let c = &mut self.counts;
        match verdict {
            Ok(()) => {
                c.used += 1;
                self.last_seq = s.seq;
            }
            Err(Refusal::WrongDof) => c.wrong_dof += 1,
            Err(Refusal::NonFinite) => c.non_finite += 1,
            Err(Refusal::SensorFault) => c.sensor_fault += 1,
            Err(Refusal::Stale) => c.stale += 1,
            Err(Refusal::OutOfOrder) => c.out_of_order += 1,
        }
        verdict
    }

    fn verdict(&self, s: &RobotState, now_ns: u64) -> Result<(), Refusal> {
        let n = self.joints;
        if s.num_joints as usize != n {
            return Err(Refusal::WrongDof);
        }
        let values = s.position[..n].iter().chain(&s.velocity[..n]).chain(std::iter::once(&s.gripper));
        if values.clone().any(|v| !v.is_finite()) {
            return Err(Refusal::NonFinite);
        }
        if s.fault != 0 {
            return Err(Refusal::SensorFault);
        }
        if s.seq <= self.last_seq {
            return Err(Refusal::OutOfOrder);
        }
        if now_ns.saturating_sub(s.timestamp_ns) > self.max_age_ns {
            return Err(Refusal::Stale);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(seq: u64, t: u64) -> RobotState {
        RobotState { seq, timestamp_ns: t, num_joints: 7, ..Default::default() }
    }

    #[test]
    fn each_kind_of_bad_frame_is_refused_and_counted() {
        let mut c = FrameCheck::new(7, 3_000_000);
        assert_eq!(c.judge(&frame(1, 1_000_000), 2_000_000), Ok(()));
        assert_eq!(c.judge(&RobotState { num_joints: 6, ..frame(2, 2_000_000) }, 2_000_000), Err(Refusal::WrongDof));
        let mut nan = frame(3, 2_000_000);
        nan.position[3] = f64::NAN;
        assert_eq!(c.judge(&nan, 2_000_000), Err(Refusal::NonFinite));
        let mut inf = frame(3, 2_000_000);
        inf.gripper = f64::INFINITY;
        assert_eq!(c.judge(&inf, 2_000_000), Err(Refusal::NonFinite));
        let faulty = RobotState { fault: mars_ipc::fault::FROZEN_SENSOR, ..frame(4, 2_000_000) };
        assert_eq!(c.judge(&faulty, 2_000_000), Err(Refusal::SensorFault));
        assert_eq!(c.judge(&frame(1, 2_000_000), 2_000_000), Err(Refusal::OutOfOrder));
        assert_eq!(c.judge(&frame(5, 1_000_000), 5_000_000), Err(Refusal::Stale));
        assert_eq!(c.judge(&frame(6, 5_000_000), 5_000_000), Ok(()));
        let n = c.counts;
        assert_eq!((n.used, n.wrong_dof, n.non_finite, n.sensor_fault, n.stale, n.out_of_order), (2, 1, 2, 1, 1, 1));
        assert_eq!(n.refused(), 6);
    }
}
