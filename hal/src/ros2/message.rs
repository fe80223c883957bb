//! `sensor_msgs/msg/JointState`, the one message the R1 Lite's arm and gripper topics carry, as serde types whose
//! CDR encoding (RustDDS's serializer) is ROS 2's: fields in the `.msg` file's order, `int32`/`uint32` stamps,
//! strings and `float64` sequences. On the DDS wire its type is `sensor_msgs::msg::dds_::JointState_`
//! ([`JOINT_STATE_PACKAGE`] / [`JOINT_STATE_TYPE`] through ros2-client's `MessageTypeName`).
//!
//! Written here rather than generated: ros2-client ships no `sensor_msgs`, and the three structs are the whole
//! definition (std_msgs/Header, builtin_interfaces/Time, sensor_msgs/JointState of ROS 2 Jazzy). The test below
//! checks the bytes against what Cyclone DDS (the stand-in's implementation) writes for the same message.

use serde::{Deserialize, Serialize};

pub const JOINT_STATE_PACKAGE: &str = "sensor_msgs";
pub const JOINT_STATE_TYPE: &str = "JointState";

/// `builtin_interfaces/msg/Time`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// The wall clock now (ROS time without a simulated clock).
    pub fn now() -> Self {
        let d = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        Self { sec: d.as_secs() as i32, nanosec: d.subsec_nanos() }
    }
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// `sensor_msgs/msg/JointState`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    pub header: Header,
    pub name: Vec<String>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use ros2_client::dds::rustdds::RepresentationIdentifier;
    use ros2_client::dds::rustdds::serialization::{deserialize_from_cdr_with_rep_id, to_writer_with_rep_id};

    /// `JointState_(Header_(Time_(1, 2), 'a'), ['j1'], [1.0], [], [])` as cyclonedds-python 11.0.1 serialises it
    /// (`.serialize()`), without its 4-byte encapsulation header `00 01 00 00` (CDR_LE, which RustDDS writes and
    /// reads itself): the alignment of the `float64` after the sequence length is CDR's, not packed.
    const CYCLONE_BYTES: &str = "0100000002000000020000006100000001000000030000006a31000001000000000000000000f03f\
                                 0000000000000000";

    fn hex(b: &[u8]) -> String {
        b.iter().map(|x| format!("{x:02x}")).collect()
    }

    #[test]
    fn the_cdr_bytes_are_cyclone_dds_s_for_the_same_message() {
        let m = JointState {
            header: Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: "a".into() },
            name: vec!["j1".into()],
            position: vec![1.0],
            ..Default::default()
        };
        let mut bytes = Vec::new();
        to_writer_with_rep_id(&mut bytes, &m, RepresentationIdentifier::CDR_LE).unwrap();
        assert_eq!(hex(&bytes), CYCLONE_BYTES);
        let (back, used): (JointState, usize) =
            deserialize_from_cdr_with_rep_id(&bytes, RepresentationIdentifier::CDR_LE).unwrap();
        assert_eq!((back, used), (m, bytes.len()));
    }
}
