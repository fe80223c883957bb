//! The `[ros2]` table of a profile: which DDS domain and topics the robot speaks on, with which QoS, and how
//! long its feedback may be silent. The profile keeps the table as TOML; this driver reads it ([`Ros2Params::of`])
//! and checks it against the profile ([`Ros2Params::check`]).

use mars_profile::{Profile, ProfileError};
use serde::Deserialize;

/// A topic's DDS reliability.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Reliability {
    /// Lost samples are resent (to reliable readers; a best-effort reader matches it and gets no resends).
    Reliable,
    /// Lost samples stay lost: for a stream where only the newest sample counts.
    BestEffort,
}

/// One of the robot's cameras (`[[ros2.cameras]]`): a `sensor_msgs/CompressedImage` (JPEG) topic, bridged to our
/// image frames on `mars/<robot>/camera/<id>` (the HAL's `ros2::camera`).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraParams {
    /// Our name for it: the image service is `mars/<robot>/camera/<id>`.
    pub id: String,
    /// The robot's topic (absolute ROS name).
    pub topic: String,
    /// The size the camera sends (px); a frame of another size is refused and counted, never resized.
    pub width: u32,
    pub height: u32,
}

/// The largest camera side accepted (px): also the decoder's bound, so a corrupt header cannot make it allocate
/// for a gigapixel image.
pub const MAX_CAMERA_SIDE: u32 = 8192;

/// The most cameras one profile bridges.
pub const MAX_CAMERAS: usize = 16;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Ros2Params {
    /// The DDS domain (ROS_DOMAIN_ID), 0–232; `mars-hal --ros-domain-id` overrides it.
    pub domain_id: u16,
    /// Discover and talk only over this host's loopback (ROS_LOCALHOST_ONLY's meaning): for a robot simulated on
    /// the same machine, and the tests. `mars-hal --ros-localhost-only` sets it.
    pub localhost_only: bool,
    /// ROS topic names (absolute; the DDS topic is `rt` + the name, as rmw maps it).
    pub arm_feedback_topic: String,
    pub arm_target_topic: String,
    pub gripper_feedback_topic: String,
    pub gripper_target_topic: String,
    /// Joint names the targets carry (`JointState.name`); one per profile joint.
    pub joint_names: Vec<String>,
    /// Drive the gripper topics (false: no gripper; its opening reads `gripper_min`, targets are refused).
    pub gripper: bool,
    /// The gripper topics' position at the profile's `gripper_max` opening (0 is `gripper_min`, linear between).
    pub gripper_stroke_max: f64,
    /// Feedback older than this (ms) is a fault: the HAL holds and publishes no motion. Default: the profile's
    /// `command_timeout_ms`.
    pub feedback_timeout_ms: Option<f64>,
    /// How long to wait at start for the robot's first feedback (s); nothing is published before it.
    pub connect_timeout_s: f64,
    pub target_reliability: Reliability,
    pub feedback_reliability: Reliability,
    /// The cameras to bridge (none: no camera thread runs).
    pub cameras: Vec<CameraParams>,
}

impl Default for Ros2Params {
    fn default() -> Self {
        Self {
            domain_id: 0,
            localhost_only: false,
            arm_feedback_topic: "/hdas/feedback_arm_right".into(),
            arm_target_topic: "/motion_target/target_joint_state_arm_right".into(),
            gripper_feedback_topic: "/hdas/feedback_gripper_right".into(),
            gripper_target_topic: "/motion_target/target_position_gripper_right".into(),
            // Galaxea's R1 Lite URDF.
            joint_names: (1..=6).map(|i| format!("right_arm_joint{i}")).collect(),
            gripper: true,
            gripper_stroke_max: 100.0,
            feedback_timeout_ms: None,
            connect_timeout_s: 10.0,
            // The public R1 Lite drivers publish targets RELIABLE (the robot's subscribers are BEST_EFFORT, so
            // nothing is resent in practice; a reliable writer matches either kind of reader).
            target_reliability: Reliability::Reliable,
            // Only the newest feedback counts, and a best-effort reader matches either kind of writer.
            feedback_reliability: Reliability::BestEffort,
            // Galaxea's R1 Lite docs: the head's left camera (1280×720) and the right wrist's (640×360), JPEG.
            cameras: vec![
                CameraParams {
                    id: "head_left".into(),
                    topic: "/hdas/camera_head/left_raw/image_raw_color/compressed".into(),
                    width: 1280,
                    height: 720,
                },
                CameraParams {
                    id: "wrist_right".into(),
                    topic: "/hdas/camera_wrist_right/color/image_raw/compressed".into(),
                    width: 640,
                    height: 360,
                },
            ],
        }
    }
}

impl Ros2Params {
    /// The profile's `[ros2]` table (the defaults for what it leaves out), not yet checked: `mars-hal`'s options
    /// may override it first.
    pub fn of(profile: &Profile) -> Result<Self, ProfileError> {
        profile.driver_table("ros2", &profile.ros2)
    }

    /// Whether these settings can drive the robot of `profile` (its joints, rate and command timeout). Called before
    /// anything moves.
    pub fn check(&self, profile: &Profile) -> Result<(), ProfileError> {
        let (joints, rate, timeout) = (profile.joints, profile.rate_hz, profile.command_timeout_ms);
        self.validate(joints, rate, timeout).map_err(|msg| profile.invalid(format!("ros2.{msg}")))
    }

    /// The feedback timeout (ms) for a profile whose command timeout is `command_timeout_ms`.
    pub fn feedback_timeout_ms(&self, command_timeout_ms: f64) -> f64 {
        self.feedback_timeout_ms.unwrap_or(command_timeout_ms)
    }

    /// Checks the table for a profile of `joints` joints at `rate_hz`.
    fn validate(&self, joints: usize, rate_hz: f64, command_timeout_ms: f64) -> Result<(), String> {
        // RTPS's port mapping (7400 + 250 × domain + …) leaves room for domains 0–232 only.
        if self.domain_id > 232 {
            return Err(format!("domain_id = {} must be in 0..=232 (RTPS's port range)", self.domain_id));
        }
        for (field, topic) in [
            ("arm_feedback_topic", &self.arm_feedback_topic),
            ("arm_target_topic", &self.arm_target_topic),
            ("gripper_feedback_topic", &self.gripper_feedback_topic),
            ("gripper_target_topic", &self.gripper_target_topic),
        ] {
            if let Err(why) = check_ros_name(topic) {
                return Err(format!("{field} = {topic:?}: {why}"));
            }
        }
        if self.cameras.len() > MAX_CAMERAS {
            return Err(format!(
                "{} cameras: at most {MAX_CAMERAS} (each has a thread of its own)",
                self.cameras.len()
            ));
        }
        for (i, c) in self.cameras.iter().enumerate() {
            if let Err(e) = mars_ipc::RobotNamespace::new("r").and_then(|ns| ns.camera(&c.id).map(|_| ())) {
                return Err(format!("cameras[{i}].id = {:?}: {e}", c.id));
            }
            if self.cameras[..i].iter().any(|o| o.id == c.id) {
                return Err(format!("cameras[{i}].id = {:?} names two cameras", c.id));
            }
            if let Err(why) = check_ros_name(&c.topic) {
                return Err(format!("cameras[{i}].topic = {:?}: {why}", c.topic));
            }
            if !(1..=MAX_CAMERA_SIDE).contains(&c.width) || !(1..=MAX_CAMERA_SIDE).contains(&c.height) {
                return Err(format!(
                    "cameras[{i}] is {}×{} px: each side must be in 1..={MAX_CAMERA_SIDE}",
                    c.width, c.height
                ));
            }
        }
        if self.joint_names.len() != joints {
            return Err(format!("joint_names has {} names but the robot has {joints} joints", self.joint_names.len()));
        }
        if !(self.gripper_stroke_max.is_finite() && self.gripper_stroke_max > 0.0) {
            return Err(format!("gripper_stroke_max = {} must be a positive number", self.gripper_stroke_max));
        }
        let period_ms = 1e3 / rate_hz;
        let timeout = self.feedback_timeout_ms(command_timeout_ms);
        let max = mars_profile::MAX_TIMEOUT_MS;
        if !(timeout.is_finite() && timeout >= 2.0 * period_ms && timeout <= max) {
            return Err(format!(
                "feedback_timeout_ms = {timeout} must be at least two feedback periods ({:.3} ms) and at most {max} ms",
                2.0 * period_ms
            ));
        }
        if !(self.connect_timeout_s.is_finite() && self.connect_timeout_s > 0.0 && self.connect_timeout_s <= 600.0) {
            return Err(format!("connect_timeout_s = {} must be in (0, 600] s", self.connect_timeout_s));
        }
        Ok(())
    }
}

/// Whether `name` is an absolute ROS topic name: `/` then tokens of ASCII letters, digits and `_`, separated by
/// single `/`s, no token starting with a digit, no `__`, no trailing `/` (ROS 2's name rules, the part that
/// applies to a fully qualified name).
pub fn check_ros_name(name: &str) -> Result<(), &'static str> {
    let Some(rest) = name.strip_prefix('/') else {
        return Err("a ROS topic name here must be absolute (start with /)");
    };
    if rest.is_empty() {
        return Err("an empty topic name");
    }
    for token in rest.split('/') {
        if token.is_empty() {
            return Err("an empty token (// or a trailing /)");
        }
        if !token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err("only ASCII letters, digits, _ and / are allowed");
        }
        if token.starts_with(|c: char| c.is_ascii_digit()) {
            return Err("a token may not start with a digit");
        }
        if token.contains("__") {
            return Err("a name may not contain __");
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    #[test]
    fn the_r1_lite_topics_are_valid_ros_names_and_malformed_ones_are_not() {
        for t in ["/hdas/feedback_arm_right", "/motion_target/target_position_gripper_right"] {
            assert_eq!(check_ros_name(t), Ok(()), "{t}");
        }
        for bad in ["hdas/x", "/", "/a//b", "/a/", "/a-b", "/1a", "/a__b"] {
            assert!(check_ros_name(bad).is_err(), "{bad}");
        }
    }

    fn r1_lite() -> Profile {
        Profile::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/r1_lite.toml")).unwrap()
    }

    #[test]
    fn the_r1_lite_profile_s_table_is_valid_and_names_the_r1_lite_s_topics() {
        let p = r1_lite();
        let r = Ros2Params::of(&p).unwrap();
        r.check(&p).unwrap();
        let (r, d) = (&r, Ros2Params::default());
        assert_eq!(
            [&r.arm_feedback_topic, &r.arm_target_topic, &r.gripper_feedback_topic, &r.gripper_target_topic],
            [&d.arm_feedback_topic, &d.arm_target_topic, &d.gripper_feedback_topic, &d.gripper_target_topic]
        );
        assert_eq!(r.joint_names, d.joint_names);
        assert_eq!(r.cameras, d.cameras);
        assert_eq!((r.target_reliability, r.feedback_reliability), (Reliability::Reliable, Reliability::BestEffort));
        assert_eq!(r.feedback_timeout_ms(p.command_timeout_ms), 100.0);
    }

    #[test]
    fn a_bad_table_is_refused_by_the_ros2_driver() {
        type Spoil = fn(&mut Ros2Params);
        let cases: [(&str, Spoil); 8] = [
            ("cameras[1].id", |r| r.cameras[1].id = "head_left".into()),
            ("cameras[0].topic", |r| r.cameras[0].topic = "/a b".into()),
            ("cameras[1]", |r| r.cameras[1].width = 0),
            ("domain_id", |r| r.domain_id = 233),
            ("joint_names", |r| {
                r.joint_names.pop();
            }),
            ("feedback_timeout_ms", |r| r.feedback_timeout_ms = Some(5.0)),
            ("arm_target_topic", |r| r.arm_target_topic = "motion_target/x".into()),
            ("gripper_stroke_max", |r| r.gripper_stroke_max = 0.0),
        ];
        for (field, spoil) in cases {
            let p = r1_lite();
            let mut r = Ros2Params::of(&p).unwrap();
            spoil(&mut r);
            let msg = r.check(&p).unwrap_err().to_string();
            assert!(msg.contains(&format!("ros2.{field}")), "{field}: {msg}");
        }
    }
}
