//! A video encoder's threads run under the normal scheduler, whoever runs it: SVT-AV1 (LeRobot's encoder) run as
//! root makes its threads SCHED_FIFO 99, above a robot's servo loop — marsd records while the arm moves.
#![cfg(feature = "video")]

use mars_lerobot::video_out::{VideoWriter, realtime_threads_demoted};

/// This process's threads under SCHED_FIFO or SCHED_RR, as "tid comm policy/priority", from /proc (stat's fields
/// 40 and 41: rt_priority and policy).
fn realtime_threads() -> Vec<String> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc/self/task").unwrap() {
        let path = entry.unwrap().path();
        let Ok(stat) = std::fs::read_to_string(path.join("stat")) else { continue };
        let (head, tail) = stat.rsplit_once(") ").unwrap();
        let fields: Vec<&str> = tail.split_whitespace().collect();
        let (priority, policy) = (fields[40 - 3], fields[41 - 3]);
        if policy == "1" || policy == "2" {
            found.push(format!("{head}) policy {policy} priority {priority}"));
        }
    }
    found
}

#[test]
fn an_open_encoder_has_no_realtime_thread() {
    let euid = std::fs::read_to_string("/proc/self/status").unwrap();
    let euid = euid.lines().find(|l| l.starts_with("Uid:")).unwrap().split_whitespace().nth(2).unwrap().to_owned();
    let dir = tempfile::tempdir().unwrap();
    let mut writer = VideoWriter::create(&dir.path().join("episode.mp4"), 64, 64, 30).unwrap();
    let while_open = realtime_threads();
    for i in 0..8u8 {
        writer.push(&[i * 30; 64 * 64 * 3]).unwrap();
    }
    let while_encoding = realtime_threads();
    let codec = writer.codec;
    writer.finish().unwrap();
    eprintln!(
        "{codec} encoder, effective uid {euid}: real-time threads open {while_open:?}, encoding {while_encoding:?}; \
         threads set back after opening: {}",
        realtime_threads_demoted()
    );
    assert!(while_open.is_empty() && while_encoding.is_empty(), "{while_open:?} {while_encoding:?}");
}
