//! The ros2 backend's decoding of what the robot sends: `sensor_msgs/JointState` and `CompressedImage` in CDR (as
//! RustDDS decodes a sample, in every representation its readers accept), the arm's sample taken out of a joint
//! state, and the camera bridge's JPEG decoding (zune-jpeg) of an image to the configured size. Seeds: messages
//! and JPEGs (RGB and grey, several sizes and qualities) made at start.

use std::sync::Arc;
use std::time::Duration;

use mars_hal::ros2::camera::{capture_ns, decode};
use mars_hal::ros2::io::arm_sample;
use mars_hal::ros2::message::{CompressedImage, Header, JointState, Time};
use ros2_client::dds::rustdds::RepresentationIdentifier;
use ros2_client::dds::rustdds::serialization::{deserialize_from_cdr_with_rep_id, to_writer_with_rep_id};
use serde_bytes::ByteBuf;

use super::Bundles;
use crate::runner::Target;

/// The encodings a RustDDS reader decodes a sample from (the sample's encapsulation header names it).
const REPRESENTATIONS: [RepresentationIdentifier; 4] = [
    RepresentationIdentifier::CDR_LE,
    RepresentationIdentifier::CDR_BE,
    RepresentationIdentifier::PL_CDR_LE,
    RepresentationIdentifier::PL_CDR_BE,
];
/// Seed JPEGs: (width, height, grey, quality).
const JPEGS: [(u32, u32, bool, u8); 5] =
    [(64, 48, false, 90), (16, 16, false, 50), (33, 17, true, 75), (8, 8, false, 10), (40, 24, true, 100)];

fn encode_jpeg(w: u32, h: u32, grey: bool, quality: u8) -> Vec<u8> {
    let channels = if grey { 1 } else { 3 };
    let pixels: Vec<u8> = (0..w * h * channels).map(|i| ((i * 37) ^ (i / 7)) as u8).collect();
    let mut out = Vec::new();
    let color = if grey { image::ColorType::L8 } else { image::ColorType::Rgb8 };
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality).encode(&pixels, w, h, color).expect("a JPEG");
    out
}

fn stamp() -> Header {
    Header { stamp: Time { sec: 1_700_000_000, nanosec: 5 }, frame_id: "head".into() }
}

fn cdr_of<T: serde::Serialize>(m: &T, rep: RepresentationIdentifier) -> Vec<u8> {
    let mut out = Vec::new();
    to_writer_with_rep_id(&mut out, m, rep).expect("CDR");
    out
}

/// A CDR message: `[representation, kind (0 joint state, 1 image)]` then the message's bytes.
pub fn cdr() -> Arc<dyn Target> {
    let names = |n: usize| (1..=n).map(|i| format!("right_arm_joint{i}")).collect::<Vec<_>>();
    let arm = JointState {
        header: stamp(),
        name: names(6),
        position: vec![0.1, 1.0, -1.2, 0.0, 0.2, 0.3],
        velocity: vec![0.0; 6],
        effort: vec![0.5; 6],
    };
    let gripper = JointState { header: stamp(), position: vec![55.0], ..JointState::default() };
    let (w, h, grey, q) = JPEGS[0];
    let format = "rgb8; jpeg compressed bgr8".to_owned();
    let image = CompressedImage { header: stamp(), format, data: ByteBuf::from(encode_jpeg(w, h, grey, q)) };
    let mut files = Vec::new();
    for (r, rep) in REPRESENTATIONS.into_iter().enumerate() {
        for (kind, bytes) in [(0u8, cdr_of(&arm, rep)), (0, cdr_of(&gripper, rep)), (1, cdr_of(&image, rep))] {
            files.push([&[r as u8, kind][..], &bytes].concat());
        }
    }
    Bundles::of_files("ros2-cdr", files, false, |_, message| {
        let [rep, kind, bytes @ ..] = message else { return false };
        let rep = REPRESENTATIONS[*rep as usize % REPRESENTATIONS.len()];
        if kind % 2 == 0 {
            let Ok((m, _)) = deserialize_from_cdr_with_rep_id::<JointState>(bytes, rep) else { return false };
            let _ = arm_sample(&m, 7);
            arm_sample(&m, 6).is_some() || m.position.len() == 1
        } else {
            let Ok((m, _)) = deserialize_from_cdr_with_rep_id::<CompressedImage>(bytes, rep) else { return false };
            let _ = capture_ns(m.header.stamp, 5_000_000_000, Duration::new(1_700_000_001, 0));
            decode(&m, JPEGS[0].0, JPEGS[0].1, &mut Vec::new()).is_ok()
        }
    })
}

/// A camera's JPEG bytes, decoded to the size the bridge is configured for (the seed's).
pub fn jpeg() -> Arc<dyn Target> {
    let files = JPEGS.iter().map(|&(w, h, g, q)| encode_jpeg(w, h, g, q)).collect();
    Bundles::of_files("ros2-jpeg", files, false, |b, bytes| {
        let (w, h, _, _) = JPEGS[b];
        let msg = CompressedImage { header: stamp(), format: "jpeg".into(), data: ByteBuf::from(bytes.to_vec()) };
        decode(&msg, w, h, &mut Vec::new()).is_ok()
    })
}
