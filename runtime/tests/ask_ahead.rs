//! `[policy] ask_ahead_periods` and `continuity` as marsd reads them: parsed, and refused before anything moves where
//! they cannot work (half the checkpoint's chunk or more; with a recording or a replay, which hold whole chunks).

use std::path::{Path, PathBuf};

use mars_runtime::config::{Continuity, DaemonConfig};
use mars_runtime::daemon;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn config(policy_lines: &str) -> DaemonConfig {
    let text = std::fs::read_to_string(root().join("configs/marsd.toml")).unwrap();
    let text = text.replace("handoff_margin_ms = 2.0", &format!("handoff_margin_ms = 2.0\n{policy_lines}"));
    let mut cfg = DaemonConfig::parse(&text, "marsd.toml").unwrap();
    for p in [&mut cfg.profile, &mut cfg.task, &mut cfg.checkpoint] {
        *p = root().join(&p);
    }
    cfg
}

fn refusal(cfg: DaemonConfig) -> String {
    match daemon::prepare(cfg) {
        Ok(_) => panic!("prepared"),
        Err(e) => format!("{e:#}"),
    }
}

#[test]
fn the_keys_parse_with_their_defaults() {
    let cfg = config("");
    assert_eq!((cfg.policy.ask_ahead_periods, cfg.policy.continuity), (0, Continuity::Guided));
    let cfg = config("ask_ahead_periods = 2\ncontinuity = \"drop-late\"");
    assert_eq!((cfg.policy.ask_ahead_periods, cfg.policy.continuity), (2, Continuity::DropLate));
    let text = std::fs::read_to_string(root().join("configs/marsd.toml")).unwrap();
    let bad = text.replace("handoff_margin_ms = 2.0", "handoff_margin_ms = 2.0\ncontinuity = \"sideways\"");
    let err = DaemonConfig::parse(&bad, "marsd.toml").unwrap_err().to_string();
    assert!(err.contains("sideways") || err.contains("unknown variant"), "{err}");
}

#[test]
fn asking_half_a_chunk_ahead_or_more_is_refused_before_anything_moves() {
    let err = refusal(config("ask_ahead_periods = 4"));
    assert!(err.contains("ask_ahead_periods = 4: at most 3 for the checkpoint's chunk of 8 actions"), "{err}");
}

#[test]
fn asking_ahead_with_a_recording_is_refused() {
    let mut cfg = config("ask_ahead_periods = 2");
    cfg.record = Some(std::env::temp_dir().join(format!("mars-ask-ahead-{}", std::process::id())));
    let err = refusal(cfg);
    assert!(err.contains("not with policy.ask_ahead_periods > 0"), "{err}");
}

/// `[remote] auto_ask_ahead` chooses `ask_ahead_periods`: not both in one file, and not with a recording (refused
/// before the host is asked anything).
#[test]
fn auto_ask_ahead_is_refused_beside_a_count_or_a_recording() {
    let text = std::fs::read_to_string(root().join("configs/marsd.toml")).unwrap();
    let remote = "\n[remote]\nconnect = [\"tcp/127.0.0.1:9\"]\nauto_ask_ahead = true\n";
    let both = text.replace("handoff_margin_ms = 2.0", "handoff_margin_ms = 2.0\nask_ahead_periods = 1") + remote;
    let err = format!("{:#}", DaemonConfig::parse(&both, "marsd.toml").unwrap_err());
    assert!(err.contains("remote.auto_ask_ahead") && err.contains("give one of the two"), "{err}");
    let mut cfg = DaemonConfig::parse(&(text + remote), "marsd.toml").unwrap();
    assert!(cfg.remote.as_ref().unwrap().auto_ask_ahead);
    for p in [&mut cfg.profile, &mut cfg.task, &mut cfg.checkpoint] {
        *p = root().join(&p);
    }
    cfg.record = Some(std::env::temp_dir().join(format!("mars-auto-ahead-{}", std::process::id())));
    let err = refusal(cfg);
    assert!(err.contains("[remote] auto_ask_ahead"), "{err}");
}
