//! The R1 Lite as a [`Backend`]: `read` is the newest feedback the I/O thread took, `apply` publishes the
//! filtered setpoint as the arm's target, `move_gripper` the gripper's.
//!
//! The robot's controllers *latch* the last target they got: going quiet does not stop the arm, a target does.
//! So the backend always says where the arm is to stop:
//! - **Commands stop** (the controller's timeout, a hold, a lost controller, the HAL exiting): the HAL's safety
//!   filter brakes the setpoint to rest within the limits and holds it there, and every one of those setpoints
//!   is published, one per tick, never silence: the last target the robot latched is always a position at rest.
//! - **Feedback stops** (nothing newer than the feedback timeout): `read` fails (a transient error: the HAL holds,
//!   flags its frame `BACKEND_ERROR` / `NO_MEASUREMENT` and logs it), and instead of the filter's setpoint, which
//!   no measurement backs any more, the backend publishes the explicit stop: the arm's last measured position,
//!   [`STOP_REPEATS`] times (the robot's subscribers are BEST_EFFORT: one sample may be lost). Then nothing: a
//!   stale position is no target for an arm nobody can see. The gripper is not commanded meanwhile.
//! - **Feedback returns**: the backend publishes the measured position as the target (the arm holds where it is)
//!   until the driver has taken the arm over again from that measurement (see [`super::drive`]), as at start:
//!   the filter restarts there, so no setpoint computed blind ever reaches the robot.
//!
//! The gripper's topic carries a position on its own scale (the R1 Lite's stroke, 0–100 mm): the profile's
//! opening `[gripper_min, gripper_max]` maps linearly onto `[0, gripper_stroke_max]`. A gripper target is published
//! when it changes and repeated every gripper interval, so a lost BEST_EFFORT sample is made good.

use std::time::Duration;

use mars_ipc::MAX_JOINTS;
use mars_rt::monotonic_ns;

use super::io::{Link, Newest, Target};
use super::params::Ros2Params;
use crate::backend::{Backend, BackendError, Measurement};
use crate::gripper::GripperMove;
use mars_profile::Profile;

/// How many ticks the stop target is published after the feedback stopped.
pub const STOP_REPEATS: u32 = 5;

const NO_FEEDBACK_YET: BackendError = BackendError::Transient("no feedback from the robot yet");
const ARM_FEEDBACK_STALE: BackendError = BackendError::Transient(
    "no arm feedback from the robot within the feedback timeout: holding, the stop target (its last measured \
     position) published, no motion",
);
const GRIPPER_FEEDBACK_STALE: BackendError = BackendError::Transient(
    "no gripper feedback from the robot within the feedback timeout: holding, the stop target (the arm's last \
     measured position) published, no motion",
);
const NOT_COMMANDING: BackendError =
    BackendError::Transient("the gripper is not commanded without fresh feedback from the robot");
const NO_GRIPPER: BackendError = BackendError::Transient("no gripper: [ros2] gripper = false");

/// What the backend publishes in `apply`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Publishing {
    /// The HAL's filtered setpoint.
    Setpoint,
    /// The feedback stopped: the last measured position, `left` more times, then nothing.
    Stop { left: u32 },
    /// The feedback came back: the measured position, until the driver re-took the arm ([`Ros2Backend::retaken`]).
    Retake,
}

/// The profile's gripper opening ↔ the topic's scale.
#[derive(Debug, Clone, Copy)]
struct GripperScale {
    min: f64,
    max: f64,
    stroke_max: f64,
}

impl GripperScale {
    fn width(&self, stroke: f64) -> f64 {
        self.min + stroke / self.stroke_max * (self.max - self.min)
    }

    fn stroke(&self, width: f64) -> f64 {
        (width - self.min) / (self.max - self.min) * self.stroke_max
    }
}

/// A feedback loss the driver has not logged yet.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Loss {
    /// How old the newest feedback was when it was found stale (ms).
    pub age_ms: f64,
    pub arm: bool,
}

/// What the backend counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Ros2Counts {
    /// Times the feedback went stale.
    pub losses: u64,
    pub stop_targets: u64,
    pub retakes: u64,
}

pub struct Ros2Backend {
    pub link: Link,
    n: usize,
    timeout_ns: u64,
    gripper: Option<GripperScale>,
    gripper_min: f64,
    /// The last measurement read from fresh feedback.
    last: Option<Measurement>,
    publishing: Publishing,
    /// The gripper's last target (on the topic's scale) and ticks since it was published.
    gripper_target: Option<f64>,
    gripper_repeat_ticks: u64,
    ticks_since_gripper: u64,
    loss: Option<Loss>,
    pub counts: Ros2Counts,
}

impl Ros2Backend {
    pub fn new(profile: &Profile, p: &Ros2Params, link: Link) -> Self {
        let timeout_ms = p.feedback_timeout_ms(profile.command_timeout_ms);
        Self {
            link,
            n: profile.joints,
            timeout_ns: (timeout_ms * 1e6) as u64,
            gripper: p.gripper.then_some(GripperScale {
                min: profile.gripper_min,
                max: profile.gripper_max,
                stroke_max: p.gripper_stroke_max,
            }),
            gripper_min: profile.gripper_min,
            last: None,
            publishing: Publishing::Setpoint,
            gripper_target: None,
            gripper_repeat_ticks: profile.gripper_interval_ticks(),
            ticks_since_gripper: 0,
            loss: None,
            counts: Ros2Counts::default(),
        }
    }

    /// Waits (at most `timeout`, checking `stop` meanwhile) for fresh feedback of the arm (and the gripper, when
    /// driven): the measurement the HAL starts from. Nothing is published.
    pub fn wait_first(&mut self, timeout: Duration, stop: impl Fn() -> bool) -> Result<Measurement, BackendError> {
        let end = std::time::Instant::now() + timeout;
        loop {
            if let Ok(m) = self.measure(monotonic_ns()) {
                self.last = Some(m);
                return Ok(m);
            }
            if std::time::Instant::now() >= end || stop() {
                return Err(NO_FEEDBACK_YET);
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// The newest feedback as a measurement, or why there is none that is fresh at `now_ns`.
    fn measure(&mut self, now_ns: u64) -> Result<Measurement, (BackendError, f64)> {
        let newest: Newest = *self.link.newest();
        let Some(arm) = newest.arm else { return Err((NO_FEEDBACK_YET, f64::INFINITY)) };
        // The I/O thread may have taken a sample after `now_ns` was read: its age is then 0.
        let arm_age = now_ns.saturating_sub(arm.received_ns);
        if arm_age > self.timeout_ns {
            return Err((ARM_FEEDBACK_STALE, arm_age as f64 * 1e-6));
        }
        let mut m = Measurement {
            position: arm.position,
            velocity: arm.velocity,
            effort: arm.effort,
            gripper: self.gripper_min,
            ..Default::default()
        };
        if let Some(scale) = self.gripper {
            let Some(g) = newest.gripper else { return Err((NO_FEEDBACK_YET, f64::INFINITY)) };
            let age = now_ns.saturating_sub(g.received_ns);
            if age > self.timeout_ns {
                return Err((GRIPPER_FEEDBACK_STALE, age as f64 * 1e-6));
            }
            m.gripper = scale.width(g.stroke);
        }
        Ok(m)
    }

    /// What `apply` publishes now.
    pub fn publishing(&self) -> Publishing {
        self.publishing
    }

    /// The feedback came back and the arm has not been taken over again yet: the measurement to take it from.
    pub fn retake_from(&self) -> Option<Measurement> {
        (self.publishing == Publishing::Retake).then_some(self.last).flatten()
    }

    /// The driver took the arm over from [`Self::retake_from`]'s measurement: the setpoint is published again.
    pub fn retaken(&mut self) {
        self.publishing = Publishing::Setpoint;
        // The HAL's gripper target restarts at the measured opening too: nothing is repeated until it asks.
        self.gripper_target = None;
        self.counts.retakes += 1;
    }

    /// A feedback loss not reported yet (once per loss).
    pub fn take_loss(&mut self) -> Option<Loss> {
        self.loss.take()
    }

    fn publish_arm(&mut self, q: &[f64]) -> Result<(), BackendError> {
        let mut target = [0.0; MAX_JOINTS];
        target[..self.n].copy_from_slice(&q[..self.n]);
        if self.link.send(Target::Arm(target)) {
            Ok(())
        } else {
            Err(BackendError::Transient("the ROS 2 I/O thread fell behind: a target was not published"))
        }
    }
}

impl Backend for Ros2Backend {
    fn read(&mut self) -> Result<Measurement, BackendError> {
        match self.measure(monotonic_ns()) {
            Ok(m) => {
                self.last = Some(m);
                if let Publishing::Stop { .. } = self.publishing {
                    self.publishing = Publishing::Retake;
                }
                Ok(m)
            }
            Err((e, age_ms)) => {
                if !matches!(self.publishing, Publishing::Stop { .. }) {
                    self.publishing = Publishing::Stop { left: STOP_REPEATS };
                    self.counts.losses += 1;
                    self.loss = Some(Loss { age_ms, arm: e == ARM_FEEDBACK_STALE });
                }
                Err(e)
            }
        }
    }

    fn apply(&mut self, position: &[f64]) -> Result<(), BackendError> {
        self.ticks_since_gripper = self.ticks_since_gripper.saturating_add(1);
        match self.publishing {
            Publishing::Setpoint => {
                self.publish_arm(position)?;
                if let Some(stroke) = self.gripper_target
                    && self.ticks_since_gripper >= self.gripper_repeat_ticks
                {
                    self.ticks_since_gripper = 0;
                    self.link.send(Target::Gripper(stroke));
                }
                Ok(())
            }
            Publishing::Stop { left } => {
                let Some(last) = self.last else { return Ok(()) };
                if left > 0 {
                    self.publishing = Publishing::Stop { left: left - 1 };
                    self.counts.stop_targets += 1;
                    self.publish_arm(&last.position)?;
                }
                Ok(())
            }
            Publishing::Retake => match self.last {
                Some(last) => self.publish_arm(&last.position),
                None => Ok(()),
            },
        }
    }

    fn move_gripper(&mut self, to: GripperMove) -> Result<(), BackendError> {
        let Some(scale) = self.gripper else { return Err(NO_GRIPPER) };
        if self.publishing != Publishing::Setpoint {
            return Err(NOT_COMMANDING);
        }
        let stroke = scale.stroke(to.width);
        self.gripper_target = Some(stroke);
        self.ticks_since_gripper = 0;
        if self.link.send(Target::Gripper(stroke)) {
            Ok(())
        } else {
            Err(BackendError::Transient("the ROS 2 I/O thread fell behind: a gripper target was not published"))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gripper_scale_maps_the_profile_s_opening_onto_the_stroke() {
        let s = GripperScale { min: 0.0, max: 0.1, stroke_max: 100.0 };
        assert!((s.stroke(0.1) - 100.0).abs() < 1e-12 && s.stroke(0.0) == 0.0);
        assert!((s.width(55.0) - 0.055).abs() < 1e-12);
        assert!((s.width(s.stroke(0.0314)) - 0.0314).abs() < 1e-15);
    }
}
