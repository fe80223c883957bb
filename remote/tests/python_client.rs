//! A client in another language: tests/peers/remote_client.py (Zenoh's Python binding, the wire encoded and decoded
//! from README's description) asks a host in this process for chunks; each is the local engine's, bit for bit.

mod support;

use std::io::Write;
use std::process::{Command, Stdio};
use std::time::Duration;

use support::*;

#[test]
fn a_python_zenoh_client_gets_the_local_engines_chunks() {
    let python = python();
    let prefix = format!("mars-test/{}/python", std::process::id());
    let host = Host::start(&prefix, &["fr3"]);
    let mut local = engine();
    // The last two carry committed rows (one, then two): the host's call is guided toward them.
    let d = local.action_dim();
    let requests: Vec<_> = (1..=4u64)
        .map(|seq| {
            let mut r = request(&local, seq);
            r.committed = r.history[..seq.saturating_sub(2) as usize * d].to_vec();
            r
        })
        .collect();
    let job = serde_json::json!({
        "connect": host.locator, "prefix": prefix, "robot": "fr3",
        "requests": requests.iter().map(|r| serde_json::json!({
            "seq": r.seq, "episode": r.episode, "period": r.period, "budget_ns": r.budget_ns, "seed": r.seed,
            "observation": r.observation, "history": r.history, "committed": r.committed,
        })).collect::<Vec<_>>(),
    });
    let mut child = Command::new(&python)
        .arg(repo().join("tests/peers/remote_client.py"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("starting the Python client");
    child.stdin.take().unwrap().write_all(job.to_string().as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "the Python client failed ({})", out.status);
    let lines: Vec<serde_json::Value> =
        String::from_utf8(out.stdout).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), requests.len());
    for (r, got) in requests.iter().zip(&lines) {
        local.reseed(r.seed);
        let want = local.infer_after(&r.observation, &r.history, &r.committed, Duration::from_secs(2)).unwrap();
        let chunk: Vec<f32> = got["chunk"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect();
        assert_eq!((got["seq"].as_u64(), got["status"].as_u64()), (Some(r.seq), Some(0)), "{got}");
        assert_eq!(chunk, want.chunk, "seq {}", r.seq);
        assert_eq!(got["k_used"].as_u64(), Some(want.k_used as u64));
    }
    assert_eq!(host.stop().robots["fr3"].chunks, requests.len() as u64);
}
