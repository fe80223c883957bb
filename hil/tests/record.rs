//! `--record`: runs written as LeRobot v3.0 datasets. The loop's side never waits and never allocates, even with
//! a writer that cannot keep up (it drops and counts, and leaves incomplete episodes out); a recorded demo reads
//! back and trains a policy.

mod common;

use std::path::Path;
use std::time::Duration;

use common::*;
use mars_lerobot::{Keys, LeRobotDataset};
use mars_runtime::record::{EpisodeEnd, RecordSetup, start};

// The project's counting allocator: per-thread counts, so the writer thread's own allocations are not counted.
#[global_allocator]
static ALLOC: mars_runtime::alloc_count::CountingAlloc = mars_runtime::alloc_count::CountingAlloc;

fn setup(path: &Path, delay_ms: u64) -> RecordSetup {
    RecordSetup {
        path: path.to_owned(),
        fps: 10,
        robot_type: "fr3".into(),
        task: "test".into(),
        state_names: vec!["a".into(), "b".into(), "c".into()],
        action_names: vec!["a".into(), "b".into(), "c".into()],
        camera: None,
        writer_delay: Duration::from_millis(delay_ms),
        seed: 7,
        checkpoint: "none".into(),
        config: "none".into(),
    }
}

/// A writer that sleeps 50 ms per frame: episode 1 (10 frames, fewer than the pool holds) is handed over whole
/// whatever the writer does; episode 2 (100 frames at once) cannot be, so most of its frames are dropped and it
/// is left out. The loop's side made no allocation and never waited (every call returned at once: 110 calls).
#[test]
fn a_slow_writer_costs_the_loop_nothing_and_keeps_only_complete_episodes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run");
    let (mut rec, writer) = start(setup(&path, 50)).unwrap();
    let mut handed = [0u64; 2];
    let state = |e: u64, k: u64| [e as f32, k as f32, -(k as f32)];
    let before = mars_runtime::alloc_count::thread_counts().expect("the counting allocator is installed");
    for (e, frames) in [(1u64, 10u64), (2, 100)] {
        for k in 0..frames {
            let kept = rec.record(|f| {
                f.episode = e;
                f.frame = k;
                f.state.copy_from_slice(&state(e, k));
                f.action.copy_from_slice(&state(e, k + 1));
                f.call = (k % 8 == 0) as u8 as f32;
            });
            handed[e as usize - 1] += kept as u64;
        }
        rec.end_episode(EpisodeEnd {
            episode: e,
            frames,
            success: true,
            mode: None,
            rest: [0.0; mars_runtime::servo::chunk::MAX_ACTION],
            rest_len: 3,
        });
    }
    let after = mars_runtime::alloc_count::thread_counts().unwrap();
    assert_eq!((after.system - before.system, after.pooled - before.pooled), (0, 0), "the loop's side allocated");
    assert_eq!(handed[0], 10, "episode 1 fits the pool");
    assert!(handed[1] < 100, "the writer kept up with 100 frames at 50 ms each?");
    let report = writer.finish();
    assert_eq!(report.episodes_written, 1, "{report:?}");
    assert_eq!(report.episodes_incomplete, 1, "{report:?}");
    assert_eq!(report.frames_dropped, 100 - handed[1], "{report:?}");
    assert_eq!(report.error, None);
    let ds = LeRobotDataset::open(&path).unwrap();
    let keys = Keys { state: "observation.state".into(), action: "action".into(), images: vec![] };
    let (episodes, _) = ds.read(&keys, (0, 0)).unwrap();
    assert_eq!(episodes.len(), 1);
    assert_eq!(episodes[0].len, 10);
    for k in 0..10 {
        assert_eq!(episodes[0].state[k * 3..k * 3 + 3], state(1, k as u64));
        assert_eq!(episodes[0].action[k * 3..k * 3 + 3], state(1, k as u64 + 1));
    }
    // Our one-value columns are plain float32 columns, as LeRobot stores a feature of shape (1,).
    let keys = Keys { state: "mars.call".into(), action: "mars.w_inf".into(), images: vec![] };
    let (episodes, _) = ds.read(&keys, (0, 0)).unwrap();
    let calls: Vec<f32> = (0..10).map(|k| (k % 8 == 0) as u8 as f32).collect();
    assert_eq!(episodes[0].state, calls);
}

#[test]
fn a_recording_never_overwrites_and_leaves_nothing_when_no_episode_completed() {
    let dir = tempfile::tempdir().unwrap();
    let taken = dir.path().join("taken");
    std::fs::create_dir(&taken).unwrap();
    let e = start(setup(&taken, 0)).err().expect("an existing path is refused");
    assert!(e.to_string().contains("never overwritten"), "{e:#}");
    let path = dir.path().join("empty");
    let (mut rec, writer) = start(setup(&path, 0)).unwrap();
    rec.record(|f| f.episode = 1); // an episode that never ends (the run stopped inside it)
    let report = writer.finish();
    assert_eq!((report.episodes_written, report.episodes_incomplete), (0, 1));
    assert!(!path.exists() && !dir.path().join("empty.partial").exists(), "something was left behind");
}

/// A recorded demo (mock HAL + marsd, 2 episodes of Pick Cup) is a dataset: one episode per episode run, each a
/// frame per policy period with the policy's state and the action in force, and it trains a policy; `marsd
/// replay` makes its calls again bit for bit, and `mars-hil replay` its trajectory through the mock HAL.
#[test]
fn a_recorded_demo_reads_back_trains_and_replays() {
    let _rt = rt_rig_lock();
    at_most_one_rerun("a recorded demo", recorded_demo);
}

/// The least stall of the servo's core in a run that explains a replay ending another way than its recording:
/// two periods, in which commands come late.
const REPLAY_STALL_MS: f64 = 2.0;

/// One run of the test above; its excuse if marsd tripped, or the replay's outcome differed from the recording's,
/// while the stall witness saw the machine stall then.
fn recorded_demo(attempt: u32) -> Attempt {
    let logs = TempDir::new(&format!("record{attempt}"));
    let robot = robot(&format!("record{attempt}"));
    let path = logs.join("dataset");
    let _hal = spawn_hal(&robot, &[], &logs);
    let recorded_from = monotonic_ns();
    let mut marsd = spawn_marsd(&robot, &shipped_config(), 2, &["--record", path.to_str().unwrap()], &logs);
    let code = marsd.exit_code(Duration::from_secs(120));
    let recorded = (recorded_from, monotonic_ns());
    let s = summary(&logs, "marsd");
    let out = marsd.stdout_text();
    if code == 3
        && let Some(e) = marsd_trip_excuse(&s, &marsd)
    {
        return Err(e);
    }
    assert_eq!(code, 0, "{}", marsd.logs());
    assert!(out.contains("recorded "), "{out}");
    let written = u64_at(&s, "/record/episodes_written");
    assert_eq!(written, 2, "{out}");
    assert_eq!(u64_at(&s, "/record/frames_dropped"), 0, "{out}");

    let ds = LeRobotDataset::open(&path).unwrap();
    assert_eq!(ds.info.fps, 10.0);
    let keys = Keys { state: "observation.state".into(), action: "action".into(), images: vec![] };
    let (episodes, _) = ds.read(&keys, (0, 0)).unwrap();
    for (e, r) in episodes.iter().zip(s["episode_results"].as_array().unwrap()) {
        // A frame per period the episode ran (its duration at 10 Hz, give or take the period it ended in).
        let periods = r["duration_s"].as_f64().unwrap() * 10.0;
        assert!(
            (e.len as f64 - periods).abs() <= 1.5,
            "episode {}: {} frames for {periods:.1} periods",
            e.index,
            e.len
        );
        assert_eq!(e.state.len(), e.len * 8);
    }
    for key in ["mars.w_inf", "mars.k", "mars.latency_ms", "mars.call", "mars.hal"] {
        ds.vector_len(key).unwrap();
    }
    // The HAL's word on every period: following marsd's session (ACTIVE), no fault bit, no hold.
    let keys = Keys { state: "mars.hal".into(), action: "mars.call".into(), images: vec![] };
    let (hal, _) = ds.read(&keys, (0, 0)).unwrap();
    for e in &hal {
        for (t, bits) in e.state.chunks_exact(3).enumerate() {
            let (status, fault) = (bits[0] as u32, bits[1] as u32);
            assert!(status & mars_ipc::status::ACTIVE != 0 && fault == 0, "episode {} frame {t}: {bits:?}", e.index);
        }
    }

    // `mars train --dataset` on it (in process, a small config, one epoch).
    let cfg_path = root().join("configs/fr3_policy.toml");
    let mut cfg = mars_policy::config::PolicyConfig::load(&cfg_path).unwrap();
    cfg.train.epochs = 1;
    let input = mars_policy::from_dataset::DatasetInput {
        dir: path.clone(),
        state_key: "observation.state".into(),
        action_key: "action".into(),
        image_keys: vec![],
        rest: None,
        normalize: Default::default(),
    };
    let (demos, _) = mars_policy::from_dataset::load(&input, &cfg.model).unwrap();
    assert_eq!(demos.len() as u64, written);
    let trained = mars_policy::train::train(&cfg, &demos, false).unwrap();
    assert!(trained.log.last().unwrap().total.is_finite());

    // `marsd replay`: the run's calls again, with its seeds and step counts, equal what it executed bit for
    // bit; another checkpoint diverges at the first call and says by how much.
    use mars_runtime::tools::replay::{ReplayArgs, run};
    let args = ReplayArgs { dataset: path.clone(), episode: 0, checkpoint: None };
    let same = run(&args).unwrap();
    eprint!("{same}");
    assert!(same.identical && same.calls >= 3 && same.actions_compared == episodes[0].len, "{same}");
    let fm = root().join("assets/checkpoints/fr3_pick_cup/fm");
    let other = run(&ReplayArgs { checkpoint: Some(fm), ..args }).unwrap();
    eprint!("{other}");
    assert!(!other.identical && other.first_divergence.as_ref().unwrap().frame == 0, "{other}");

    // `mars-hil replay`: episode 0's chunks through the mock HAL again, from the same start pose, recorded in
    // turn: the plant's trajectory comes back within the tolerance and the episode ends the same way.
    let out = logs.join("hil-replay");
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_mars-hil"));
    cmd.arg("replay").arg(&path).args(["--episode", "0"]).arg("--out").arg(&out);
    let replayed_from = monotonic_ns();
    let mut replay = spawn_named(cmd, "hil-replay", &logs);
    let code = replay.exit_code(Duration::from_secs(120));
    let replayed = (replayed_from, monotonic_ns());
    eprintln!(
        "{}",
        replay.stdout_text().lines().skip_while(|l| !l.starts_with("replay of")).collect::<Vec<_>>().join("\n")
    );
    if code == 3
        && let Some(e) = demo_trip_excuse(&out)
    {
        return Err(e);
    }
    assert!(code == 0 || code == 2, "the replay did not run to its end\n{}", replay.logs());
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("replay.json")).unwrap()).unwrap();
    assert_eq!(r["reproduced"] == true, code == 0, "the exit status says what replay.json says: {r:#}");
    // Timing that one run had and the other did not repeat: in episode 0 a chunk late or servo periods missed in
    // the recorded run (its commands came late), or servo periods missed in the replay. (A test build misses
    // many: its servo tick is not optimised.)
    let first = &s["episode_results"][0];
    let (late, missed) = (u64_at(first, "/late_chunks"), u64_at(first, "/servo_missed_periods"));
    let replay_summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let replay_missed = u64_at(&replay_summary["episode_results"][0], "/servo_missed_periods");
    // A replayed chunk was computed from no camera frame: nothing recorded as capture → command (it once was, into
    // a recorder that does not keep that channel).
    assert_eq!(u64_at(&replay_summary, "/latency/stray"), 0, "{}", replay_summary["latency"]);
    let on_time = late == 0 && missed == 0 && replay_missed == 0;
    let timing = format!(
        "in episode 0 the recorded run had {late} late chunks and {missed} missed servo periods, the replay \
         {replay_missed} missed servo periods"
    );
    // The episode ends the same way whatever the timing (the grasp is the actions'), unless the machine stalled
    // the servo's core in one of the two runs.
    if r["recorded_outcome"] != r["replayed_outcome"] {
        let failure =
            format!("the replay ended {} where the recording ended {}", r["replayed_outcome"], r["recorded_outcome"]);
        let excuse = |(from, to)| witness().excuse_on(servo_core(), failure.clone(), from, to, REPLAY_STALL_MS);
        if let Some(e) = excuse(recorded).or_else(|| excuse(replayed)) {
            return Err(e);
        }
    }
    assert_eq!(r["recorded_outcome"], r["replayed_outcome"], "{timing}: {r:#}");
    let t = &r["trajectory"];
    let compared = t["compared"].as_u64().unwrap();
    assert!(compared + 3 >= t["recorded_frames"].as_u64().unwrap(), "{r:#}");
    let (worst, tolerance) = (t["worst"].as_f64().unwrap(), r["tolerance"].as_f64().unwrap());
    if on_time {
        // Both runs kept every servo period: the trajectory comes back within the tolerance.
        assert!(worst <= tolerance && code == 0, "{timing}: {r:#}");
    } else {
        // Commands that came late in one run and not in the other move it by up to ~0.05 rad (seen in test
        // builds); the tolerance is not judged then, only that the replay follows this episode's commands.
        eprintln!("the tolerance is not judged: {timing}; worst {worst:.4}");
        assert!(worst <= 4.0 * tolerance, "{timing}: {r:#}");
    }
    // The comparison tells episodes apart: the replay against the other recorded episode is far off.
    if written >= 2 {
        let other = mars_hil::hil_replay::compare(&path, 1, &out.join("replayed"), 0).unwrap();
        eprintln!("the replay of episode 0 against episode 1: worst {:.3}", other.worst);
        assert!(other.worst > 5.0 * worst.max(tolerance / 10.0), "{other:?}");
    }
    Ok(())
}

/// The same through marsd with a writer that sleeps 300 ms per frame: the run goes on as without a recording
/// (the servo tick still allocates nothing), the periods it could not hand over are counted, the episode they
/// belong to is left out, and nothing is left at the path.
#[test]
fn marsd_with_a_writer_that_cannot_keep_up_drops_and_counts() {
    let _rt = rt_rig_lock();
    let logs = TempDir::new("record-slow");
    let robot = robot("record-slow");
    let path = logs.join("dataset");
    let _hal = spawn_hal(&robot, &[], &logs);
    let extra = ["--record", path.to_str().unwrap(), "--record-writer-delay-ms", "300"];
    let mut marsd = spawn_marsd(&robot, &shipped_config(), 1, &extra, &logs);
    let code = marsd.exit_code(Duration::from_secs(120));
    let s = summary(&logs, "marsd");
    let out = marsd.stdout_text();
    assert_eq!(code, 0, "a writer that cannot keep up is no reason to stop\n{}", marsd.logs());
    assert!(u64_at(&s, "/record/frames_dropped") > 0, "{out}");
    assert_eq!(u64_at(&s, "/record/episodes_written"), 0, "{out}");
    assert_eq!(u64_at(&s, "/record/episodes_incomplete"), 1, "{out}");
    assert_eq!(u64_at(&s, "/servo_allocations/system"), 0, "the servo tick allocated\n{out}");
    assert!(!path.exists() && !logs.join("dataset.partial").exists());
}
