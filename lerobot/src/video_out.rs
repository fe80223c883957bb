//! A camera stream written as LeRobot v3.0 writes it: each episode encoded into an MP4 file of its own
//! ([`VideoWriter`]), then its packets copied to the end of the dataset's current video file ([`VideoFile`]; many
//! episodes share a file and each one's frames are found by time). AV1 through SVT-AV1 with LeRobot's own settings
//! (crf 30, a keyframe every 2 frames so a reader can seek to any episode cheaply, yuv420p); H.264 when this FFmpeg
//! has no AV1 encoder.
//!
//! FFmpeg does the work in builds with the `video` feature; a build without it writes state-only datasets and
//! refuses a camera when the writer is created, before any frame ([`crate::video::NO_VIDEO`]).

/// SVT-AV1, the AV1 encoder a recording uses, prints a 16-line banner to stderr for every file it encodes (one
/// per recorded episode): warnings and errors only, unless the user set `SVT_LOG`. Call from main before any
/// thread exists (it sets an environment variable).
pub fn quiet_encoder() {
    if std::env::var_os("SVT_LOG").is_none() {
        // SAFETY: called from main before any thread exists (see above).
        unsafe { std::env::set_var("SVT_LOG", "2") };
    }
}

#[cfg(feature = "video")]
mod ffmpeg_encode;
#[cfg(feature = "video")]
pub use ffmpeg_encode::{VideoFile, VideoWriter};
#[cfg(feature = "video")]
mod no_realtime;
#[cfg(feature = "video")]
pub use no_realtime::realtime_threads_demoted;

#[cfg(not(feature = "video"))]
mod absent;
#[cfg(not(feature = "video"))]
pub use absent::{VideoFile, VideoWriter};
