//! A dataset's video file decoded once, every frame converted (and resized) to RGB8 at the size the policy's
//! encoder takes, with its presentation time. FFmpeg does the work (AV1 through dav1d, H.264, …), in builds with
//! the `video` feature ([`ffmpeg_decode`]); a build without it reads state-only datasets and refuses a video with
//! a message that says how to build one that reads it.

use std::path::Path;

use crate::LeRobotError;

#[cfg(feature = "video")]
mod ffmpeg_decode;
#[cfg(feature = "video")]
pub(crate) use ffmpeg_decode::init;

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
        self.width as usize * self.height as usize * 3
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

/// Decodes every frame of the best video stream of `path` to RGB8 at `width × height` (area-averaged when
/// smaller than the file's frames). A read error before the end of the file is an error, not a short video.
pub fn decode(path: &Path, width: u32, height: u32) -> Result<DecodedVideo, LeRobotError> {
    #[cfg(feature = "video")]
    return ffmpeg_decode::decode(path, width, height);
    #[cfg(not(feature = "video"))]
    {
        let _ = (width, height);
        Err(LeRobotError::video(path, NO_VIDEO))
    }
}

/// Whether this build reads and writes videos (the `video` feature).
pub const SUPPORTED: bool = cfg!(feature = "video");

/// Why a build without FFmpeg refuses a video file, and what to do about it.
pub const NO_VIDEO: &str = "this build has no video support (FFmpeg): build with `--features video` \
    (needs FFmpeg's development libraries, libclang and pkg-config; Debian: libavcodec-dev libavformat-dev \
    libavutil-dev libswscale-dev libclang-dev pkg-config)";
