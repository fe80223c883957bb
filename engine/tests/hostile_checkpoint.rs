//! Checkpoint sizes that used to run for seconds a call, abort or panic (issue 33, section 5): `k_max` of 10⁵ (a
//! call took 2.9 s), 10⁹ (the engine asked for 256 GB and aborted), 2⁶³ (its buffer size overflowed,
//! `buffers.rs:72`), and a camera image of 2³² pixels a side (`image_len` overflowed, `policy/src/config.rs:103`).
//! Each is now refused at load, naming the field and the limit.

use std::path::{Path, PathBuf};

use mars_engine::{Engine, EngineConfig};
use mars_policy::checkpoint::META_FILE;

fn checkpoint_copy(name: &str, dir: &Path) -> PathBuf {
    let from = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/checkpoints").join(name);
    let to = dir.join(name.replace('/', "-"));
    std::fs::create_dir_all(&to).unwrap();
    for f in ["policy.json", "model.safetensors"] {
        std::fs::copy(from.join(f), to.join(f)).unwrap();
    }
    to
}

fn with_meta(ckpt: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let path = ckpt.join(META_FILE);
    let mut meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut meta);
    std::fs::write(&path, serde_json::to_string(&meta).unwrap()).unwrap();
}

fn load_err(ckpt: &Path) -> String {
    match Engine::load(ckpt, EngineConfig::with_seed(0)) {
        Ok(e) => panic!("{} loaded with k_max {}", ckpt.display(), e.k_max()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_k_max_beyond_the_limit_is_refused_at_load() {
    let dir = tempfile::tempdir().unwrap();
    for k in [100_000u64, 1_000_000_000, 1 << 63] {
        let ckpt = checkpoint_copy("fr3_pick_cup/mars", dir.path());
        with_meta(&ckpt, |m| m["model"]["k_max"] = k.into());
        let e = load_err(&ckpt);
        assert!(e.contains("model.k_max") && e.contains("limit of 1000"), "k_max {k}: {e}");
    }
    // The limit itself loads (and its buffers are what the engine allocates for it).
    let ckpt = checkpoint_copy("fr3_pick_cup/mars", dir.path());
    with_meta(&ckpt, |m| m["model"]["k_max"] = 1000.into());
    assert_eq!(
        Engine::load(&ckpt, EngineConfig { warmup_calls: 1, ..EngineConfig::with_seed(0) }).unwrap().k_max(),
        1000
    );
}

#[test]
fn camera_image_sizes_beyond_the_limit_are_refused_at_load() {
    let dir = tempfile::tempdir().unwrap();
    // 2³² × 2³² × 3 overflowed `image_len` (a panic); one side alone passed to the obs_dim check.
    let cases: [(&str, &[(&str, u64)]); 3] = [
        ("image_height", &[("image_height", 1 << 32), ("image_width", 1 << 32)]),
        ("image_width", &[("image_width", (1 << 32) + 64)]),
        ("cameras", &[("cameras", 1 << 40)]),
    ];
    for (field, edits) in cases {
        let ckpt = checkpoint_copy("fr3_push_t/mars", dir.path());
        with_meta(&ckpt, |m| edits.iter().for_each(|(k, v)| m["model"]["encoder"][*k] = (*v).into()));
        let e = load_err(&ckpt);
        assert!(e.contains(&format!("model.encoder.{field}")) && e.contains("limit"), "{edits:?}: {e}");
    }
}
