//! The two messages the R1 Lite's topics carry, `sensor_msgs/msg/JointState` (arm and gripper) and
//! `sensor_msgs/msg/CompressedImage` (cameras), as serde types whose CDR encoding (RustDDS's serializer) is ROS 2's:
//! fields in the `.msg` file's order, `int32`/`uint32` stamps, strings, `float64` and `uint8` sequences. On the DDS
//! wire their types are `sensor_msgs::msg::dds_::JointState_` and `…::CompressedImage_` ([`SENSOR_MSGS`] and the
//! type names, through ros2-client's `MessageTypeName`).
//!
//! Written here rather than generated: ros2-client ships no `sensor_msgs`, and these structs are the whole
//! definition (std_msgs/Header, builtin_interfaces/Time and the two messages, as in ROS 2 Jazzy). The tests below
//! check the bytes against what Cyclone DDS (the stand-in's implementation) writes for the same messages.

use serde::{Deserialize, Serialize};

pub const SENSOR_MSGS: &str = "sensor_msgs";
pub const JOINT_STATE_TYPE: &str = "JointState";
pub const COMPRESSED_IMAGE_TYPE: &str = "CompressedImage";

/// The wall clock (CLOCK_REALTIME) since the Unix epoch: what ROS stamps messages with.
pub fn wall_clock() -> std::time::Duration {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default()
}

/// `builtin_interfaces/msg/Time`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// The wall clock now (ROS time without a simulated clock).
    pub fn now() -> Self {
        let d = wall_clock();
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

/// `sensor_msgs/msg/CompressedImage`: `format` names the codec (image_transport writes e.g. `"rgb8; jpeg compressed
/// bgr8"`), `data` the compressed bytes. `data` as [`serde_bytes::ByteBuf`]: CDR's `sequence<uint8>` is a length and
/// the raw bytes, which serde's byte-buffer path reads in one copy rather than element by element.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CompressedImage {
    pub header: Header,
    pub format: String,
    pub data: serde_bytes::ByteBuf,
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

    /// `m` serialises (little-endian CDR, as RustDDS writes it) to `cyclone_hex`, and reads back whole.
    fn assert_cdr_is<T>(m: &T, cyclone_hex: &str)
    where
        T: Serialize + for<'de> Deserialize<'de> + PartialEq + std::fmt::Debug,
    {
        let mut bytes = Vec::new();
        to_writer_with_rep_id(&mut bytes, m, RepresentationIdentifier::CDR_LE).unwrap();
        assert_eq!(hex(&bytes), cyclone_hex);
        let (back, used): (T, usize) =
            deserialize_from_cdr_with_rep_id(&bytes, RepresentationIdentifier::CDR_LE).unwrap();
        assert_eq!((&back, used), (m, bytes.len()));
    }

    #[test]
    fn the_cdr_bytes_are_cyclone_dds_s_for_the_same_message() {
        let m = JointState {
            header: Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: "a".into() },
            name: vec!["j1".into()],
            position: vec![1.0],
            ..Default::default()
        };
        assert_cdr_is(&m, CYCLONE_BYTES);
    }

    /// `CompressedImage_(Header_(Time_(1, 2), 'a'), 'jpeg', b'\xff\xd8\x01')` as cyclonedds-python 11.0.1 writes
    /// it (`data: sequence[uint8]`, given a `bytes`), without the encapsulation header: the data's length is
    /// aligned to 4 after the string, the bytes follow raw.
    const CYCLONE_IMAGE_BYTES: &str = "01000000020000000200000061000000050000006a7065670000000003000000ffd801";

    #[test]
    fn a_compressed_image_s_cdr_bytes_are_cyclone_dds_s() {
        let m = CompressedImage {
            header: Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: "a".into() },
            format: "jpeg".into(),
            data: serde_bytes::ByteBuf::from(vec![0xff, 0xd8, 0x01]),
        };
        assert_cdr_is(&m, CYCLONE_IMAGE_BYTES);
    }
}
