//! A daemon's live view (`mars_ipc::LiveStats`, what `marsd top` shows) on the Zenoh network, so one `marsd top`
//! on any machine watches every robot of a fleet: marsd with `[remote]` puts each frame its latency collector makes
//! on `<prefix>/<robot>/live` ([`LivePublisher`]); `marsd top --connect` subscribes to `<prefix>/*/live`
//! ([`LiveWatch`]).
//!
//! The frame travels as explicit little-endian bytes, not as the `#[repr(C)]` struct iceoryx2 carries, so a reader
//! in another language (Python's `struct` with `<4sHH4Q84QII4Q7Q6Q32s`) or on another architecture reads it:
//! "MARL", version, flags (0); seq, timestamp_ns, period_ns, inference_budget_ns; 12 channels of count, p50, p99,
//! max, over_period, start_ns, end_ns; phase, trip (u32); episode, ticks, policy_beats, starved; the servo's 7
//! counters, the HAL's 6 (in `mars_ipc::live`'s order); the camera's name (32 bytes, zero-padded). 888 bytes: any
//! other length, magic or version is refused.
//!
//! Publishing is on the collector's thread (never a real-time loop), with Zenoh's default congestion control for
//! publications (drop, never block): a slow link loses live frames, not the daemon's time.

use mars_ipc::{HalLive, LIVE_CHANNELS, LiveChannel, LiveStats, ServoLive};
use zenoh::Wait;

use crate::link::{LinkError, check_prefix, check_robot};

/// "MARL": a live frame.
pub const LIVE_MAGIC: [u8; 4] = *b"MARL";
/// Bumped on any change of the layout.
pub const LIVE_VERSION: u16 = 1;
/// Bytes of a live frame.
pub const LIVE_LEN: usize = 8 + 4 * 8 + LIVE_CHANNELS * 7 * 8 + 2 * 4 + 4 * 8 + 7 * 8 + 6 * 8 + CAMERA_LEN;
const CAMERA_LEN: usize = mars_ipc::live::CAMERA_NAME_LEN;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LiveError {
    #[error("live frame: {0} bytes, not {LIVE_LEN}")]
    Length(usize),
    #[error("live frame: magic {0:?}, not {LIVE_MAGIC:?}")]
    Magic([u8; 4]),
    #[error("live frame: version {0}, this build reads {LIVE_VERSION}")]
    Version(u16),
}

/// The key a robot's live frames go to: `<prefix>/<robot>/live`.
pub fn live_key(prefix: &str, robot: &str) -> Result<String, LinkError> {
    check_prefix(prefix)?;
    check_robot(robot)?;
    Ok(format!("{prefix}/{robot}/live"))
}

/// Every robot's live frames under `prefix`: `<prefix>/*/live`.
pub fn all_live_keys(prefix: &str) -> Result<String, LinkError> {
    check_prefix(prefix)?;
    Ok(format!("{prefix}/*/live"))
}

/// The robot a live key names (`<prefix>/<robot>/live`), if it is one.
pub fn robot_of_live<'a>(prefix: &str, key: &'a str) -> Option<&'a str> {
    key.strip_prefix(prefix)?.strip_prefix('/')?.strip_suffix("/live").filter(|r| !r.is_empty() && !r.contains('/'))
}

/// The frame's bytes.
pub fn encode(frame: &LiveStats) -> Vec<u8> {
    let mut out = Vec::with_capacity(LIVE_LEN);
    out.extend_from_slice(&LIVE_MAGIC);
    out.extend_from_slice(&LIVE_VERSION.to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes());
    let put = |out: &mut Vec<u8>, values: &[u64]| values.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
    put(&mut out, &[frame.seq, frame.timestamp_ns, frame.period_ns, frame.inference_budget_ns]);
    for c in &frame.channels {
        put(&mut out, &[c.count, c.p50, c.p99, c.max, c.over_period, c.start_ns, c.end_ns]);
    }
    out.extend_from_slice(&frame.phase.to_le_bytes());
    out.extend_from_slice(&frame.trip.to_le_bytes());
    put(&mut out, &[frame.episode, frame.ticks, frame.policy_beats, frame.starved]);
    let s = &frame.servo;
    let servo = [
        s.commands_sent,
        s.late_commands,
        s.resyncs,
        s.frameless_ticks,
        s.actions_dropped,
        s.starved_ticks,
        s.limit_violations,
    ];
    put(&mut out, &servo);
    let h = &frame.hal;
    put(&mut out, &[h.rejected, h.clamped, h.late, h.position_guard_hits, h.infeasible_steps, h.backend_errors]);
    out.extend_from_slice(&frame.camera);
    debug_assert_eq!(out.len(), LIVE_LEN);
    out
}

/// A frame from its bytes: exactly [`LIVE_LEN`] of them, with the magic and version.
pub fn decode(bytes: &[u8]) -> Result<LiveStats, LiveError> {
    let bytes: &[u8; LIVE_LEN] = bytes.try_into().map_err(|_| LiveError::Length(bytes.len()))?;
    let mut r = Fields { bytes, at: 0 };
    let magic: [u8; 4] = r.take();
    if magic != LIVE_MAGIC {
        return Err(LiveError::Magic(magic));
    }
    let version = u16::from_le_bytes(r.take());
    if version != LIVE_VERSION {
        return Err(LiveError::Version(version));
    }
    let _flags: [u8; 2] = r.take();
    let [seq, timestamp_ns, period_ns, inference_budget_ns] = r.u64s();
    let channels = std::array::from_fn(|_| {
        let [count, p50, p99, max, over_period, start_ns, end_ns] = r.u64s();
        LiveChannel { count, p50, p99, max, over_period, start_ns, end_ns }
    });
    let (phase, trip) = (u32::from_le_bytes(r.take()), u32::from_le_bytes(r.take()));
    let [episode, ticks, policy_beats, starved] = r.u64s();
    let [commands_sent, late_commands, resyncs, frameless_ticks, actions_dropped, starved_ticks, limit_violations] =
        r.u64s();
    let servo = ServoLive {
        commands_sent,
        late_commands,
        resyncs,
        frameless_ticks,
        actions_dropped,
        starved_ticks,
        limit_violations,
    };
    let [rejected, clamped, late, position_guard_hits, infeasible_steps, backend_errors] = r.u64s();
    let hal = HalLive { rejected, clamped, late, position_guard_hits, infeasible_steps, backend_errors };
    let camera = r.take();
    Ok(LiveStats {
        seq,
        timestamp_ns,
        period_ns,
        inference_budget_ns,
        channels,
        phase,
        trip,
        episode,
        ticks,
        policy_beats,
        starved,
        servo,
        hal,
        camera,
    })
}

/// Reads a frame's fields in order (the length was checked once, so no read can run past the end).
struct Fields<'a> {
    bytes: &'a [u8; LIVE_LEN],
    at: usize,
}

impl Fields<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let v = self.bytes[self.at..self.at + N].try_into().expect("N bytes");
        self.at += N;
        v
    }

    fn u64s<const N: usize>(&mut self) -> [u64; N] {
        std::array::from_fn(|_| u64::from_le_bytes(self.take()))
    }
}

/// A daemon's live frames, put on `<prefix>/<robot>/live`.
pub struct LivePublisher {
    publisher: zenoh::pubsub::Publisher<'static>,
}

impl LivePublisher {
    /// Declares the robot's live key on `session` (the daemon's, joined for `[remote]`).
    pub fn declare(session: &zenoh::Session, prefix: &str, robot: &str) -> Result<Self, LinkError> {
        let key = live_key(prefix, robot)?;
        let publisher = session.declare_publisher(key).wait().map_err(|e| LinkError::Open(e.to_string()))?;
        Ok(Self { publisher })
    }

    /// Puts one frame (dropped, not queued, when the link is congested).
    pub fn put(&self, frame: &LiveStats) -> Result<(), LinkError> {
        self.publisher.put(encode(frame)).wait().map_err(|e| LinkError::Open(e.to_string()))
    }
}

/// The live frames of every robot under a prefix (or of one), as they arrive.
pub struct LiveWatch {
    prefix: String,
    subscriber: zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
}

/// One frame received: the robot its key names, and the frame or why it could not be read.
pub type Received = (String, Result<LiveStats, LiveError>);

impl LiveWatch {
    /// Subscribes to `<prefix>/<robot>/live`, or to every robot's with `robot` None.
    pub fn subscribe(session: &zenoh::Session, prefix: &str, robot: Option<&str>) -> Result<Self, LinkError> {
        let key = match robot {
            Some(r) => live_key(prefix, r)?,
            None => all_live_keys(prefix)?,
        };
        let subscriber = session.declare_subscriber(key).wait().map_err(|e| LinkError::Open(e.to_string()))?;
        Ok(Self { prefix: prefix.to_owned(), subscriber })
    }

    /// The next frame within `timeout`; None when none came (or the session closed).
    pub fn next(&self, timeout: std::time::Duration) -> Option<Received> {
        let sample = self.subscriber.recv_timeout(timeout).ok()??;
        let key = sample.key_expr().as_str();
        let robot = robot_of_live(&self.prefix, key).unwrap_or(key).to_owned();
        Some((robot, decode(&sample.payload().to_bytes())))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame with every field different, so a field read in another's place shows.
    fn numbered() -> LiveStats {
        let mut f = LiveStats { seq: 1, timestamp_ns: 2, period_ns: 3, inference_budget_ns: 4, ..Default::default() };
        for (i, c) in f.channels.iter_mut().enumerate() {
            let b = 100 + 10 * i as u64;
            *c = LiveChannel {
                count: b,
                p50: b + 1,
                p99: b + 2,
                max: b + 3,
                over_period: b + 4,
                start_ns: b + 5,
                end_ns: b + 6,
            };
        }
        (f.phase, f.trip, f.episode, f.ticks, f.policy_beats, f.starved) = (5, 6, 7, 8, 9, 10);
        f.servo = ServoLive {
            commands_sent: 11,
            late_commands: 12,
            resyncs: 13,
            frameless_ticks: 14,
            actions_dropped: 15,
            starved_ticks: 16,
            limit_violations: 17,
        };
        f.hal = HalLive {
            rejected: 18,
            clamped: 19,
            late: 20,
            position_guard_hits: 21,
            infeasible_steps: 22,
            backend_errors: u64::MAX,
        };
        f.set_camera_name("wrist");
        f
    }

    #[test]
    fn a_frame_comes_back_as_it_was_sent_in_888_bytes() {
        let f = numbered();
        let bytes = encode(&f);
        assert_eq!((bytes.len(), LIVE_LEN), (888, 888));
        assert_eq!(decode(&bytes), Ok(f));
        // The layout README gives: the first channel's p99 at byte 56, the HAL's last counter before the camera.
        assert_eq!(u64::from_le_bytes(bytes[56..64].try_into().unwrap()), 102);
        assert_eq!(u64::from_le_bytes(bytes[848..856].try_into().unwrap()), u64::MAX);
        assert_eq!(&bytes[856..861], b"wrist");
    }

    #[test]
    fn a_cut_long_or_foreign_frame_is_refused() {
        let bytes = encode(&numbered());
        assert_eq!(decode(&bytes[..887]), Err(LiveError::Length(887)));
        assert_eq!(decode(&[&bytes[..], &[0u8][..]].concat()), Err(LiveError::Length(889)));
        assert_eq!(decode(&[]), Err(LiveError::Length(0)));
        let mut foreign = bytes.clone();
        foreign[..4].copy_from_slice(b"MARQ");
        assert_eq!(decode(&foreign), Err(LiveError::Magic(*b"MARQ")));
        let mut newer = bytes;
        newer[4] = 2;
        assert_eq!(decode(&newer), Err(LiveError::Version(2)));
    }

    #[test]
    fn live_keys_name_the_robot_and_refuse_wildcards() {
        assert_eq!(live_key("mars/lab", "fr3-a").unwrap(), "mars/lab/fr3-a/live");
        assert_eq!(all_live_keys("mars/lab").unwrap(), "mars/lab/*/live");
        assert_eq!(robot_of_live("mars/lab", "mars/lab/fr3-a/live"), Some("fr3-a"));
        assert_eq!(robot_of_live("mars/lab", "mars/lab/x/y/live"), None);
        assert_eq!(robot_of_live("mars/lab", "mars/lab/fr3-a/infer"), None);
        assert!(live_key("mars", "a/b").is_err() && live_key("mars/**", "a").is_err() && all_live_keys("").is_err());
    }
}
