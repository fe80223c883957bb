//! ROS 2 topic names as the wire carries them.
//!
//! rmw maps a ROS topic `/a/b` to the DDS topic `rt/a/b` ("ROS topic"); ros2-client does the same
//! (`Name::to_dds_name("rt", …)`), so a name here is the ROS one, and [`dds_topic`] is what a peer written against
//! DDS directly (the tests' Cyclone DDS stand-in) subscribes to.

/// The DDS topic of the absolute ROS topic `ros_name`.
pub fn dds_topic(ros_name: &str) -> String {
    format!("rt{ros_name}")
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
    use super::*;

    #[test]
    fn the_r1_lite_topics_are_valid_and_map_to_rt() {
        for t in ["/hdas/feedback_arm_right", "/motion_target/target_position_gripper_right"] {
            assert_eq!(check_ros_name(t), Ok(()), "{t}");
        }
        assert_eq!(dds_topic("/hdas/feedback_arm_right"), "rt/hdas/feedback_arm_right");
        for bad in ["hdas/x", "/", "/a//b", "/a/", "/a-b", "/1a", "/a__b"] {
            assert!(check_ros_name(bad).is_err(), "{bad}");
        }
    }
}
