//! What the lerobot tests (and the write_split example) share: the LeRobot-written fixture, a copy of it to
//! change, its episodes, and those episodes written again by our writer (at file limits of the test's choosing).
#![allow(dead_code)] // each test binary uses a part

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

/// The fixture's features as our writer declares them.
pub fn spec() -> DatasetSpec {
    let xy = vec!["x".to_owned(), "y".to_owned()];
    DatasetSpec {
        fps: 10,
        robot_type: "fr3".into(),
        vectors: vec![
            VectorSpec { key: "observation.state".into(), names: xy.clone() },
            VectorSpec { key: "action".into(), names: xy },
        ],
        cameras: vec![CameraSpec { key: IMAGE.into(), height: 64, width: 64 }],
    }
}

pub fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), target).unwrap();
        }
    }
}

/// A copy of the fixture, to change or break.
pub fn copy() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    copy_dir(&fixture(), dir.path());
    dir
}

/// `episodes` written as a dataset at `root`, its files split at `limits`.
pub fn write(root: &Path, episodes: &[EpisodeFrames], limits: FileLimits) -> PathBuf {
    let mut w = DatasetWriter::create_with_limits(root, spec(), limits).unwrap();
    for e in episodes {
        for t in 0..e.len {
            let img = &e.images[0][t * FRAME..(t + 1) * FRAME];
            w.add_frame(&[&e.state[t * 2..t * 2 + 2], &e.action[t * 2..t * 2 + 2]], &[img]).unwrap();
        }
        w.end_episode(TASK).unwrap();
    }
    w.finish().unwrap()
}
