//! What the split and cache tests share: the LeRobot-written fixture, its episodes, and those episodes written
//! again by our writer (at file limits of the test's choosing).

use std::path::{Path, PathBuf};

use mars_lerobot::writer::{CameraSpec, DatasetSpec, DatasetWriter, FileLimits, VectorSpec};
use mars_lerobot::{EpisodeFrames, Keys, LeRobotDataset, ReadOptions};

pub const IMAGE: &str = "observation.images.top";
pub const TASK: &str = "push the T block into its goal pose";
/// The fixture's frames: 64 × 64 RGB.
pub const FRAME: usize = 64 * 64 * 3;

pub fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/lerobot/push_t")
}

pub fn keys() -> Keys {
    Keys { state: "observation.state".into(), action: "action".into(), images: vec![IMAGE.into()] }
}

/// The fixture's six episodes (180 frames), read without the cache.
pub fn fixture_episodes() -> Vec<EpisodeFrames> {
    let ds = LeRobotDataset::open(&fixture()).unwrap();
    ds.read_with(&keys(), (64, 64), &ReadOptions::no_cache()).unwrap().0
}

/// `episodes` written as a dataset at `root`, its files split at `limits`.
pub fn write(root: &Path, episodes: &[EpisodeFrames], limits: FileLimits) -> PathBuf {
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
    let mut w = DatasetWriter::create_with_limits(root, spec, limits).unwrap();
    for e in episodes {
        for t in 0..e.len {
            let img = &e.images[0][t * FRAME..(t + 1) * FRAME];
            w.add_frame(&[&e.state[t * 2..t * 2 + 2], &e.action[t * 2..t * 2 + 2]], &[img]).unwrap();
        }
        w.end_episode(TASK).unwrap();
    }
    w.finish().unwrap()
}
