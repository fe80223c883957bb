//! The HAL over ROS 2: the HAL's own absolute-deadline timer at the profile's rate (the robot publishes its
//! feedback at its own pace; each tick reads the newest), as with the sim, plus what a robot whose controllers
//! latch their last target needs:
//! - **Start**: open DDS, wait for the robot's first feedback (`[ros2] connect_timeout_s`); without it the HAL
//!   refuses to start (exit 2) and has published nothing. The first setpoint is that measurement.
//! - **Feedback lost / back**: see [`super::backend`]; when it is back, the arm is taken over again from the
//!   measured pose (at rest, within the limits, exactly as at start) before any setpoint is published again, and
//!   a controller starts a new session.
//! - **SIGTERM / the duration**: stop following and brake the setpoint to rest, publishing each step, so the
//!   robot latches a position at rest; then the I/O thread publishes what is left and closes.
//! - **Cameras**: bridged on threads of their own from the start ([`super::camera`]); their counts are logged at
//!   exit (`ROS 2 camera`).

use std::time::Duration;

use mars_rt::Ticker;
use mars_rt::overlong::Stamp;
use tracing::info;

use super::backend::Ros2Backend;
use super::io::Link;
use super::params::Ros2Params;
use crate::control::StartError;
use crate::events::LoopEvent;
use crate::runner::{HalLoop, Next, Report, RunOptions};
use mars_profile::Profile;

/// Runs the HAL on the ROS 2 robot of `profile`, over the topics and QoS of `p` (its `[ros2]` table, checked),
/// until the duration ends or a termination request (both at rest). Refuses to start (a [`StartError`], nothing
/// published) without feedback from the robot.
pub fn run(profile: &Profile, p: &Ros2Params, opts: &RunOptions) -> anyhow::Result<Report> {
    let link = Link::open(p, profile.joints, &opts.robot)?;
    info!(
        domain = p.domain_id, localhost_only = p.localhost_only, feedback = %p.arm_feedback_topic,
        target = %p.arm_target_topic, gripper = p.gripper, "ROS 2 open; waiting for the robot's feedback"
    );
    let mut backend = Ros2Backend::new(profile, p, link);
    let stop = opts.stop.clone();
    let first = backend
        .wait_first(Duration::from_secs_f64(p.connect_timeout_s), || {
            stop.as_ref().is_some_and(|s| s.load(std::sync::atomic::Ordering::Acquire))
        })
        .map_err(StartError::Read)?;
    let mut hal = HalLoop::start(profile, first, opts)?;
    let timeout_ms = p.feedback_timeout_ms(profile.command_timeout_ms);
    let mut ticker = Ticker::new(Duration::from_secs_f64(profile.period_s()));
    let mut retake_refused = false;
    let ended = loop {
        let wake = ticker.wait();
        let woke = Stamp::now();
        hal.late_us.saturating_record(wake.late_ns / 1000);
        let next = hal.tick(&mut backend, woke);
        // Rare events (a loss, a retake), logged off this thread as the loop's own are: it is the loop's thread.
        if let Some(loss) = backend.take_loss() {
            hal.log(LoopEvent::FeedbackLost { arm: loss.arm, age_ms: loss.age_ms, timeout_ms });
        }
        if let Some(m) = backend.retake_from() {
            match hal.control.resume_from(&m) {
                Ok(()) => {
                    backend.retaken();
                    retake_refused = false;
                    hal.log(LoopEvent::FeedbackBack);
                }
                Err(e) if !retake_refused => {
                    retake_refused = true;
                    hal.log(LoopEvent::RetakeRefused(e));
                }
                Err(_) => {}
            }
        }
        if let Next::End(e) = next {
            break e;
        }
    };
    let report = hal.finish(ended, ticker.missed_total(), None);
    let newest = *backend.link.newest();
    let (c, io) = (backend.counts, &backend.link.counts);
    info!(
        arm_targets = io.arm_published.load(std::sync::atomic::Ordering::Relaxed),
        gripper_targets = io.gripper_published.load(std::sync::atomic::Ordering::Relaxed),
        publish_errors = io.publish_errors.load(std::sync::atomic::Ordering::Relaxed),
        ring_full = backend.link.ring_full,
        arm_feedback = newest.arm_samples,
        gripper_feedback = newest.gripper_samples,
        bad_feedback = newest.bad_samples,
        losses = c.losses,
        stop_targets = c.stop_targets,
        retakes = c.retakes,
        "ROS 2 link"
    );
    let cameras = backend.link.cameras.clone();
    backend.link.close();
    // Counted once the camera threads have ended: none is between taking a frame and publishing it.
    for (id, counts) in &cameras {
        info!(camera = %id, "ROS 2 camera: {counts}");
    }
    Ok(report)
}
