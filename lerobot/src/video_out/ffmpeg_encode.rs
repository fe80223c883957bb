//! [`super::VideoWriter`] and [`super::VideoFile`] through FFmpeg (the `video` feature).

use std::ops::{Deref, DerefMut};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use ffmpeg::Rescale;
use ffmpeg::format::Pixel;
use ffmpeg::software::scaling::{Context as Scaler, Flags};
use ffmpeg::util::frame::Video as VideoFrame;
use ffmpeg_next as ffmpeg;

use crate::LeRobotError;

/// Encoders tried in order: LeRobot's default, then others a Debian FFmpeg has. (name, info.json's codec,
/// options)
type EncoderChoice = (&'static str, &'static str, &'static [(&'static str, &'static str)]);
const ENCODERS: [EncoderChoice; 3] = [
    ("libsvtav1", "av1", &[("crf", "30"), ("preset", "12")]),
    ("libaom-av1", "av1", &[("crf", "30"), ("cpu-used", "8")]),
    ("libx264", "h264", &[("crf", "23"), ("preset", "veryfast")]),
];
/// LeRobot's `g`: a keyframe every 2 frames.
const GOP: u32 = 2;

/// Held while an encoder is opened or closed in this process.
static ENCODER_LIFECYCLE: Mutex<()> = Mutex::new(());

/// An open encoder whose opening and closing hold [`ENCODER_LIFECYCLE`]: SVT-AV1 1.4.1 crashed (SIGSEGV inside
/// `svt_av1_enc_init_handle`, from a core dump) when one thread opened an encoder while another closed its own —
/// the parallel lerobot tests under load, 2 runs in 25. marsd records from one thread, but nothing here may
/// assume that. Encoding itself runs unlocked.
///
/// It is also never closed without its end of stream, nor with an end of stream and no frame: SVT-AV1 1.4.1 then
/// waits for ever (closed so, "deinit called without sending EOS!"; or in `svt_av1_enc_get_packet` at the end of
/// an empty stream, from a debugger) — marsd hung after a trip in its first recorded episode, its recording
/// abandoned. An encoder dropped unfinished is given a blank frame if it had none, ended and drained.
struct Encoder {
    encoder: Option<ffmpeg::encoder::Video>,
    frames_sent: u64,
    eof_sent: bool,
}

impl Encoder {
    fn open(
        enc: ffmpeg::encoder::video::Video,
        codec: ffmpeg::Codec,
        options: ffmpeg::Dictionary,
    ) -> Result<Self, ffmpeg::Error> {
        let _lifecycle = ENCODER_LIFECYCLE.lock().unwrap_or_else(|e| e.into_inner());
        // A failed open frees its context here too, under the lock. Its threads start normal (SVT-AV1 as root
        // would make them SCHED_FIFO 99, above a robot's loops).
        super::no_realtime::open_without_realtime(|| enc.open_as_with(codec, options)).map(|e| Self {
            encoder: Some(e),
            frames_sent: 0,
            eof_sent: false,
        })
    }

    fn send_frame(&mut self, frame: &VideoFrame) -> Result<(), ffmpeg::Error> {
        (**self).send_frame(frame)?;
        self.frames_sent += 1;
        Ok(())
    }

    /// Ends the stream (the packets still to come are then received until `Eof`).
    fn send_eof(&mut self) -> Result<(), ffmpeg::Error> {
        self.eof_sent = true;
        (**self).send_eof()
    }
}

impl Deref for Encoder {
    type Target = ffmpeg::encoder::Video;
    fn deref(&self) -> &Self::Target {
        self.encoder.as_ref().expect("open until dropped")
    }
}

impl DerefMut for Encoder {
    fn deref_mut(&mut self) -> &mut Self::Target {
        self.encoder.as_mut().expect("open until dropped")
    }
}

impl Drop for Encoder {
    fn drop(&mut self) {
        if !self.eof_sent {
            // An abandoned stream: ended (after a blank frame if it had none) and its last packets received and
            // dropped, so the encoder can close.
            if self.frames_sent == 0 {
                let (format, width, height) = (self.format(), self.width(), self.height());
                let _ = self.send_frame(&VideoFrame::new(format, width, height));
            }
            if self.frames_sent > 0 && self.send_eof().is_ok() {
                let mut packet = ffmpeg::Packet::empty();
                while (**self).receive_packet(&mut packet).is_ok() {}
            }
        }
        let _lifecycle = ENCODER_LIFECYCLE.lock().unwrap_or_else(|e| e.into_inner());
        drop(self.encoder.take());
    }
}

pub struct VideoWriter {
    path: PathBuf,
    output: ffmpeg::format::context::Output,
    encoder: Encoder,
    scaler: Scaler,
    rgb: VideoFrame,
    yuv: VideoFrame,
    width: u32,
    height: u32,
    fps: i32,
    stream_time_base: ffmpeg::Rational,
    frames: i64,
    /// `video.codec` as LeRobot's info.json names it.
    pub codec: &'static str,
}

impl VideoWriter {
    /// Opens `path` (an .mp4) for `width × height` RGB frames at `fps`.
    pub fn create(path: &Path, width: u32, height: u32, fps: u32) -> Result<Self, LeRobotError> {
        crate::video::init();
        let fail = |what: &str, e: ffmpeg::Error| LeRobotError::video(path, format!("{what}: {e}"));
        let mut last_error = String::from("no AV1 or H.264 encoder in this FFmpeg");
        for (name, codec_name, options) in ENCODERS {
            let Some(codec) = ffmpeg::encoder::find_by_name(name) else { continue };
            let mut output = ffmpeg::format::output(path).map_err(|e| fail("cannot create", e))?;
            let global_header = output.format().flags().contains(ffmpeg::format::Flags::GLOBAL_HEADER);
            output.add_stream(codec).map_err(|e| fail("cannot add a video stream", e))?;
            let mut enc = ffmpeg::codec::context::Context::new_with_codec(codec)
                .encoder()
                .video()
                .map_err(|e| fail("not a video encoder", e))?;
            enc.set_width(width);
            enc.set_height(height);
            enc.set_format(Pixel::YUV420P);
            enc.set_time_base((1, fps as i32));
            enc.set_frame_rate(Some((fps as i32, 1)));
            enc.set_gop(GOP);
            if global_header {
                enc.set_flags(ffmpeg::codec::Flags::GLOBAL_HEADER);
            }
            let mut dict = ffmpeg::Dictionary::new();
            for (k, v) in options {
                dict.set(k, v);
            }
            let encoder = match Encoder::open(enc, codec, dict) {
                Ok(e) => e,
                Err(e) => {
                    // e.g. a size the encoder does not take: the next one may.
                    last_error = format!("{name}: {e}");
                    continue;
                }
            };
            output.stream_mut(0).expect("the stream just added").set_parameters(&*encoder);
            output.write_header().map_err(|e| fail("cannot write the header", e))?;
            let stream_time_base = output.stream(0).expect("the stream just added").time_base();
            let scaler = Scaler::get(Pixel::RGB24, width, height, Pixel::YUV420P, width, height, Flags::BILINEAR)
                .map_err(|e| fail("no RGB → YUV conversion", e))?;
            return Ok(Self {
                path: path.to_owned(),
                output,
                encoder,
                scaler,
                rgb: VideoFrame::new(Pixel::RGB24, width, height),
                yuv: VideoFrame::empty(),
                width,
                height,
                fps: fps as i32,
                stream_time_base,
                frames: 0,
                codec: codec_name,
            });
        }
        Err(LeRobotError::video(path, format!("cannot open an encoder: {last_error}")))
    }

    /// Frames written so far (the next frame's time is `frames / fps`).
    pub fn frames(&self) -> i64 {
        self.frames
    }

    /// Appends one frame: `height × width × 3` bytes, row-major RGB.
    pub fn push(&mut self, rgb: &[u8]) -> Result<(), LeRobotError> {
        let row = self.width as usize * 3;
        if rgb.len() != row * self.height as usize {
            return Err(LeRobotError::video(
                &self.path,
                format!("a frame of {} bytes, not {}×{}×3", rgb.len(), self.height, self.width),
            ));
        }
        let stride = self.rgb.stride(0);
        let data = self.rgb.data_mut(0);
        for (y, src) in rgb.chunks_exact(row).enumerate() {
            data[y * stride..y * stride + row].copy_from_slice(src);
        }
        self.scaler
            .run(&self.rgb, &mut self.yuv)
            .map_err(|e| LeRobotError::video(&self.path, format!("converting a frame: {e}")))?;
        self.yuv.set_pts(Some(self.frames));
        self.frames += 1;
        self.encoder.send_frame(&self.yuv).map_err(|e| LeRobotError::video(&self.path, format!("encoding: {e}")))?;
        self.write_packets()
    }

    fn write_packets(&mut self) -> Result<(), LeRobotError> {
        let mut packet = ffmpeg::Packet::empty();
        while self.encoder.receive_packet(&mut packet).is_ok() {
            packet.set_stream(0);
            packet.rescale_ts((1, self.fps), self.stream_time_base);
            packet
                .write_interleaved(&mut self.output)
                .map_err(|e| LeRobotError::video(&self.path, format!("writing: {e}")))?;
        }
        Ok(())
    }

    /// Drains the encoder and closes the file.
    pub fn finish(mut self) -> Result<(), LeRobotError> {
        self.encoder.send_eof().map_err(|e| LeRobotError::video(&self.path, format!("ending the stream: {e}")))?;
        self.write_packets()?;
        self.output.write_trailer().map_err(|e| LeRobotError::video(&self.path, format!("closing: {e}")))
    }
}

/// One of the dataset's video files, open while episodes are appended to it: each episode's own file copied in
/// packet by packet (no re-encode), its times shifted to follow the frames already there. LeRobot concatenates
/// the same way (`concatenate_video_files`, a stream copy), but rewrites the whole file for every episode; this
/// keeps the file open and writes its index once, at [`VideoFile::finish`].
pub struct VideoFile {
    path: PathBuf,
    output: ffmpeg::format::context::Output,
    time_base: ffmpeg::Rational,
    fps: i32,
    frames: i64,
    bytes: u64,
}

impl VideoFile {
    /// Starts `path` with the stream parameters of `episode`, an episode's file (every episode is encoded with the
    /// same settings, so the first one's parameters are every one's).
    pub fn create(path: &Path, episode: &Path, fps: u32) -> Result<Self, LeRobotError> {
        crate::video::init();
        let fail = |what: &str, e: ffmpeg::Error| LeRobotError::video(path, format!("{what}: {e}"));
        let input =
            ffmpeg::format::input(episode).map_err(|e| LeRobotError::video(episode, format!("cannot open: {e}")))?;
        let stream = input
            .streams()
            .best(ffmpeg::media::Type::Video)
            .ok_or_else(|| LeRobotError::video(episode, "has no video stream"))?;
        let mut output = ffmpeg::format::output(path).map_err(|e| fail("cannot create", e))?;
        {
            let mut out = output
                .add_stream(ffmpeg::encoder::find(ffmpeg::codec::Id::None))
                .map_err(|e| fail("cannot add a video stream", e))?;
            out.set_parameters(stream.parameters());
            out.set_time_base(stream.time_base());
            out.set_rate(stream.rate());
            out.set_avg_frame_rate(stream.avg_frame_rate());
        }
        output.write_header().map_err(|e| fail("cannot write the header", e))?;
        let time_base = output.stream(0).expect("the stream just added").time_base();
        Ok(Self { path: path.to_owned(), output, time_base, fps: fps as i32, frames: 0, bytes: 0 })
    }

    /// Frames in the file so far (the next episode starts at `frames / fps` seconds).
    pub fn frames(&self) -> i64 {
        self.frames
    }

    /// The appended episodes' own files' bytes, summed: what LeRobot's rule weighs as the file's size (its file
    /// has one header and index for all its episodes, a few hundred bytes per episode less than this).
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// Copies `episode` (a file of `frames` frames, as [`VideoWriter`] wrote it) to the end of this file.
    pub fn append(&mut self, episode: &Path, frames: i64) -> Result<(), LeRobotError> {
        let fail = |what: &str, e: ffmpeg::Error| LeRobotError::video(episode, format!("{what}: {e}"));
        let bytes =
            std::fs::metadata(episode).map_err(|error| LeRobotError::Read { path: episode.to_owned(), error })?.len();
        let mut input = ffmpeg::format::input(episode).map_err(|e| fail("cannot open", e))?;
        let (index, time_base) = {
            let s = input
                .streams()
                .best(ffmpeg::media::Type::Video)
                .ok_or_else(|| LeRobotError::video(episode, "has no video stream"))?;
            (s.index(), s.time_base())
        };
        let shift = self.frames.rescale((1, self.fps), self.time_base);
        let mut packet = ffmpeg::Packet::empty();
        loop {
            match packet.read(&mut input) {
                Ok(()) => {}
                Err(ffmpeg::Error::Eof) => break,
                Err(e) => return Err(fail("reading", e)),
            }
            if packet.stream() != index {
                continue;
            }
            packet.rescale_ts(time_base, self.time_base);
            packet.set_pts(packet.pts().map(|t| t + shift));
            packet.set_dts(packet.dts().map(|t| t + shift));
            packet.set_position(-1);
            packet.set_stream(0);
            packet
                .write_interleaved(&mut self.output)
                .map_err(|e| LeRobotError::video(&self.path, format!("writing: {e}")))?;
        }
        self.frames += frames;
        self.bytes += bytes;
        Ok(())
    }

    /// Writes the file's index and closes it.
    pub fn finish(mut self) -> Result<(), LeRobotError> {
        self.output.write_trailer().map_err(|e| LeRobotError::video(&self.path, format!("closing: {e}")))
    }
}
