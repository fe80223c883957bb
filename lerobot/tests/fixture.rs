//! The reader against files LeRobot itself wrote (tests/fixtures/lerobot/push_t, made with LeRobot 0.6.1; its
//! README says how), and against what LeRobot reads back from them (push_t_expected.json).

use std::path::Path;

mod common;

use common::{fixture, keys};
use mars_lerobot::{Keys, LeRobotDataset, ReadOptions};
use serde_json::Value;

fn expected() -> Value {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/lerobot/push_t_expected.json");
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

fn f32s(v: &Value) -> Vec<f32> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap() as f32).collect()
}

#[test]
fn episodes_and_vectors_equal_what_lerobot_reads_bit_for_bit() {
    let want = expected();
    let ds = LeRobotDataset::open(&fixture()).unwrap();
    assert_eq!(ds.info.fps, want["fps"].as_f64().unwrap());
    assert_eq!(ds.episodes.len(), want["total_episodes"].as_u64().unwrap() as usize);
    // The vectors alone (a build without FFmpeg reads them too).
    let vectors = Keys { images: vec![], ..keys() };
    let (episodes, report) = ds.read_with(&vectors, (64, 64), &ReadOptions::no_cache()).unwrap();
    assert_eq!(report.frames, want["total_frames"].as_u64().unwrap() as usize);
    let frames = want["frames"].as_array().unwrap();
    let mut i = 0;
    for (e, we) in episodes.iter().zip(want["episodes"].as_array().unwrap()) {
        assert_eq!(e.len, we["length"].as_u64().unwrap() as usize);
        for t in 0..e.len {
            let f = &frames[i];
            assert_eq!(f["episode_index"].as_i64().unwrap(), e.index);
            assert_eq!(f["frame_index"].as_u64().unwrap() as usize, t);
            assert_eq!(e.state[t * 2..t * 2 + 2], f32s(&f["observation.state"])[..], "episode {} frame {t}", e.index);
            assert_eq!(e.action[t * 2..t * 2 + 2], f32s(&f["action"])[..], "episode {} frame {t}", e.index);
            assert_eq!(e.timestamps[t] as f32, f["timestamp"].as_f64().unwrap() as f32);
            assert_eq!(e.tasks, vec![f["task"].as_str().unwrap().to_owned()]);
            i += 1;
        }
    }
    assert_eq!(i, frames.len());
}

#[cfg(feature = "video")]
/// The same frames as LeRobot decodes (torchcodec over FFmpeg 7, here FFmpeg 5.1 through ffmpeg-next): AV1
/// decodes exactly by its specification, and both convert YUV → RGB with FFmpeg's swscale, so every byte agrees.
#[test]
fn video_frames_equal_what_lerobot_decodes() {
    let want = expected();
    let ds = LeRobotDataset::open(&fixture()).unwrap();
    let (episodes, report) = ds.read_with(&keys(), (64, 64), &ReadOptions::no_cache()).unwrap();
    assert_eq!(report.decoded_frames, 180, "one file, every frame decoded once");
    let frames = want["frames"].as_array().unwrap();
    let (mut i, mut worst_full, mut worst_mean, mut full_frames) = (0, 0u8, 0f64, 0);
    for e in &episodes {
        let images = &e.images[0];
        assert_eq!(images.len(), e.len * 64 * 64 * 3);
        for t in 0..e.len {
            let ours = &images[t * 12288..(t + 1) * 12288];
            let f = &frames[i];
            for c in 0..3 {
                let mean = ours.iter().skip(c).step_by(3).map(|&p| f64::from(p)).sum::<f64>() / 4096.0;
                let theirs = f["image_channel_mean_255"][c].as_f64().unwrap();
                worst_mean = worst_mean.max((mean - theirs).abs());
            }
            if let Some(full) = f.get("image_hwc_u8").and_then(Value::as_array) {
                full_frames += 1;
                for (a, b) in ours.iter().zip(full) {
                    worst_full = worst_full.max(a.abs_diff(b.as_u64().unwrap() as u8));
                }
            }
            i += 1;
        }
    }
    println!(
        "vs LeRobot: worst pixel difference {worst_full} over {full_frames} full frames, worst channel mean {worst_mean:.3}"
    );
    assert_eq!(full_frames, 12);
    assert_eq!(worst_full, 0, "a pixel {worst_full} levels away from LeRobot's decode");
    // LeRobot's means are float32 sums (of byte / 255); one byte off in a frame would move its mean by 1/4096.
    assert!(worst_mean < 1e-4, "a channel mean {worst_mean} levels away from LeRobot's decode");
}
