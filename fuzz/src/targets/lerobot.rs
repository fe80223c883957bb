//! LeRobot v3.0: `meta/info.json`, the episodes' metadata (parquet), and a whole dataset opened and read as
//! `mars train --dataset` and `marsd replay` read one. Seeds: the LeRobot-written fixture and a state-only dataset
//! our writer makes at start.

use std::path::{Path, PathBuf};

use mars_lerobot::demos::{RestAction, to_demos};
use mars_lerobot::info::Info as InfoJson;
use mars_lerobot::table::Table;
use mars_lerobot::writer::{DatasetSpec, DatasetWriter, VectorSpec};
use mars_lerobot::{Keys, LeRobotDataset, ReadOptions, episodes};
use rand::rngs::StdRng;

use super::{Seeds, bundle_seeds, generate_bundle, split_bundle};
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
pub struct Info {
    seeds: Seeds,
}

impl Info {
    pub fn new() -> Self {
        Self { seeds: Seeds { files: datasets().into_iter().map(|mut d| d.remove(0)).collect(), text: true } }
    }
}

impl Target for Info {
    fn name(&self) -> &'static str {
        "lerobot-info"
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        self.seeds.pick(rng).1
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        self.seeds.files.clone()
    }

    fn run(&self, input: &[u8]) -> bool {
        // The product reads info.json with `read_to_string`: not UTF-8 is an I/O error there.
        let Ok(text) = std::str::from_utf8(input) else { return false };
        let Ok(info) = InfoJson::parse(text, PathBuf::from("meta/info.json")) else { return false };
        let ds = LeRobotDataset { root: PathBuf::from("dataset"), info, episodes: Vec::new() };
        for (key, f) in &ds.info.features {
            let _ = (f.len(), ds.vector_len(key), ds.image_size(key));
        }
        for (chunk, file) in [(0, 0), (-1, 999), (i64::MAX, i64::MIN)] {
            let _ = ds.info.file_path(&ds.root, &ds.info.data_path, None, chunk, file);
            if let Some(template) = &ds.info.video_path {
                for key in ds.info.features.keys() {
                    let _ = ds.info.file_path(&ds.root, template, Some(key), chunk, file);
                }
            }
        }
        true
    }
}

/// An episodes parquet file, read with its dataset's `info.json` and checked as `LeRobotDataset::open` does.
pub struct Episodes {
    bundles: Vec<Vec<Vec<u8>>>,
    infos: Vec<InfoJson>,
}

impl Episodes {
    pub fn new() -> Self {
        let bundles: Vec<Vec<Vec<u8>>> = datasets().into_iter().map(|d| vec![d[1].clone()]).collect();
        let infos = datasets()
            .iter()
            .map(|d| InfoJson::parse(std::str::from_utf8(&d[0]).expect("UTF-8"), "info.json".into()).expect("a seed"))
            .collect();
        Self { bundles, infos }
    }
}

impl Target for Episodes {
    fn name(&self) -> &'static str {
        "lerobot-episodes"
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        generate_bundle(rng, &self.bundles, |_| false)
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        bundle_seeds(&self.bundles)
    }

    fn run(&self, input: &[u8]) -> bool {
        let Some((b, _, bytes)) = split_bundle(input, self.bundles.len()) else { return false };
        let info = &self.infos[b];
        let columns = episodes::columns(info);
        let columns: Vec<&str> = columns.iter().map(String::as_str).collect();
        let path = Path::new("meta/episodes/chunk-000/file-000.parquet");
        let Ok(t) = Table::from_bytes(path, bytes.to_vec(), Some(&columns)) else { return false };
        episodes::from_table(&t, info).and_then(|e| episodes::check(e, info)).is_ok()
    }
}

/// A whole dataset on disk, one of its three files mutated: opened, its episodes read (state and action, as a
/// state policy and `marsd replay` read them) and made into training demos.
pub struct Dataset {
    bundles: Vec<Vec<Vec<u8>>>,
    dir: tempfile::TempDir,
}

impl Dataset {
    pub fn new() -> Self {
        Self { bundles: datasets(), dir: tempfile::tempdir().expect("a temporary folder") }
    }
}

impl Target for Dataset {
    fn name(&self) -> &'static str {
        "lerobot-dataset"
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        generate_bundle(rng, &self.bundles, |f| f == 0)
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        bundle_seeds(&self.bundles)
    }

    fn run(&self, input: &[u8]) -> bool {
        let Some((b, f, bytes)) = split_bundle(input, self.bundles.len()) else { return false };
        let root = self.dir.path();
        for (i, name) in FILES.iter().enumerate() {
            let path = root.join(name);
            std::fs::create_dir_all(path.parent().expect("a folder")).expect("the case's folder");
            std::fs::write(&path, if i == f % FILES.len() { bytes } else { &self.bundles[b][i] }).expect("a case file");
        }
        let Ok(ds) = LeRobotDataset::open(root) else { return false };
        let keys = Keys { state: "observation.state".into(), action: "action".into(), images: vec![] };
        let (Ok(s), Ok(a)) = (ds.vector_len(&keys.state), ds.vector_len(&keys.action)) else { return false };
        let Ok((eps, _)) = ds.read_with(&keys, (0, 0), &ReadOptions::no_cache()) else { return false };
        let _ = to_demos(&eps, s, a, RestAction::FirstState);
        to_demos(&eps, s, a, RestAction::FirstAction).is_ok()
    }
}
