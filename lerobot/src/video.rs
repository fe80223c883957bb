//! A dataset's video file decoded once, every frame converted (and resized) to RGB8 at the size the policy's
//! encoder takes, with its presentation time. FFmpeg does the work (AV1 through dav1d, H.264, …).

use std::path::Path;
use std::sync::Once;

use ffmpeg::format::Pixel;
use ffmpeg::software::scaling::{Context as Scaler, Flags};
use ffmpeg::util::frame::Video as VideoFrame;
use ffmpeg_next as ffmpeg;

use crate::LeRobotError;

/// The decoded frames of one file, in presentation order.
pub struct DecodedVideo {
    pub width: u32,
    pub height: u32,
    /// Presentation time of each frame, seconds from the file's start.
    pub times_s: Vec<f64>,
    /// `times_s.len()` frames of `height × width × 3` bytes, row-major, no padding.
    pub rgb: Vec<u8>,
}

impl DecodedVideo {
    pub fn frame_len(&self) -> usize {
        (self.width * self.height * 3) as usize
    }

    pub fn frame(&self, i: usize) -> &[u8] {
        let n = self.frame_len();
        &self.rgb[i * n..(i + 1) * n]
    }

    /// The frame shown at `t_s` ([`frame_at`]).
    pub fn frame_at(&self, t_s: f64, tolerance_s: f64) -> Result<usize, f64> {
        frame_at(&self.times_s, t_s, tolerance_s)
    }
}

/// Of frames at `times_s` (ascending), the one shown at `t_s`: the one whose time is nearest, if within
/// `tolerance_s` of it (LeRobot's own reader asks the same of a timestamp, 1e-4 s by default); else the nearest
/// time there is (NaN for no frames).
pub fn frame_at(times_s: &[f64], t_s: f64, tolerance_s: f64) -> Result<usize, f64> {
    let i = times_s.partition_point(|&t| t < t_s);
    let best = [i.checked_sub(1), (i < times_s.len()).then_some(i)]
        .into_iter()
        .flatten()
        .min_by(|&a, &b| (times_s[a] - t_s).abs().total_cmp(&(times_s[b] - t_s).abs()));
    match best {
        Some(j) if (times_s[j] - t_s).abs() <= tolerance_s => Ok(j),
        Some(j) => Err(times_s[j]),
        None => Err(f64::NAN),
    }
}

pub(crate) fn init() {
    static INIT: Once = Once::new();
    INIT.call_once(|| {
        // Our errors say what went wrong; FFmpeg's own log lines would only repeat it on stderr.
        let _ = ffmpeg::init();
        ffmpeg::util::log::set_level(ffmpeg::util::log::Level::Fatal);
    });
}

/// Decodes every frame of the best video stream of `path` to RGB8 at `width × height` (area-averaged when
/// smaller than the file's frames). A read error before the end of the file is an error, not a short video.
pub fn decode(path: &Path, width: u32, height: u32) -> Result<DecodedVideo, LeRobotError> {
    init();
    let fail = |what: &str, e: ffmpeg::Error| LeRobotError::video(path, format!("{what}: {e}"));
    let mut input = ffmpeg::format::input(path).map_err(|e| fail("cannot open (truncated or not a video?)", e))?;
    let stream = input
        .streams()
        .best(ffmpeg::media::Type::Video)
        .ok_or_else(|| LeRobotError::video(path, "has no video stream"))?;
    let (index, time_base) = (stream.index(), f64::from(stream.time_base()));
    let context = ffmpeg::codec::context::Context::from_parameters(stream.parameters())
        .map_err(|e| fail("unreadable stream parameters", e))?;
    let mut decoder = context.decoder().video().map_err(|e| fail("no decoder for its codec", e))?;
    let source_size = (decoder.width(), decoder.height());
    let flags = if width < source_size.0 || height < source_size.1 { Flags::AREA } else { Flags::BILINEAR };
    let mut scaler = Scaler::get(decoder.format(), source_size.0, source_size.1, Pixel::RGB24, width, height, flags)
        .map_err(|e| fail("cannot convert its frames to RGB", e))?;
    let mut out = DecodedVideo { width, height, times_s: Vec::new(), rgb: Vec::new() };
    let (mut frame, mut rgb) = (VideoFrame::empty(), VideoFrame::empty());
    let mut drain = |decoder: &mut ffmpeg::decoder::Video, out: &mut DecodedVideo| -> Result<(), LeRobotError> {
        while decoder.receive_frame(&mut frame).is_ok() {
            let pts =
                frame.timestamp().or(frame.pts()).ok_or_else(|| LeRobotError::video(path, "a frame without a time"))?;
            scaler.run(&frame, &mut rgb).map_err(|e| fail("converting a frame", e))?;
            // Rows of the converted frame are `stride` bytes apart (FFmpeg pads them for alignment).
            let (row, stride) = (width as usize * 3, rgb.stride(0));
            let data = rgb.data(0);
            for y in 0..height as usize {
                out.rgb.extend_from_slice(&data[y * stride..y * stride + row]);
            }
            out.times_s.push(pts as f64 * time_base);
        }
        Ok(())
    };
    let mut packet = ffmpeg::Packet::empty();
    loop {
        match packet.read(&mut input) {
            Ok(()) => {}
            Err(ffmpeg::Error::Eof) => break,
            Err(e) => return Err(fail("reading the file (truncated?)", e)),
        }
        if packet.stream() != index {
            continue;
        }
        decoder.send_packet(&packet).map_err(|e| fail("a packet the decoder refuses (corrupt?)", e))?;
        drain(&mut decoder, &mut out)?;
    }
    // The decoder holds frames back (reordering, frame threads): the end of the file must drain them.
    decoder.send_eof().map_err(|e| fail("ending the stream", e))?;
    drain(&mut decoder, &mut out)?;
    if out.times_s.windows(2).any(|w| w[1] < w[0]) {
        return Err(LeRobotError::video(path, "frames out of presentation order"));
    }
    Ok(out)
}
