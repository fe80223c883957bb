//! [`super::decode`] through FFmpeg (the `video` feature).

use std::path::Path;
use std::sync::Once;

use ffmpeg::format::Pixel;
use ffmpeg::software::scaling::{Context as Scaler, Flags};
use ffmpeg::util::frame::Video as VideoFrame;
use ffmpeg_next as ffmpeg;

use super::DecodedVideo;
use crate::LeRobotError;

pub(crate) fn init() {
    static INIT: Once = Once::new();
    INIT.call_once(|| {
        // Our errors say what went wrong; FFmpeg's own log lines would only repeat it on stderr.
        let _ = ffmpeg::init();
        ffmpeg::util::log::set_level(ffmpeg::util::log::Level::Fatal);
    });
}

pub(super) fn decode(path: &Path, width: u32, height: u32) -> Result<DecodedVideo, LeRobotError> {
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
