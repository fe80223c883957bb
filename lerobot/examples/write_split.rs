//! The LeRobot-written fixture's episodes written again by our writer with small file limits, so that they land in
//! several data and video files (and chunks): a dataset to check with LeRobot itself.
//!
//! cargo run -p mars-lerobot --example write_split -- OUT [DATA_MB VIDEO_MB CHUNKS_SIZE]
//! HF_HUB_OFFLINE=1 /work/lerobot-venv/bin/python tests/fixtures/lerobot/check_with_lerobot.py OUT tests/fixtures/lerobot/push_t
//!
//! Without limits: 0.0034 MB of data and 0.016 MB of video per file (about two and a half of these episodes'
//! rows, and of their video files: about 1.4 KB and 6.7 KB each), two files to a chunk.

use std::path::{Path, PathBuf};

use mars_lerobot::writer::{CameraSpec, DatasetSpec, DatasetWriter, FileLimits, VectorSpec};
use mars_lerobot::{EpisodeFrames, Keys, LeRobotDataset, ReadOptions};

const IMAGE: &str = "observation.images.top";
const FRAME: usize = 64 * 64 * 3;

fn write(root: &Path, episodes: &[EpisodeFrames], limits: FileLimits) -> PathBuf {
    let xy = vec!["x".to_owned(), "y".to_owned()];
    let spec = DatasetSpec {
        fps: 10,
        robot_type: "fr3".into(),
        vectors: vec![
            VectorSpec { key: "observation.state".into(), names: xy.clone() },
            VectorSpec { key: "action".into(), names: xy },
        ],
        cameras: vec![CameraSpec { key: IMAGE.into(), height: 64, width: 64 }],
    };
    let mut w = DatasetWriter::create_with_limits(root, spec, limits).expect("a new dataset");
    for e in episodes {
        for t in 0..e.len {
            let img = &e.images[0][t * FRAME..(t + 1) * FRAME];
            w.add_frame(&[&e.state[t * 2..t * 2 + 2], &e.action[t * 2..t * 2 + 2]], &[img]).expect("a frame");
        }
        w.end_episode(&e.tasks[0]).expect("an episode");
    }
    w.finish().expect("the dataset")
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let out = PathBuf::from(args.first().expect("usage: write_split OUT [DATA_MB VIDEO_MB CHUNKS_SIZE]"));
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/lerobot/push_t");
    let keys = Keys { state: "observation.state".into(), action: "action".into(), images: vec![IMAGE.into()] };
    let (episodes, _) = LeRobotDataset::open(&fixture)
        .and_then(|ds| ds.read_with(&keys, (64, 64), &ReadOptions::no_cache()))
        .expect("the fixture");
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
