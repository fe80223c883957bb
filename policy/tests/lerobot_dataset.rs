//! `mars train --dataset` on the LeRobot-written fixture (tests/fixtures/lerobot/push_t): a vision policy trains
//! on it and its checkpoint loads and acts; a policy the dataset does not fit is refused before anything is
//! written.

mod mars_cli;

use std::path::{Path, PathBuf};

use mars_cli::mars;
use mars_policy::inference::MarsPolicy;
use mars_tasks::rollout::ChunkPolicy;

const FIXTURE: &str = "tests/fixtures/lerobot/push_t";

/// configs/push_t_policy.toml made small (a 1-epoch test), with `edit` applied to its text.
fn config(dir: &Path, edit: impl Fn(String) -> String) -> PathBuf {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/push_t_policy.toml")).unwrap();
    let text = text
        .replace("width = 16", "width = 4")
        .replace("hidden = 128", "hidden = 16")
        .replace("obs_embed_dim = 128", "obs_embed_dim = 16")
        .replace("scheduler_hidden = 128", "scheduler_hidden = 16");
    let path = dir.join("push_t_tiny.toml");
    std::fs::write(&path, edit(text)).unwrap();
    path
}

fn train(dir: &Path, cfg: &Path, extra: &[&str]) -> (std::process::Output, PathBuf) {
    let out = dir.join("ckpt");
    let mut args = vec!["train", "--dataset", FIXTURE, "--config", cfg.to_str().unwrap(), "--epochs", "1"];
    args.extend_from_slice(&["--out", out.to_str().unwrap()]);
    args.extend_from_slice(extra);
    (mars(&args), out)
}

#[test]
fn a_vision_policy_trains_on_a_lerobot_dataset_and_acts() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path(), |t| t);
    let (out, ckpt) = train(dir.path(), &cfg, &["--image-key", "observation.images.top"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("6 episodes, 180 frames read") && stdout.contains("180 video frames decoded"), "{stdout}");
    let (mut policy, meta) = MarsPolicy::load(&ckpt, 0).unwrap();
    // The first frame of the dataset as the policy sees it: the state, then the image / 255.
    let obs: Vec<f32> = [0.45, 0.0].into_iter().chain(std::iter::repeat_n(0.5, 64 * 64 * 3)).collect();
    let history = [0.45f32, 0.0].repeat(meta.model.history_len);
    let p = policy.predict(&obs, &history).unwrap();
    assert_eq!(p.chunk.len(), meta.model.chunk_len * 2);
    assert!(p.chunk.iter().all(|v| v.is_finite()));
}

#[test]
fn a_policy_the_dataset_does_not_fit_is_refused_before_anything_is_written() {
    let dir = tempfile::tempdir().unwrap();
    type Edit = Box<dyn Fn(String) -> String>;
    let cases: [(&str, Edit, &[&str]); 4] = [
        ("action_dim", Box::new(|t| t.replace("action_dim = 2", "action_dim = 3")), &[]),
        (
            "cameras",
            Box::new(|t| t.replace("cameras = 1", "cameras = 2").replace("obs_dim = 12290", "obs_dim = 24578")),
            &[],
        ),
        ("obs_dim", Box::new(|t| t.replace("obs_dim = 12290", "obs_dim = 12291")), &[]),
        ("key", Box::new(|t| t), &["--state-key", "observation.joints"]),
    ];
    for (what, edit, extra) in cases {
        let cfg = config(dir.path(), edit);
        let (out, ckpt) = train(dir.path(), &cfg, extra);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{what}: trained");
        let said = match what {
            "action_dim" => "has 2 values, the policy's model.action_dim is 3",
            "cameras" => "the policy takes 2 camera(s)",
            "obs_dim" => "make observations of 12290 values; the policy's model.obs_dim is 12291",
            _ => "no feature `observation.joints`",
        };
        assert!(stderr.contains(said), "{what}: {stderr}");
        assert!(!ckpt.exists(), "{what}: a checkpoint directory was written");
    }
}
