//! The ros2 backend's decoding of what the robot sends: `sensor_msgs/JointState` and `CompressedImage` in CDR (as
//! RustDDS decodes a sample, in every representation its readers accept), the arm's sample taken out of a joint
//! state, and the camera bridge's JPEG decoding (zune-jpeg) of an image to the configured size. Seeds: messages
//! and JPEGs (RGB and grey, several sizes and qualities) made at start.

use mars_hal::ros2::camera::{capture_ns, decode};
use mars_hal::ros2::io::arm_sample;
use mars_hal::ros2::message::{CompressedImage, Header, JointState, Time};
use rand::rngs::StdRng;
use ros2_client::dds::rustdds::RepresentationIdentifier;
use ros2_client::dds::rustdds::serialization::{deserialize_from_cdr_with_rep_id, to_writer_with_rep_id};
use serde_bytes::ByteBuf;

use super::{bundle_seeds, generate_bundle, split_bundle};
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

fn jpeg(w: u32, h: u32, grey: bool, quality: u8) -> Vec<u8> {
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

fn cdr<T: serde::Serialize>(m: &T, rep: RepresentationIdentifier) -> Vec<u8> {
    let mut out = Vec::new();
    to_writer_with_rep_id(&mut out, m, rep).expect("CDR");
    out
}

/// A CDR message: `[representation, kind (0 joint state, 1 image)]` then the message's bytes.
pub struct Cdr {
    bundles: Vec<Vec<Vec<u8>>>,
}

impl Cdr {
    pub fn new() -> Self {
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
        let image = CompressedImage {
            header: stamp(),
            format: "rgb8; jpeg compressed bgr8".into(),
            data: ByteBuf::from(jpeg(w, h, grey, q)),
        };
        let mut bundles = Vec::new();
        for rep in REPRESENTATIONS {
            for (kind, bytes) in [(0u8, cdr(&arm, rep)), (0, cdr(&gripper, rep)), (1, cdr(&image, rep))] {
                let mut m = vec![REPRESENTATIONS.iter().position(|r| *r == rep).unwrap_or(0) as u8, kind];
                m.extend_from_slice(&bytes);
                bundles.push(vec![m]);
            }
        }
        Self { bundles }
    }
}

impl Target for Cdr {
    fn name(&self) -> &'static str {
        "ros2-cdr"
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        generate_bundle(rng, &self.bundles, |_| false)
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        bundle_seeds(&self.bundles)
    }

    fn run(&self, input: &[u8]) -> bool {
        let Some((_, _, message)) = split_bundle(input, self.bundles.len()) else { return false };
        let [rep, kind, bytes @ ..] = message else { return false };
        let rep = REPRESENTATIONS[*rep as usize % REPRESENTATIONS.len()];
        if kind % 2 == 0 {
            let Ok((m, _)) = deserialize_from_cdr_with_rep_id::<JointState>(bytes, rep) else { return false };
            let _ = arm_sample(&m, 7);
            arm_sample(&m, 6).is_some() || m.position.len() == 1
        } else {
            let Ok((m, _)) = deserialize_from_cdr_with_rep_id::<CompressedImage>(bytes, rep) else { return false };
            let _ = capture_ns(m.header.stamp, 5_000_000_000, std::time::Duration::new(1_700_000_001, 0));
            decode(&m, JPEGS[0].0, JPEGS[0].1, &mut Vec::new()).is_ok()
        }
    }
}

/// A camera's JPEG bytes, decoded to the size the bridge is configured for (the seed's).
pub struct Jpeg {
    bundles: Vec<Vec<Vec<u8>>>,
}

impl Jpeg {
    pub fn new() -> Self {
        Self { bundles: JPEGS.iter().map(|&(w, h, g, q)| vec![jpeg(w, h, g, q)]).collect() }
    }
}

impl Target for Jpeg {
    fn name(&self) -> &'static str {
        "ros2-jpeg"
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        generate_bundle(rng, &self.bundles, |_| false)
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        bundle_seeds(&self.bundles)
    }

    fn run(&self, input: &[u8]) -> bool {
        let Some((b, _, bytes)) = split_bundle(input, self.bundles.len()) else { return false };
        let (w, h, _, _) = JPEGS[b];
        let msg = CompressedImage { header: stamp(), format: "jpeg".into(), data: ByteBuf::from(bytes.to_vec()) };
        decode(&msg, w, h, &mut Vec::new()).is_ok()
    }
}
