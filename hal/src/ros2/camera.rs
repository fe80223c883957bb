//! The robot's cameras as our image frames, off the real-time path.
//!
//! Each `[[ros2.cameras]]` entry gets a thread of its own (`ros2-cam-<n>`, spawned by the I/O thread before the HAL
//! loop starts, so at normal priority and never pinned) that takes the newest `sensor_msgs/CompressedImage` from
//! the robot's topic, decodes its JPEG (zune-jpeg) to RGB8 and publishes it on `mars/<robot>/camera/<id>` as an
//! `ImageHeader` and the pixels, as any camera process of ours does: `marsd camera` and the policy's camera gate
//! read it like any other. The HAL loop never touches a camera; a slow decode delays nothing but the next frame.
//!
//! - **Newest only**: a thread that falls behind skips to the newest frame; skipped frames are counted, not queued.
//! - **Refused, counted, never passed on**: a frame that is not JPEG, that does not decode in full (strict mode: a
//!   truncated frame is an error, not a grey bottom half), or that is not the configured size (nothing is resized:
//!   a policy is trained on one size). The first refusal of each kind is logged with the reason.
//! - **Capture time**: the message's stamp is the robot's wall clock; our frames carry CLOCK_MONOTONIC. The frame
//!   keeps the age the stamp had when it was taken: capture = (monotonic when taken) − (wall clock when taken −
//!   stamp). A stamp of 0, in the future or older than [`STAMP_TRUST`] (the robot's clock is not this machine's:
//!   no NTP/PTP, or simulated time) gives the time it was taken instead, counted as `unstamped`. An age is only
//!   as true as the two clocks agree: sync the robot's computer and this one (PTP, chrony).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use mars_ipc::node::create_node;
use mars_ipc::{ImageEncoding, ImageHeader, ImageWriter, RobotNamespace};
use mars_rt::monotonic_ns;
use ros2_client::dds::Subscription;
use tracing::{info, warn};
use zune_jpeg::JpegDecoder;
use zune_jpeg::zune_core::bytestream::ZCursor;
use zune_jpeg::zune_core::colorspace::ColorSpace;
use zune_jpeg::zune_core::options::DecoderOptions;

use super::message::{CompressedImage, Time, wall_clock};
use super::params::{CameraParams, MAX_CAMERA_SIDE};

/// How often a camera thread looks for a frame (cameras send every 33–100 ms: this adds at most 2 ms).
pub const POLL: Duration = Duration::from_millis(2);
/// The oldest stamp taken as the robot's capture time; an older one says the clocks disagree.
pub const STAMP_TRUST: Duration = Duration::from_secs(5);
/// Samples taken from the topic per round (the newest is kept).
const TAKE_PER_ROUND: usize = 64;

/// One camera's counters.
#[derive(Debug, Default)]
pub struct CameraCounts {
    /// Messages taken from the topic.
    pub taken: AtomicU64,
    /// Frames published as image frames.
    pub published: AtomicU64,
    /// Frames never decoded because a newer one was already there.
    pub skipped: AtomicU64,
    /// Not JPEG (the `format` names another codec and the bytes do not start as a JPEG does).
    pub not_jpeg: AtomicU64,
    /// Not a whole, valid JPEG, or a sample that could not be read off the wire.
    pub undecodable: AtomicU64,
    /// Not the configured width × height.
    pub wrong_size: AtomicU64,
    /// Published with the time it was taken: the stamp was unusable (see the module's doc).
    pub unstamped: AtomicU64,
    /// iceoryx2 refused the frame.
    pub publish_errors: AtomicU64,
}

/// `taken=… published=… …`: every counter, for the HAL's exit log.
impl std::fmt::Display for CameraCounts {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let l = |c: &AtomicU64| c.load(Ordering::Relaxed);
        write!(
            f,
            "taken={} published={} skipped={} not_jpeg={} undecodable={} wrong_size={} unstamped={} publish_errors={}",
            l(&self.taken),
            l(&self.published),
            l(&self.skipped),
            l(&self.not_jpeg),
            l(&self.undecodable),
            l(&self.wrong_size),
            l(&self.unstamped),
            l(&self.publish_errors)
        )
    }
}

/// Why a frame was not published.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Refusal {
    NotJpeg { format: String },
    Undecodable(String),
    WrongSize { width: usize, height: usize },
}

impl Refusal {
    fn kind(&self) -> usize {
        match self {
            Self::NotJpeg { .. } => 0,
            Self::Undecodable(_) => 1,
            Self::WrongSize { .. } => 2,
        }
    }

    fn counter<'a>(&self, c: &'a CameraCounts) -> &'a AtomicU64 {
        match self {
            Self::NotJpeg { .. } => &c.not_jpeg,
            Self::Undecodable(_) => &c.undecodable,
            Self::WrongSize { .. } => &c.wrong_size,
        }
    }
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::NotJpeg { format } => write!(f, "format {format:?} is not JPEG (the bridge decodes JPEG only)"),
            Self::Undecodable(why) => write!(f, "not a whole, valid JPEG: {why}"),
            Self::WrongSize { width, height } => write!(f, "{width}×{height} px, not the configured size"),
        }
    }
}

/// Decodes `msg` into `out` as RGB8 (`width × height × 3` bytes) if it is a JPEG of exactly `width × height`.
pub fn decode(msg: &CompressedImage, width: u32, height: u32, out: &mut Vec<u8>) -> Result<(), Refusal> {
    let data: &[u8] = &msg.data;
    // image_transport names the codec in `format` ("rgb8; jpeg compressed bgr8", "jpeg"); a driver that leaves it
    // empty still sends JPEG's start-of-image marker.
    let format = msg.format.to_ascii_lowercase();
    if !(format.contains("jpeg") || format.contains("jpg") || data.starts_with(&[0xFF, 0xD8])) {
        return Err(Refusal::NotJpeg { format: msg.format.clone() });
    }
    let options = DecoderOptions::default()
        .jpeg_set_out_colorspace(ColorSpace::RGB)
        .set_strict_mode(true)
        .set_max_width(MAX_CAMERA_SIDE as usize)
        .set_max_height(MAX_CAMERA_SIDE as usize);
    let mut decoder = JpegDecoder::new_with_options(ZCursor::new(data), options);
    decoder.decode_headers().map_err(|e| Refusal::Undecodable(e.to_string()))?;
    let (w, h) = decoder.dimensions().ok_or_else(|| Refusal::Undecodable("no frame header".into()))?;
    if (w, h) != (width as usize, height as usize) {
        return Err(Refusal::WrongSize { width: w, height: h });
    }
    out.resize(w * h * 3, 0);
    decoder.decode_into(out).map_err(|e| Refusal::Undecodable(e.to_string()))
}

/// The CLOCK_MONOTONIC capture time of a frame stamped `stamp` (the robot's wall clock) that was taken at
/// `taken_ns` (monotonic) when this machine's wall clock read `taken_wall`; `None` when the stamp is unusable.
pub fn capture_ns(stamp: Time, taken_ns: u64, taken_wall: Duration) -> Option<u64> {
    if stamp.sec <= 0 && stamp.nanosec == 0 {
        return None;
    }
    let stamp = Duration::new(u64::try_from(stamp.sec).ok()?, stamp.nanosec);
    let age = taken_wall.checked_sub(stamp)?;
    if age > STAMP_TRUST {
        return None;
    }
    taken_ns.checked_sub(age.as_nanos() as u64)
}

/// The camera threads, stopped by the I/O thread's stop flag.
pub struct Cameras {
    handles: Vec<JoinHandle<()>>,
}

impl Cameras {
    /// Starts one thread per camera and returns once each has its image service open, or why one could not.
    pub fn start(
        subs: Vec<Subscription<CompressedImage>>,
        cams: &[CameraParams],
        robot: &str,
        stop: &Arc<AtomicBool>,
        counts: &[Arc<CameraCounts>],
    ) -> anyhow::Result<Self> {
        let mut started = Self { handles: Vec::new() };
        for (i, ((sub, cam), counts)) in subs.into_iter().zip(cams).zip(counts).enumerate() {
            let (ready_tx, ready_rx) = std::sync::mpsc::channel();
            let (cam, robot, thread_stop, counts) = (cam.clone(), robot.to_owned(), stop.clone(), counts.clone());
            let handle =
                std::thread::Builder::new().name(format!("ros2-cam-{i}")).spawn(move || {
                    match Bridge::open(&robot, &cam) {
                        Ok(bridge) => {
                            let _ = ready_tx.send(Ok(()));
                            bridge.serve(&sub, &thread_stop, &counts);
                        }
                        Err(e) => {
                            let _ = ready_tx.send(Err(e));
                        }
                    }
                })?;
            started.handles.push(handle);
            match ready_rx.recv() {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    stop.store(true, Ordering::Release);
                    started.join();
                    return Err(e);
                }
                Err(_) => anyhow::bail!("camera thread {i} ended while opening"),
            }
        }
        Ok(started)
    }

    /// Waits for every camera thread (after the stop flag was set).
    pub fn join(self) {
        for h in self.handles {
            if h.join().is_err() {
                warn!("a camera thread panicked");
            }
        }
    }
}

/// One camera's image service and decode buffer.
struct Bridge {
    cam: CameraParams,
    service: String,
    writer: ImageWriter,
    // The writer's node: it must outlive the writer's port.
    _node: iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>,
}

impl Bridge {
    fn open(robot: &str, cam: &CameraParams) -> anyhow::Result<Self> {
        let ns = RobotNamespace::new(robot)?;
        let (node, _) = create_node(&format!("hal-camera-{}", cam.id))?;
        let len = cam.width as usize * cam.height as usize * 3;
        let writer = ImageWriter::new(&node, &ns, &cam.id, len)?;
        let service = ns.camera(&cam.id)?.as_str().to_owned();
        Ok(Self { cam: cam.clone(), service, writer, _node: node })
    }

    fn serve(self, sub: &Subscription<CompressedImage>, stop: &AtomicBool, counts: &CameraCounts) {
        let c = &self.cam;
        let mut pixels = Vec::with_capacity(c.width as usize * c.height as usize * 3);
        let mut seq = 0u64;
        let mut logged = [false; 3];
        while !stop.load(Ordering::Acquire) {
            let mut newest = None;
            for _ in 0..TAKE_PER_ROUND {
                match sub.take() {
                    Ok(Some((m, _))) => {
                        counts.taken.fetch_add(1, Ordering::Relaxed);
                        if newest.is_some() {
                            counts.skipped.fetch_add(1, Ordering::Relaxed);
                        }
                        newest = Some((m, monotonic_ns(), wall_clock()));
                    }
                    Ok(None) => break,
                    Err(e) => {
                        if counts.undecodable.fetch_add(1, Ordering::Relaxed) == 0 {
                            warn!(camera = %c.id, "a sample on {} could not be read: {e:?}", c.topic);
                        }
                    }
                }
            }
            let Some((msg, taken_ns, taken_wall)) = newest else {
                std::thread::park_timeout(POLL);
                continue;
            };
            if let Err(r) = decode(&msg, c.width, c.height, &mut pixels) {
                r.counter(counts).fetch_add(1, Ordering::Relaxed);
                if !std::mem::replace(&mut logged[r.kind()], true) {
                    warn!(camera = %c.id, "a frame on {} refused: {r} (expected {}×{} JPEG); counted, not published",
                        c.topic, c.width, c.height);
                }
                continue;
            }
            let capture = capture_ns(msg.header.stamp, taken_ns, taken_wall).unwrap_or_else(|| {
                counts.unstamped.fetch_add(1, Ordering::Relaxed);
                taken_ns
            });
            seq += 1;
            let header = ImageHeader {
                width: c.width,
                height: c.height,
                encoding: ImageEncoding::Rgb8 as u32,
                seq,
                timestamp_ns: capture,
                ..Default::default()
            };
            match self.writer.send_with(header, |px| px.copy_from_slice(&pixels)) {
                Ok(_) => {
                    if counts.published.fetch_add(1, Ordering::Relaxed) == 0 {
                        info!(camera = %c.id, "first frame from {} published on {}", c.topic, self.service);
                    }
                }
                Err(e) => {
                    if counts.publish_errors.fetch_add(1, Ordering::Relaxed) == 0 {
                        warn!(camera = %c.id, "publishing on {} failed: {e}", self.service);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros2::message::Header;

    /// A JPEG of `w × h` in four flat quadrants, written by the `image` crate's encoder (not ours, not zune's).
    fn jpeg(w: u32, h: u32) -> Vec<u8> {
        let img = image::RgbImage::from_fn(w, h, |x, y| match (x < w / 2, y < h / 2) {
            (true, true) => image::Rgb([200, 40, 40]),
            (false, true) => image::Rgb([40, 200, 40]),
            (true, false) => image::Rgb([40, 40, 200]),
            (false, false) => image::Rgb([128, 128, 128]),
        });
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90).encode_image(&img).unwrap();
        out
    }

    fn msg(format: &str, data: Vec<u8>) -> CompressedImage {
        CompressedImage { header: Header::default(), format: format.into(), data: serde_bytes::ByteBuf::from(data) }
    }

    #[test]
    fn a_jpeg_of_the_configured_size_decodes_to_its_rgb_pixels() {
        let (w, h) = (64, 48);
        let mut px = Vec::new();
        decode(&msg("rgb8; jpeg compressed bgr8", jpeg(w, h)), w, h, &mut px).unwrap();
        assert_eq!(px.len(), (w * h * 3) as usize);
        let at = |x: u32, y: u32| &px[((y * w + x) * 3) as usize..][..3];
        for (x, y, want) in [(8, 8, [200, 40, 40]), (56, 8, [40, 200, 40]), (8, 40, [40, 40, 200]), (56, 40, [128; 3])]
        {
            let got = at(x, y);
            assert!(got.iter().zip(want).all(|(g, w)| (*g as i32 - w).abs() <= 6), "({x}, {y}): {got:?} vs {want:?}");
        }
    }

    #[test]
    fn other_sizes_truncated_frames_and_other_codecs_are_refused() {
        let mut px = Vec::new();
        let good = jpeg(64, 48);
        assert_eq!(
            decode(&msg("jpeg", good.clone()), 64, 32, &mut px),
            Err(Refusal::WrongSize { width: 64, height: 48 })
        );
        let cut = good[..good.len() * 2 / 3].to_vec();
        assert!(matches!(decode(&msg("jpeg", cut), 64, 48, &mut px), Err(Refusal::Undecodable(_))));
        let png = b"\x89PNG\r\n\x1a\n".to_vec();
        assert_eq!(decode(&msg("png", png), 64, 48, &mut px), Err(Refusal::NotJpeg { format: "png".into() }));
        // An empty format with JPEG's marker is decoded.
        decode(&msg("", good), 64, 48, &mut px).unwrap();
    }

    #[test]
    fn the_capture_time_keeps_the_stamp_s_age_unless_the_stamp_is_unusable() {
        let wall = Duration::new(1_700_000_000, 500_000_000);
        let stamp = |d: Duration| Time { sec: d.as_secs() as i32, nanosec: d.subsec_nanos() };
        let taken = 10_000_000_000;
        assert_eq!(capture_ns(stamp(wall - Duration::from_millis(30)), taken, wall), Some(taken - 30_000_000));
        assert_eq!(capture_ns(Time::default(), taken, wall), None, "a zero stamp");
        assert_eq!(capture_ns(stamp(wall + Duration::from_millis(1)), taken, wall), None, "in the future");
        assert_eq!(capture_ns(stamp(wall - Duration::from_secs(6)), taken, wall), None, "older than the trust");
        assert_eq!(capture_ns(Time { sec: -1, nanosec: 0 }, taken, wall), None);
    }
}
