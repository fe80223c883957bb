//! LeRobot v3.0: `meta/info.json`, the episodes' metadata (parquet), and a whole dataset opened and read as
//! `mars train --dataset` and `marsd replay` read one. Seeds: the LeRobot-written fixture and a state-only dataset
//! our writer makes at start.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use mars_lerobot::demos::{RestAction, to_demos};
use mars_lerobot::info::Info;
use mars_lerobot::table::Table;
use mars_lerobot::writer::{DatasetSpec, DatasetWriter, VectorSpec};
use mars_lerobot::{Keys, LeRobotDataset, ReadOptions, episodes};

use super::{Bundles, text};
use crate::runner::Target;

const FIXTURE: &str = "tests/fixtures/lerobot/push_t";
const FILES: [&str; 3] =
    ["meta/info.json", "meta/episodes/chunk-000/file-000.parquet", "data/chunk-000/file-000.parquet"];

/// The three files of the fixture and of a dataset our writer makes (4 episodes of 2-value state and action).
fn datasets() -> Vec<Vec<Vec<u8>>> {
    let ours = tempfile::tempdir().expect("a temporary folder");
    let root = ours.path().join("ours");
    let xy = || vec!["x".to_owned(), "y".to_owned()];
    let spec = DatasetSpec {
        fps: 10,
        robot_type: "fr3".into(),
        vectors: vec![
            VectorSpec { key: "observation.state".into(), names: xy() },
            VectorSpec { key: "action".into(), names: xy() },
        ],
        cameras: vec![],
    };
    let mut w = DatasetWriter::create(&root, spec).expect("writing the seed dataset");
    for e in 0..4 {
        for t in 0..(3 + e) {
            let (state, action) = ([e as f32, t as f32 * 0.5], [t as f32 * 0.5, -(e as f32)]);
            w.add_frame(&[&state[..], &action[..]], &[]).expect("a frame");
        }
        w.end_episode("push").expect("an episode");
    }
    w.finish().expect("the seed dataset");
    let files = |root: &Path| FILES.iter().map(|f| std::fs::read(root.join(f)).expect("a seed file")).collect();
    vec![files(&super::repo(FIXTURE)), files(&root)]
}

/// `meta/info.json` alone, then every feature's size and every path template used as the reader uses them.
pub fn info() -> Arc<dyn Target> {
    let files = datasets().into_iter().map(|mut d| d.remove(0)).collect();
    Bundles::of_files("lerobot-info", files, true, |_, bytes| {
        let Some(Ok(info)) = text(bytes).map(|t| Info::parse(t, PathBuf::from("meta/info.json"))) else { return false };
        let ds = LeRobotDataset { root: PathBuf::from("dataset"), info, episodes: Vec::new() };
        for (key, f) in &ds.info.features {
            let _ = (f.len(), ds.vector_len(key), ds.image_size(key));
        }
        for (chunk, file) in [(0, 0), (-1, 999), (i64::MAX, i64::MIN)] {
            let _ = ds.info.file_path(&ds.root, &ds.info.data_path, None, chunk, file);
            for key in ds.info.features.keys() {
                let _ = ds.info.video_path.as_ref().map(|t| ds.info.file_path(&ds.root, t, Some(key), chunk, file));
            }
        }
        true
    })
}

/// An episodes parquet file, read with its dataset's `info.json` and checked as `LeRobotDataset::open` does.
pub fn episodes() -> Arc<dyn Target> {
    let sets = datasets();
    let parse = |d: &Vec<Vec<u8>>| Info::parse(text(&d[0]).expect("UTF-8"), "info.json".into()).expect("a seed");
    let infos: Vec<Info> = sets.iter().map(parse).collect();
    let files = sets.into_iter().map(|mut d| d.remove(1)).collect();
    Bundles::of_files("lerobot-episodes", files, false, move |b, bytes| {
        let info = &infos[b];
        let columns = episodes::columns(info);
        let columns: Vec<&str> = columns.iter().map(String::as_str).collect();
        let path = Path::new("meta/episodes/chunk-000/file-000.parquet");
        let Ok(t) = Table::from_bytes(path, bytes.to_vec(), Some(&columns)) else { return false };
        episodes::from_table(&t, info).and_then(|e| episodes::check(e, info)).is_ok()
    })
}

/// A whole dataset on disk, one of its three files mutated: opened, its episodes read (state and action, as a
/// state policy and `marsd replay` read them) and made into training demos.
pub fn dataset() -> Arc<dyn Target> {
    let bundles = datasets();
    let seeds = bundles.clone();
    let dir = tempfile::tempdir().expect("a temporary folder");
    let decode = move |b: usize, f: usize, bytes: &[u8]| {
        let root = dir.path();
        for (i, name) in FILES.iter().enumerate() {
            let path = root.join(name);
            std::fs::create_dir_all(path.parent().expect("a folder")).expect("the case's folder");
            std::fs::write(&path, if i == f { bytes } else { &seeds[b][i] }).expect("a case file");
        }
        let Ok(ds) = LeRobotDataset::open(root) else { return false };
        let keys = Keys { state: "observation.state".into(), action: "action".into(), images: vec![] };
        let (Ok(s), Ok(a)) = (ds.vector_len(&keys.state), ds.vector_len(&keys.action)) else { return false };
        let Ok((eps, _)) = ds.read_with(&keys, (0, 0), &ReadOptions::no_cache()) else { return false };
        let _ = to_demos(&eps, s, a, RestAction::FirstState);
        to_demos(&eps, s, a, RestAction::FirstAction).is_ok()
    };
    Arc::new(Bundles { name: "lerobot-dataset", bundles, text: |f| f == 0, decode: Box::new(decode) })
}
