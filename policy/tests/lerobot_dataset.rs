//! `mars train --dataset` on the LeRobot-written fixture (tests/fixtures/lerobot/push_t): a vision policy trains
//! on it and its checkpoint loads and acts; a policy the dataset does not fit is refused before anything is
//! written.

mod mars_cli;

use std::path::{Path, PathBuf};

use mars_cli::mars_with_env;
#[cfg(feature = "video")]
use mars_policy::inference::MarsPolicy;
#[cfg(feature = "video")]
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

/// `mars train --dataset FIXTURE` into `dir/<out>`, with the decoded-frame cache in `dir/cache`.
fn train_into(dir: &Path, out: &str, cfg: &Path, extra: &[&str]) -> (std::process::Output, PathBuf) {
    let out = dir.join(out);
    let mut args = vec!["train", "--dataset", FIXTURE, "--config", cfg.to_str().unwrap(), "--epochs", "1"];
    args.extend_from_slice(&["--out", out.to_str().unwrap()]);
    args.extend_from_slice(extra);
    (mars_with_env(&args, &[("MARS_CACHE_DIR", &dir.join("cache"))]), out)
}

fn train(dir: &Path, cfg: &Path, extra: &[&str]) -> (std::process::Output, PathBuf) {
    train_into(dir, "ckpt", cfg, extra)
}

#[cfg(feature = "video")] // it reads the fixture's camera
#[test]
fn a_vision_policy_trains_on_a_lerobot_dataset_and_acts() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path(), |t| t);
    let (out, ckpt) = train(dir.path(), &cfg, &["--image-key", "observation.images.top"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("6 episodes, 180 frames read") && stdout.contains("180 video frames decoded"), "{stdout}");
    assert!(!stdout.contains("from the decoded-frame cache"), "{stdout}");
    // A second run decodes nothing: every frame comes from the cache the first one wrote.
    let (again, _) = train_into(dir.path(), "ckpt2", &cfg, &["--image-key", "observation.images.top"]);
    let again_out = String::from_utf8_lossy(&again.stdout);
    assert!(again.status.success(), "{again_out}");
    assert!(again_out.contains("180 video frames from the decoded-frame cache"), "{again_out}");
    assert!(!again_out.contains("decoded in"), "{again_out}");
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

/// `--normalize-from stats`: the checkpoint carries the mean and std of the dataset's meta/stats.json (made
/// different here from what the frames give, so the two sources can be told apart), cameras raw; by default it
/// carries the frames' own; without a stats.json, `stats` is refused before anything is written.
#[cfg(feature = "video")] // it reads the fixture's camera
#[test]
fn normalisation_comes_from_stats_json_when_asked_and_from_the_frames_otherwise() {
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("push_t");
    copy_dir(&Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(FIXTURE), &copy);
    let stats_path = copy.join("meta/stats.json");
    let mut stats: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&stats_path).unwrap()).unwrap();
    stats["action"]["mean"] = serde_json::json!([5.0, -5.0]);
    stats["action"]["std"] = serde_json::json!([2.0, 3.0]);
    stats["observation.state"]["mean"] = serde_json::json!([1.5, 2.5]);
    stats["observation.state"]["std"] = serde_json::json!([0.25, 0.0]);
    std::fs::write(&stats_path, stats.to_string()).unwrap();
    let cfg = config(dir.path(), |t| t);
    let train = |out: &str, extra: &[&str]| {
        let out = dir.path().join(out);
        let mut args = vec!["train", "--dataset", copy.to_str().unwrap(), "--config", cfg.to_str().unwrap()];
        args.extend_from_slice(&["--epochs", "1", "--out", out.to_str().unwrap()]);
        args.extend_from_slice(extra);
        (mars_with_env(&args, &[("MARS_CACHE_DIR", &dir.path().join("cache"))]), out)
    };
    let (run, ckpt) = train("from-stats", &["--normalize-from", "stats"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let n = mars_policy::checkpoint::load_meta(&ckpt).unwrap().normalizer;
    assert_eq!((n.action.mean.as_slice(), n.action.std.as_slice()), (&[5.0f32, -5.0][..], &[2.0f32, 3.0][..]));
    // A std of 0 is left unscaled (1), as for statistics computed from the frames; the pixels stay raw.
    assert_eq!((&n.obs.mean[..2], &n.obs.std[..2]), (&[1.5f32, 2.5][..], &[0.25f32, 1.0][..]));
    assert!(n.obs.mean[2..].iter().all(|m| *m == 0.0) && n.obs.std[2..].iter().all(|s| *s == 1.0));
    let (run, ckpt) = train("from-data", &[]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let n = mars_policy::checkpoint::load_meta(&ckpt).unwrap().normalizer;
    // The frames' own: the fixture's pusher x is around 0.32 m (LeRobot's own stats.json said 0.3241).
    assert!((n.action.mean[0] - 0.3241).abs() < 1e-3, "{:?}", n.action);
    std::fs::remove_file(&stats_path).unwrap();
    let (run, ckpt) = train("no-stats", &["--normalize-from", "stats"]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success() && err.contains("stats.json") && err.contains("--normalize-from data"), "{err}");
    assert!(!ckpt.exists(), "a refused run wrote {}", ckpt.display());
}

#[cfg(feature = "video")]
fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

/// A build without FFmpeg refuses a camera key before anything is written, saying how to build one that reads it.
#[cfg(not(feature = "video"))]
#[test]
fn without_video_support_a_camera_is_refused_with_the_remedy_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path(), |t| t);
    let (out, ckpt) = train(dir.path(), &cfg, &["--image-key", "observation.images.top"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--features video"), "{err}");
    assert!(!ckpt.exists(), "a checkpoint was written");
}

/// `mars train --dataset` with no `--config`, on the LeRobot-written fixture: the policy's features come from its
/// meta/info.json (the state's 2 values and the 64 × 64 camera in, 2 actions out), the rest from the shipped vision
/// defaults; the config is printed and written beside the checkpoint, and it is what the checkpoint holds.
#[cfg(feature = "video")] // it reads the fixture's camera
#[test]
fn with_no_config_the_policys_features_come_from_the_lerobot_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ckpt");
    let args = ["train", "--dataset", FIXTURE, "--epochs", "1", "--out", out.to_str().unwrap()];
    let run = mars_with_env(&args, &[("MARS_CACHE_DIR", &dir.path().join("cache"))]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&run.stderr));
    assert!(
        stdout.contains("no --config: the policy's features from") && stdout.contains("obs_dim = 12290"),
        "{stdout}"
    );
    let written = mars_policy::config::PolicyConfig::load(&out.join("config.toml")).unwrap();
    assert_eq!((written.model.obs_dim, written.model.action_dim), (2 + 64 * 64 * 3, 2));
    let mars_policy::config::EncoderConfig::Vision(v) = &written.model.encoder else { panic!("{written:?}") };
    assert_eq!((v.cameras, v.image_height, v.image_width), (1, 64, 64));
    // The checkpoint's is the same but for k_full_w, which training measures (a quantile of ‖w‖∞).
    let mut trained = mars_policy::checkpoint::load_meta(&out).unwrap().model;
    trained.k_full_w = written.model.k_full_w;
    assert_eq!(trained, written.model);
}

/// The same with a dataset of another shape and no camera (an FR3 recording's: 9 state values, 8 actions, as
/// `marsd --record` writes it), which the nav2d defaults refused before ("the dataset's `action` has 8 values, the
/// policy's model.action_dim is 2"): a state policy of those sizes trains.
#[test]
fn with_no_config_a_state_dataset_of_any_size_trains() {
    use mars_lerobot::writer::{DatasetSpec, DatasetWriter, VectorSpec};
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("fr3_rec");
    let names = |n: usize, p: &str| (0..n).map(|i| format!("{p}{i}")).collect::<Vec<_>>();
    let spec = DatasetSpec {
        fps: 10,
        robot_type: "fr3".into(),
        vectors: vec![
            VectorSpec { key: "observation.state".into(), names: names(9, "s") },
            VectorSpec { key: "action".into(), names: names(8, "a") },
        ],
        cameras: vec![],
    };
    let mut w = DatasetWriter::create(&root, spec).unwrap();
    for e in 0..3 {
        for t in 0..12 {
            let state: Vec<f32> = (0..9).map(|i| (e * 12 + t + i) as f32 * 0.01).collect();
            let action: Vec<f32> = (0..8).map(|i| (e * 12 + t + i + 1) as f32 * 0.01).collect();
            w.add_frame(&[&state, &action], &[]).unwrap();
        }
        w.end_episode("pick cup").unwrap();
    }
    w.finish().unwrap();
    let out = dir.path().join("ckpt");
    let run = mars_with_env(
        &["train", "--dataset", root.to_str().unwrap(), "--epochs", "1", "--out", out.to_str().unwrap()],
        &[],
    );
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let written = mars_policy::config::PolicyConfig::load(&out.join("config.toml")).unwrap();
    assert_eq!((written.model.obs_dim, written.model.action_dim), (9, 8));
    assert!(matches!(written.model.encoder, mars_policy::config::EncoderConfig::StateMlp { .. }), "{written:?}");
    let mut meta = mars_policy::checkpoint::load_meta(&out).unwrap();
    meta.model.k_full_w = written.model.k_full_w; // measured by training
    assert_eq!((meta.kind, &meta.model, &meta.train), (written.kind, &written.model, &written.train));
}
