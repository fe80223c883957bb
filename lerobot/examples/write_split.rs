//! The LeRobot-written fixture's episodes written again by our writer with small file limits, so that they land in
//! several data and video files (and chunks): a dataset to check with LeRobot itself.
//!
//! cargo run -p mars-lerobot --example write_split -- OUT [DATA_MB VIDEO_MB CHUNKS_SIZE]
//! HF_HUB_OFFLINE=1 /work/lerobot-venv/bin/python tests/fixtures/lerobot/check_with_lerobot.py OUT tests/fixtures/lerobot/push_t
//!
//! Without limits: 0.0034 MB of data and 0.016 MB of video per file (about two and a half of these episodes'
//! rows, and of their video files: about 1.4 KB and 6.7 KB each), two files to a chunk.

use std::path::PathBuf;

// The tests' helpers: the fixture's episodes and our writer at given file limits.
#[path = "../tests/common/mod.rs"]
mod common;

use common::{IMAGE, fixture_episodes, write};
use mars_lerobot::LeRobotDataset;
use mars_lerobot::writer::FileLimits;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let out = PathBuf::from(args.first().expect("usage: write_split OUT [DATA_MB VIDEO_MB CHUNKS_SIZE]"));
    let episodes = fixture_episodes();
    let limits = match &args[1..] {
        [data, video, chunks] => FileLimits {
            data_files_size_in_mb: data.parse().expect("DATA_MB"),
            video_files_size_in_mb: video.parse().expect("VIDEO_MB"),
            chunks_size: chunks.parse().expect("CHUNKS_SIZE"),
        },
        _ => FileLimits { data_files_size_in_mb: 0.0034, video_files_size_in_mb: 0.016, chunks_size: 2 },
    };
    let root = write(&out, &episodes, limits);
    let ds = LeRobotDataset::open(&root).expect("reads back");
    println!("{} with {limits:?}", root.display());
    for e in &ds.episodes {
        let v = e.videos[IMAGE];
        println!(
            "episode {}: data chunk {} file {}; video chunk {} file {} from {:.1} s to {:.1} s",
            e.index, e.data.chunk, e.data.file, v.file.chunk, v.file.file, v.from_s, v.to_s
        );
    }
}
