//! Which camera frames the policy may see: the same kind of gate as [`crate::servo::frame`] for state frames.
//!
//! A camera is any process that publishes `ImageHeader` + `[u8]` on `mars/<robot>/camera/<id>`: the HIL mock, a
//! driver, or a few lines of Python (`examples/python/camera_publisher.py`). A frame is used only if it has this
//! build's schema, a payload as long as its header says, the size and encoding the policy was trained on, a
//! capture time on this machine's CLOCK_MONOTONIC that is neither in the future nor older than the limit, and a
//! sequence number newer than the last frame used. Anything else is counted by reason and never reaches the
//! policy; the first refusal of each kind is worth a log line (the reason says what to fix).
//!
//! Judging and counting allocate nothing, so the policy thread can poll a camera every cycle.

use std::fmt;

use mars_ipc::clock::monotonic_ns;
use mars_ipc::{ImageEncoding, ImageFrame, ImageHeader, ImageReader, ImageReceiveError, SchemaMismatch};

/// What the policy expects of one camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraSpec {
    pub width: u32,
    pub height: u32,
    pub encoding: ImageEncoding,
    /// Oldest capture (capture → read) the policy may act on.
    pub max_age_ns: u64,
}

/// Why a camera frame was not used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraRefusal {
    /// Another schema version: the publisher speaks another revision of the wire.
    Schema(SchemaMismatch),
    /// The payload is not as long as the header's width × height × bytes per pixel.
    Length { expected: Option<usize>, found: usize },
    /// Not the configured width × height.
    Size { width: u32, height: u32, want_width: u32, want_height: u32 },
    /// Not the configured encoding (the raw `u32` when it names none).
    Encoding { found: u32, want: ImageEncoding },
    /// Captured longer ago than the limit.
    Stale { age_ns: u64, max_age_ns: u64 },
    /// Captured "after" it was read: the publisher stamps with another clock than CLOCK_MONOTONIC.
    Future { ahead_ns: u64 },
    /// Not newer than the last frame used (a restarted camera, or a replay).
    OutOfOrder { seq: u64, last_used: u64 },
    /// iceoryx2 could not hand out a frame.
    Port,
}

impl fmt::Display for CameraRefusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::Schema(m) => write!(f, "{m}"),
            Self::Length { expected: Some(e), found } => {
                write!(f, "the payload has {found} bytes where the header's size and encoding make {e}")
            }
            Self::Length { expected: None, found } => {
                write!(f, "the header names an unknown encoding (payload {found} bytes)")
            }
            Self::Size { width, height, want_width, want_height } => write!(
                f,
                "{width}×{height} pixels where the policy expects {want_width}×{want_height} \
                 (set the camera's resolution, or the policy's camera size)"
            ),
            Self::Encoding { found, want } => match ImageEncoding::from_u32(found) {
                Some(e) => write!(f, "encoding {} where the policy expects {}", e.name(), want.name()),
                None => write!(f, "encoding {found} names none (1 rgb8, 2 bgr8, 3 mono8)"),
            },
            Self::Stale { age_ns, max_age_ns } => write!(
                f,
                "captured {:.1} ms before it was read, older than the limit of {:.1} ms",
                age_ns as f64 / 1e6,
                max_age_ns as f64 / 1e6
            ),
            Self::Future { ahead_ns } => write!(
                f,
                "its capture time is {:.3} s after the time it was read: stamp frames with CLOCK_MONOTONIC \
                 (Python: time.monotonic_ns()), not the wall clock",
                ahead_ns as f64 / 1e9
            ),
            Self::OutOfOrder { seq, last_used } => {
                write!(f, "seq {seq} is not newer than the last frame used ({last_used})")
            }
            Self::Port => write!(f, "iceoryx2 could not hand out the frame"),
        }
    }
}

/// Camera frames by verdict.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct CameraCounts {
    pub used: u64,
    /// Newer frames arrived before the policy looked: only the newest usable one is used.
    pub superseded: u64,
    pub schema: u64,
    pub length: u64,
    pub size: u64,
    pub encoding: u64,
    pub stale: u64,
    pub future: u64,
    pub out_of_order: u64,
    pub port: u64,
}

impl CameraCounts {
    pub fn refused(&self) -> u64 {
        self.schema + self.length + self.size + self.encoding + self.stale + self.future + self.out_of_order + self.port
    }

    fn count(&mut self, r: &CameraRefusal) {
        let c = match r {
            CameraRefusal::Schema(_) => &mut self.schema,
            CameraRefusal::Length { .. } => &mut self.length,
            CameraRefusal::Size { .. } => &mut self.size,
            CameraRefusal::Encoding { .. } => &mut self.encoding,
            CameraRefusal::Stale { .. } => &mut self.stale,
            CameraRefusal::Future { .. } => &mut self.future,
            CameraRefusal::OutOfOrder { .. } => &mut self.out_of_order,
            CameraRefusal::Port => &mut self.port,
        };
        *c += 1;
    }
}

/// Judges camera frames against a [`CameraSpec`] and counts the verdicts.
#[derive(Debug, Clone)]
pub struct CameraCheck {
    spec: CameraSpec,
    last_used: Option<u64>,
    pub counts: CameraCounts,
}

impl CameraCheck {
    pub fn new(spec: CameraSpec) -> Self {
        Self { spec, last_used: None, counts: CameraCounts::default() }
    }

    pub fn spec(&self) -> &CameraSpec {
        &self.spec
    }

    /// Judges a frame whose header `h` the reader accepted (schema and length), read at `now_ns`; a usable frame
    /// becomes the last one used.
    pub fn judge(&mut self, h: &ImageHeader, now_ns: u64) -> Result<(), CameraRefusal> {
        let verdict = self.verdict(h, now_ns);
        match &verdict {
            Ok(()) => {
                self.counts.used += 1;
                self.last_used = Some(h.seq);
            }
            Err(r) => self.counts.count(r),
        }
        verdict
    }

    /// Counts a frame the reader refused, and says why.
    pub fn refused_on_receive(&mut self, e: ImageReceiveError) -> CameraRefusal {
        let r = match e {
            ImageReceiveError::Schema(m) => CameraRefusal::Schema(m),
            ImageReceiveError::Length { expected, found, .. } => CameraRefusal::Length { expected, found },
            ImageReceiveError::Port(_) => CameraRefusal::Port,
        };
        self.counts.count(&r);
        r
    }

    fn verdict(&self, h: &ImageHeader, now_ns: u64) -> Result<(), CameraRefusal> {
        let s = &self.spec;
        if (h.width, h.height) != (s.width, s.height) {
            return Err(CameraRefusal::Size {
                width: h.width,
                height: h.height,
                want_width: s.width,
                want_height: s.height,
            });
        }
        if h.encoding != s.encoding as u32 {
            return Err(CameraRefusal::Encoding { found: h.encoding, want: s.encoding });
        }
        if h.timestamp_ns > now_ns {
            return Err(CameraRefusal::Future { ahead_ns: h.timestamp_ns - now_ns });
        }
        let age_ns = now_ns - h.timestamp_ns;
        if age_ns > s.max_age_ns {
            return Err(CameraRefusal::Stale { age_ns, max_age_ns: s.max_age_ns });
        }
        if let Some(last) = self.last_used
            && h.seq <= last
        {
            return Err(CameraRefusal::OutOfOrder { seq: h.seq, last_used: last });
        }
        Ok(())
    }
}

/// What one [`Camera::poll`] found.
pub struct Polled {
    /// The newest usable frame waiting, if any (older usable ones were superseded).
    pub frame: Option<ImageFrame>,
    /// The last refusal among the frames read, for the caller to report.
    pub refusal: Option<CameraRefusal>,
}

/// One camera: its reader and its check.
pub struct Camera {
    reader: ImageReader,
    pub check: CameraCheck,
}

impl Camera {
    pub fn new(reader: ImageReader, spec: CameraSpec) -> Self {
        Self { reader, check: CameraCheck::new(spec) }
    }

    /// Reads every frame waiting and keeps the newest usable one (the policy wants the latest view; an older one it
    /// skips is counted as superseded, not refused). Each is judged at the clock read right after it was received:
    /// a time taken before the poll would make a frame published meanwhile look younger than it is when used (the
    /// servo's state frames had that bug), or, stamped after that time, as if from the future.
    pub fn poll(&mut self) -> Polled {
        let mut out = Polled { frame: None, refusal: None };
        loop {
            match self.reader.receive() {
                Ok(None) => return out,
                Ok(Some(f)) => match self.check.judge(f.header(), monotonic_ns()) {
                    Ok(()) => {
                        if out.frame.replace(f).is_some() {
                            self.check.counts.used -= 1;
                            self.check.counts.superseded += 1;
                        }
                    }
                    Err(r) => out.refusal = Some(r),
                },
                Err(e) => {
                    out.refusal = Some(self.check.refused_on_receive(e));
                    if matches!(e, ImageReceiveError::Port(_)) {
                        return out;
                    }
                }
            }
        }
    }

    /// The newest well-formed frame waiting, read for display only (an episode's last view in the report): not
    /// judged and not counted, and the policy never acts on it. The frames before it are consumed.
    pub fn newest_for_display(&mut self) -> Option<ImageFrame> {
        let mut newest = None;
        while let Ok(Some(f)) = self.reader.receive() {
            newest = Some(f);
        }
        newest
    }

    /// The service this camera is read from.
    pub fn service(&self) -> &str {
        self.reader.service()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn spec() -> CameraSpec {
        CameraSpec { width: 96, height: 96, encoding: ImageEncoding::Rgb8, max_age_ns: 50 * MS }
    }

    fn header(seq: u64, t: u64) -> ImageHeader {
        ImageHeader {
            width: 96,
            height: 96,
            encoding: ImageEncoding::Rgb8 as u32,
            seq,
            timestamp_ns: t,
            ..Default::default()
        }
    }

    #[test]
    fn each_kind_of_bad_frame_is_refused_counted_and_explained() {
        let mut c = CameraCheck::new(spec());
        let now = 1_000 * MS;
        assert_eq!(c.judge(&header(5, now - 10 * MS), now), Ok(()));
        let size = c.judge(&ImageHeader { width: 64, ..header(6, now) }, now).unwrap_err();
        assert_eq!(
            size.to_string(),
            "64×96 pixels where the policy expects 96×96 (set the camera's resolution, or the policy's camera size)"
        );
        let enc = c.judge(&ImageHeader { encoding: ImageEncoding::Bgr8 as u32, ..header(6, now) }, now).unwrap_err();
        assert_eq!(enc.to_string(), "encoding bgr8 where the policy expects rgb8");
        let stale = c.judge(&header(6, now - 51 * MS), now).unwrap_err();
        assert_eq!(stale.to_string(), "captured 51.0 ms before it was read, older than the limit of 50.0 ms");
        // A frame stamped with the wall clock (seconds since 1970) is far "in the future" of CLOCK_MONOTONIC.
        let wall = c.judge(&header(6, 1_764_000_000_000 * MS), now).unwrap_err();
        assert!(matches!(wall, CameraRefusal::Future { .. }) && wall.to_string().contains("CLOCK_MONOTONIC"), "{wall}");
        let replay = c.judge(&header(5, now), now).unwrap_err();
        assert_eq!(replay, CameraRefusal::OutOfOrder { seq: 5, last_used: 5 });
        assert_eq!(c.judge(&header(6, now), now), Ok(()));
        let short = c.refused_on_receive(ImageReceiveError::Length {
            width: 96,
            height: 96,
            encoding: 1,
            expected: Some(27_648),
            found: 100,
        });
        assert_eq!(short.to_string(), "the payload has 100 bytes where the header's size and encoding make 27648");
        let counts = CameraCounts {
            used: 2,
            size: 1,
            encoding: 1,
            stale: 1,
            future: 1,
            out_of_order: 1,
            length: 1,
            ..Default::default()
        };
        assert_eq!(c.counts, counts);
        assert_eq!(c.counts.refused(), 6);
    }

    /// CI (2026-11-26): a frame published between the caller's clock read and the poll's receive was refused as
    /// 1.4 µs "in the future"; the poll now judges a frame at the clock read after receiving it, which is never
    /// before the stamp of a frame on the same clock.
    #[test]
    fn a_frame_judged_when_it_was_read_is_never_from_the_future() {
        let mut c = CameraCheck::new(spec());
        let stamp = monotonic_ns();
        assert_eq!(c.judge(&header(1, stamp), monotonic_ns()), Ok(()));
        // The wall clock is still far ahead of the read time.
        let wall = 1_764_000_000_000 * MS;
        assert!(matches!(c.judge(&header(2, wall), monotonic_ns()), Err(CameraRefusal::Future { .. })));
    }

    #[test]
    fn the_age_limit_is_inclusive_and_a_capture_at_the_read_time_is_fine() {
        let mut c = CameraCheck::new(spec());
        let now = 1_000 * MS;
        assert_eq!(c.judge(&header(1, now - 50 * MS), now), Ok(()));
        assert_eq!(c.judge(&header(2, now), now), Ok(()));
        assert!(matches!(c.judge(&header(3, now + 1), now), Err(CameraRefusal::Future { ahead_ns: 1 })));
    }
}
