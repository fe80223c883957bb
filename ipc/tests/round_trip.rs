//! Frames through real iceoryx2 shared memory, within one process. Every test uses its own robot namespace
//! (pid + counter) so the tests run in parallel without meeting each other's services.

use std::sync::atomic::{AtomicU32, Ordering};

use mars_ipc::node::create_node;
use mars_ipc::wire::WireError;
use mars_ipc::*;

fn unique_ns() -> RobotNamespace {
    static N: AtomicU32 = AtomicU32::new(0);
    RobotNamespace::new(&format!("t{}-{}", std::process::id(), N.fetch_add(1, Ordering::Relaxed))).unwrap()
}

#[test]
fn state_and_command_frames_round_trip_unchanged() {
    let ns = unique_ns();
    let (node, _) = create_node("ipc-test").unwrap();
    let state_w = StateWriter::new(&node, &ns).unwrap();
    let state_r = StateReader::new(&node, &ns).unwrap();
    let cmd_w = CommandWriter::new(&node, &ns).unwrap();
    let cmd_r = CommandReader::new(&node, &ns).unwrap();

    assert_eq!(state_r.receive().unwrap(), None);
    let mut s = RobotState { seq: 42, timestamp_ns: 7, num_joints: 7, gripper: 0.04, ..Default::default() };
    s.position[..7].copy_from_slice(&[0.1, -0.2, 0.3, -1.5, 0.0, 1.2, 0.7]);
    s.velocity[3] = -0.5;
    assert_eq!(state_w.send(&s).unwrap(), 1);
    assert_eq!(state_r.receive().unwrap(), Some(s));

    let c = JointCommand::position(9, 1, 42, &[0.1, -0.2, 0.3, -1.5, 0.0, 1.2, 0.7]);
    assert_eq!(cmd_w.send(&c).unwrap(), 1);
    assert_eq!(cmd_r.receive().unwrap(), Some(c));
    assert_eq!(cmd_r.receive().unwrap(), None);
}

#[test]
fn a_frame_with_another_schema_version_is_refused_and_the_next_one_is_read() {
    let ns = unique_ns();
    let (node, _) = create_node("ipc-test").unwrap();
    let w = CommandWriter::new(&node, &ns).unwrap();
    let r = CommandReader::new(&node, &ns).unwrap();
    let c = JointCommand::position(1, 1, 0, &[0.0; 7]);
    w.send_with_header(&c, FrameHeader { schema_version: SCHEMA_VERSION + 1 }).unwrap();
    w.send(&JointCommand { seq: 2, ..c }).unwrap();

    assert!(r.service().ends_with("/command"), "{}", r.service());
    match r.receive() {
        Err(FrameReceiveError::Schema(mismatch)) => {
            assert_eq!(mismatch, SchemaMismatch { expected: SCHEMA_VERSION, found: SCHEMA_VERSION + 1 });
        }
        other => panic!("expected a schema refusal, got {other:?}"),
    }
    assert_eq!(r.receive().unwrap().map(|c| c.seq), Some(2));
}

#[test]
fn a_640x480_rgb_image_arrives_in_place_with_its_header() {
    let ns = unique_ns();
    let (node, _) = create_node("ipc-test").unwrap();
    let w = ImageWriter::new(&node, &ns, "wrist", 640 * 480 * 3).unwrap();
    let r = ImageReader::new(&node, &ns, "wrist").unwrap();
    let header = ImageHeader {
        width: 640,
        height: 480,
        encoding: ImageEncoding::Rgb8 as u32,
        seq: 3,
        timestamp_ns: 11,
        ..Default::default()
    };
    assert_eq!(w.send_with(header, |px| px.iter_mut().enumerate().for_each(|(i, b)| *b = (i % 251) as u8)).unwrap(), 1);

    let frame = r.receive().unwrap().expect("an image");
    assert_eq!(*frame.header(), header);
    assert_eq!(frame.pixels().len(), 640 * 480 * 3);
    assert!(frame.pixels().iter().enumerate().all(|(i, b)| *b == (i % 251) as u8));
}

#[test]
fn an_image_whose_header_lies_about_its_size_is_refused() {
    let ns = unique_ns();
    let (node, _) = create_node("ipc-test").unwrap();
    let w = ImageWriter::new(&node, &ns, "head", 64).unwrap();
    let r = ImageReader::new(&node, &ns, "head").unwrap();
    // An unknown encoding has no size: the writer refuses to send it at all.
    let bad = ImageHeader { width: 4, height: 4, encoding: 99, ..Default::default() };
    assert!(matches!(w.send_with(bad, |_| ()), Err(WireError::BadImage { expected: None, .. })));
    // A mismatched schema on an image is refused by the reader.
    let other = ImageHeader {
        schema_version: SCHEMA_VERSION + 5,
        width: 2,
        height: 2,
        encoding: ImageEncoding::Mono8 as u32,
        ..Default::default()
    };
    w.send_with(other, |_| ()).unwrap();
    let mismatch = SchemaMismatch { expected: SCHEMA_VERSION, found: SCHEMA_VERSION + 5 };
    assert_eq!(r.receive().err(), Some(ImageReceiveError::Schema(mismatch)));
    // A payload shorter than the header's size, as a buggy camera process could send it: refused, with both sizes.
    let short = ImageHeader { width: 4, height: 4, encoding: ImageEncoding::Rgb8 as u32, ..Default::default() };
    w.send_raw(short, 40, |_| ()).unwrap();
    let e = r.receive().err().expect("a refusal");
    assert_eq!(e, ImageReceiveError::Length { width: 4, height: 4, encoding: 1, expected: Some(48), found: 40 });
    assert_eq!(e.to_string(), "the header says 4×4, encoding 1: 48 bytes, but the payload has 40");
    // The reader goes on with the next frame.
    w.send_with(short, |px| px.fill(7)).unwrap();
    assert!(r.receive().unwrap().expect("the next image").pixels().iter().all(|b| *b == 7));
}

#[test]
fn two_robots_do_not_hear_each_other() {
    let (a, b) = (unique_ns(), unique_ns());
    let (node, _) = create_node("ipc-test").unwrap();
    let wa = StateWriter::new(&node, &a).unwrap();
    let rb = StateReader::new(&node, &b).unwrap();
    assert_eq!(wa.send(&RobotState::default()).unwrap(), 0);
    assert_eq!(rb.receive().unwrap(), None);
}

#[test]
fn a_bad_node_name_is_a_clear_error() {
    assert!(matches!(create_node(&"n".repeat(10_000)), Err(WireError::Node(msg)) if msg.contains("node name")));
}
