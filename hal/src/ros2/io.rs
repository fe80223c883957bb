//! The DDS side of the backend, on a thread of its own: the HAL loop never calls into DDS.
//!
//! RustDDS allocates for every sample (CDR buffers, the `Vec`s of a `JointState`) and takes locks inside, so the
//! loop thread (pinned, SCHED_FIFO) only exchanges fixed-size `Copy` values with this thread, wait-free both
//! ways: the newest feedback through a triple buffer (the I/O thread writes, the loop reads the newest whenever it
//! likes), and the targets to publish through an `rtrb` ring (the loop pushes and unparks the I/O thread, which
//! publishes at once). The I/O thread polls the two feedback subscriptions every [`POLL`] and stamps each sample
//! with CLOCK_MONOTONIC when it takes it: the feedback's age the backend judges is the time since then.
//!
//! The participant, node and topics are made on the I/O thread before the HAL loop starts, so neither it nor
//! RustDDS's own threads inherit the loop's real-time settings; so are the camera threads ([`super::camera`]),
//! which take their topics' subscriptions from it and are joined before the node is dropped.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use mars_ipc::MAX_JOINTS;
use mars_rt::monotonic_ns;
use ros2_client::dds::rustdds::DomainParticipantBuilder;
use ros2_client::dds::{Context, Node, Publisher, Subscription};
use ros2_client::names::{MessageTypeName, Name, NodeName};
use ros2_client::node_options::NodeOptions;
use ros2_client::qos::{QosProfile, WhenFull};
use tracing::warn;

use super::camera::{CameraCounts, Cameras};
use super::message::{COMPRESSED_IMAGE_TYPE, CompressedImage, Header, JOINT_STATE_TYPE, JointState, SENSOR_MSGS, Time};
use super::params::{Reliability, Ros2Params};

/// How often the I/O thread looks for feedback when nothing woke it (a target to publish wakes it at once).
pub const POLL: Duration = Duration::from_micros(500);
/// Targets in flight between the loop and the I/O thread (the loop pushes at most two per tick).
const RING: usize = 64;
/// Samples taken from one subscription per round, so a flood cannot starve the targets.
const TAKE_PER_ROUND: usize = 64;

/// The newest arm feedback: the first `joints` positions (and velocities and efforts, 0 where the message has
/// none), and when the I/O thread took it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ArmSample {
    pub position: [f64; MAX_JOINTS],
    pub velocity: [f64; MAX_JOINTS],
    pub effort: [f64; MAX_JOINTS],
    pub received_ns: u64,
}

/// The newest gripper feedback: its position on the topic's scale (the R1 Lite's stroke, 0–100 mm).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct GripperSample {
    pub stroke: f64,
    pub received_ns: u64,
}

/// What the loop reads: the newest feedback and how many samples came.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Newest {
    pub arm: Option<ArmSample>,
    pub gripper: Option<GripperSample>,
    pub arm_samples: u64,
    pub gripper_samples: u64,
    /// Samples not used: fewer positions than the arm has joints (or none for the gripper), or undecodable.
    pub bad_samples: u64,
}

/// A target to publish.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Target {
    /// Joint positions (rad), the first `joints` used.
    Arm([f64; MAX_JOINTS]),
    /// The gripper's position on the topic's scale.
    Gripper(f64),
}

/// The I/O thread's counters.
#[derive(Debug, Default)]
pub struct IoCounts {
    pub arm_published: AtomicU64,
    pub gripper_published: AtomicU64,
    pub publish_errors: AtomicU64,
}

/// The loop's end of the link to the I/O thread.
pub struct Link {
    newest: triple_buffer::Output<Newest>,
    targets: rtrb::Producer<Target>,
    io: std::thread::Thread,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
    pub counts: Arc<IoCounts>,
    /// Each camera's id and counters, in `[[ros2.cameras]]` order.
    pub cameras: Vec<(String, Arc<CameraCounts>)>,
    /// Targets the ring had no room for (the I/O thread fell behind by [`RING`] targets).
    pub ring_full: u64,
}

/// The DDS entities the I/O thread owns.
struct Dds {
    arm_feedback: Subscription<JointState>,
    gripper_feedback: Option<Subscription<JointState>>,
    arm_target: Publisher<JointState>,
    gripper_target: Option<Publisher<JointState>>,
    /// The cameras' topics, handed to their threads.
    cameras: Vec<Subscription<CompressedImage>>,
    // Kept alive for as long as the publishers and subscriptions are used.
    _node: Node,
    _context: Context,
}

fn qos(r: Reliability) -> QosProfile {
    // Keep only the newest sample either way: an older target or feedback is worth nothing once a newer exists.
    let q = QosProfile::subscription_default();
    match r {
        Reliability::BestEffort => q.reliability_best_effort(),
        // Never block the I/O thread on a full send window: the next target replaces the one refused.
        Reliability::Reliable => q.reliability_reliable(WhenFull::Fail),
    }
}

impl Dds {
    fn open(p: &Ros2Params) -> anyhow::Result<Self> {
        let mut builder = DomainParticipantBuilder::new(p.domain_id);
        if p.localhost_only {
            // Advertise and multicast only on loopback; RustDDS also announces itself to 127.0.0.1's well-known
            // discovery ports (its `same_host_loopback`, on by default), which is how it finds a peer on a `lo`
            // without multicast.
            builder = builder.with_only_networks([std::net::Ipv4Addr::LOCALHOST]);
        }
        let participant = builder.build().map_err(|e| anyhow::anyhow!("creating the DDS participant: {e:?}"))?;
        let context = Context::from_domain_participant(participant)
            .map_err(|e| anyhow::anyhow!("creating the ROS 2 context: {e:?}"))?;
        let name = NodeName::new("/", "mars_hal").map_err(|e| anyhow::anyhow!("node name: {e:?}"))?;
        // No /rosout and no parameter services: nothing runs this node's spinner, and the HAL logs to stderr.
        let options = NodeOptions::new().enable_rosout(false).start_parameter_services(false);
        let mut node = context.new_node(name, options).map_err(|e| anyhow::anyhow!("creating the node: {e:?}"))?;
        let typed_topic = |node: &Node, ros_name: &str, type_name: &str, r: Reliability| {
            let name = Name::parse(ros_name).map_err(|e| anyhow::anyhow!("topic {ros_name}: {e:?}"))?;
            let type_name = MessageTypeName::new(SENSOR_MSGS, type_name);
            node.create_topic(&name, type_name, &qos(r)).map_err(|e| anyhow::anyhow!("topic {ros_name}: {e:?}"))
        };
        let topic = |node: &Node, ros_name: &str, r| typed_topic(node, ros_name, JOINT_STATE_TYPE, r);
        let (fb, tg) = (p.feedback_reliability, p.target_reliability);
        let sub = |node: &mut Node, t| {
            node.create_subscription::<JointState>(&t, Some(qos(fb))).map_err(|e| anyhow::anyhow!("subscribing: {e:?}"))
        };
        let arm_feedback = {
            let t = topic(&node, &p.arm_feedback_topic, fb)?;
            sub(&mut node, t)?
        };
        let pubr = |node: &mut Node, t| {
            node.create_publisher::<JointState>(&t, Some(qos(tg))).map_err(|e| anyhow::anyhow!("publishing: {e:?}"))
        };
        let arm_target = {
            let t = topic(&node, &p.arm_target_topic, tg)?;
            pubr(&mut node, t)?
        };
        let (gripper_feedback, gripper_target) = if p.gripper {
            (
                {
                    let t = topic(&node, &p.gripper_feedback_topic, fb)?;
                    Some(sub(&mut node, t)?)
                },
                {
                    let t = topic(&node, &p.gripper_target_topic, tg)?;
                    Some(pubr(&mut node, t)?)
                },
            )
        } else {
            (None, None)
        };
        // Camera frames: BEST_EFFORT (it matches the robot's writers of either kind, and a lost frame is not worth
        // a resend once the next is there).
        let mut cameras = Vec::new();
        for c in &p.cameras {
            let t = typed_topic(&node, &c.topic, COMPRESSED_IMAGE_TYPE, Reliability::BestEffort)?;
            cameras.push(
                node.create_subscription::<CompressedImage>(&t, Some(qos(Reliability::BestEffort)))
                    .map_err(|e| anyhow::anyhow!("subscribing {}: {e:?}", c.topic))?,
            );
        }
        Ok(Self { arm_feedback, gripper_feedback, arm_target, gripper_target, cameras, _node: node, _context: context })
    }
}

impl Link {
    /// Opens the DDS side on a new thread (participant, node, the two feedback subscriptions and target
    /// publishers, and a thread per camera publishing on `mars/<robot>/camera/<id>`) and returns once it is ready,
    /// or why it could not be.
    pub fn open(p: &Ros2Params, joints: usize, robot: &str) -> anyhow::Result<Self> {
        let (newest_in, newest) = triple_buffer::triple_buffer(&Newest::default());
        let (targets, targets_out) = rtrb::RingBuffer::new(RING);
        let stop = Arc::new(AtomicBool::new(false));
        let counts = Arc::new(IoCounts::default());
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let cameras: Vec<_> = p.cameras.iter().map(|c| (c.id.clone(), Arc::new(CameraCounts::default()))).collect();
        let camera_counts: Vec<_> = cameras.iter().map(|(_, c)| c.clone()).collect();
        let (params, thread_stop, thread_counts, robot) = (p.clone(), stop.clone(), counts.clone(), robot.to_owned());
        let handle = std::thread::Builder::new().name("ros2-io".into()).spawn(move || {
            let opened = Dds::open(&params).and_then(|mut dds| {
                let subs = std::mem::take(&mut dds.cameras);
                let cams = Cameras::start(subs, &params.cameras, &robot, &thread_stop, &camera_counts)?;
                Ok((dds, cams))
            });
            match opened {
                Ok((dds, cams)) => {
                    let _ = ready_tx.send(Ok(()));
                    serve(&dds, &params, joints, newest_in, targets_out, &thread_stop, &thread_counts);
                    // The stop flag is theirs too; the node they subscribed through is dropped after them.
                    cams.join();
                    drop(dds);
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                }
            }
        })?;
        let io = handle.thread().clone();
        match ready_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(e.context("opening ROS 2 (RustDDS through ros2-client)")),
            Err(_) => anyhow::bail!("the ROS 2 I/O thread ended while opening"),
        }
        Ok(Self { newest, targets, io, stop, handle: Some(handle), counts, cameras, ring_full: 0 })
    }

    /// The newest feedback. Wait-free; allocates nothing.
    pub fn newest(&mut self) -> &Newest {
        self.newest.read()
    }

    /// Hands a target to the I/O thread and wakes it. Wait-free; allocates nothing. False (and counted) when the
    /// ring is full.
    pub fn send(&mut self, t: Target) -> bool {
        let pushed = self.targets.push(t).is_ok();
        if !pushed {
            self.ring_full += 1;
        }
        self.io.unpark();
        pushed
    }

    /// Stops the I/O thread after it published every target handed over so far.
    pub fn close(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        self.stop.store(true, Ordering::Release);
        self.io.unpark();
        if let Some(h) = self.handle.take()
            && h.join().is_err()
        {
            warn!("the ROS 2 I/O thread panicked");
        }
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// The I/O thread: publish what the loop hands over, take the feedback, until asked to stop (after the last
/// targets went out).
fn serve(
    dds: &Dds,
    p: &Ros2Params,
    joints: usize,
    mut newest_in: triple_buffer::Input<Newest>,
    mut targets: rtrb::Consumer<Target>,
    stop: &AtomicBool,
    counts: &IoCounts,
) {
    let mut newest = Newest::default();
    let names: Vec<String> = p.joint_names.clone();
    let mut warned_short = false;
    loop {
        let stopping = stop.load(Ordering::Acquire);
        let mut busy = false;
        while let Ok(t) = targets.pop() {
            busy = true;
            let header = Header { stamp: Time::now(), frame_id: String::new() };
            let (publisher, msg, count) = match t {
                Target::Arm(q) => (
                    Some(&dds.arm_target),
                    JointState { header, name: names.clone(), position: q[..joints].to_vec(), ..Default::default() },
                    &counts.arm_published,
                ),
                Target::Gripper(stroke) => (
                    dds.gripper_target.as_ref(),
                    JointState { header, position: vec![stroke], ..Default::default() },
                    &counts.gripper_published,
                ),
            };
            let Some(publisher) = publisher else { continue };
            match publisher.publish(msg) {
                Ok(()) => {
                    count.fetch_add(1, Ordering::Relaxed);
                }
                Err(e) => {
                    if counts.publish_errors.fetch_add(1, Ordering::Relaxed) == 0 {
                        warn!("publishing a target failed: {e:?}");
                    }
                }
            }
        }
        let mut changed = false;
        for _ in 0..TAKE_PER_ROUND {
            match dds.arm_feedback.take() {
                Ok(Some((m, _))) => {
                    changed = true;
                    newest.arm_samples += 1;
                    match arm_sample(&m, joints) {
                        Some(s) => newest.arm = Some(s),
                        None => {
                            newest.bad_samples += 1;
                            if !warned_short {
                                warned_short = true;
                                warn!(
                                    "arm feedback with {} positions ignored: the arm has {joints} joints",
                                    m.position.len()
                                );
                            }
                        }
                    }
                }
                Ok(None) => break,
                Err(e) => {
                    changed = true;
                    if newest.bad_samples == 0 {
                        warn!("an arm feedback sample could not be read: {e:?}");
                    }
                    newest.bad_samples += 1;
                }
            }
        }
        if let Some(sub) = &dds.gripper_feedback {
            for _ in 0..TAKE_PER_ROUND {
                match sub.take() {
                    Ok(Some((m, _))) => {
                        changed = true;
                        newest.gripper_samples += 1;
                        match m.position.first() {
                            Some(&stroke) => {
                                newest.gripper = Some(GripperSample { stroke, received_ns: monotonic_ns() })
                            }
                            None => newest.bad_samples += 1,
                        }
                    }
                    Ok(None) => break,
                    Err(_) => {
                        changed = true;
                        newest.bad_samples += 1;
                    }
                }
            }
        }
        if changed {
            newest_in.write(newest);
            busy = true;
        }
        if stopping {
            // Every target handed over before the stop was published above.
            break;
        }
        if !busy {
            std::thread::park_timeout(POLL);
        }
    }
}

/// The arm's sample from a feedback message: its first `joints` positions (Galaxea's docs show 6, some with the
/// gripper as a 7th), or `None` when it has fewer.
pub fn arm_sample(m: &JointState, joints: usize) -> Option<ArmSample> {
    if m.position.len() < joints {
        return None;
    }
    let mut s = ArmSample { received_ns: monotonic_ns(), ..Default::default() };
    s.position[..joints].copy_from_slice(&m.position[..joints]);
    // A driver may leave velocity and effort empty: 0 then (the HAL judges the arm at rest by its velocity).
    if m.velocity.len() >= joints {
        s.velocity[..joints].copy_from_slice(&m.velocity[..joints]);
    }
    if m.effort.len() >= joints {
        s.effort[..joints].copy_from_slice(&m.effort[..joints]);
    }
    Some(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arm_feedback_with_the_gripper_as_a_seventh_joint_uses_the_first_six() {
        let m =
            JointState { position: vec![0.1, 1.0, -1.2, 0.0, 0.2, 0.3, 55.0], velocity: vec![], ..Default::default() };
        let s = arm_sample(&m, 6).unwrap();
        assert_eq!(&s.position[..7], &[0.1, 1.0, -1.2, 0.0, 0.2, 0.3, 0.0]);
        assert_eq!(s.velocity, [0.0; MAX_JOINTS], "no velocities: at rest");
        assert!(arm_sample(&JointState { position: vec![0.0; 5], ..Default::default() }, 6).is_none());
    }
}
