//! ROS 2 topic names as the wire carries them.
//!
//! rmw maps a ROS topic `/a/b` to the DDS topic `rt/a/b` ("ROS topic"); ros2-client does the same
//! (`Name::to_dds_name("rt", …)`), so a name here is the ROS one, and [`dds_topic`] is what a peer written against
//! DDS directly (the tests' Cyclone DDS stand-in) subscribes to.

/// The DDS topic of the absolute ROS topic `ros_name`.
pub fn dds_topic(ros_name: &str) -> String {
    format!("rt{ros_name}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_r1_lite_topics_map_to_rt() {
        assert_eq!(dds_topic("/hdas/feedback_arm_right"), "rt/hdas/feedback_arm_right");
    }
}
