//! The Push-T scene process (`mars-hil scene`) on its own, against an arm this test plays: it publishes state
//! frames whose joints put the flange where the test wants it (IK), asks for a reset and a start as marsd does,
//! and reads what the scene publishes: the referee's frames and the camera's.

#[allow(unused_imports)]
mod common;

use std::process::Command;
use std::time::{Duration, Instant};

use common::*;
use mars_ipc::node::create_node;
use mars_ipc::{
    ImageEncoding, ImageReader, RobotNamespace, RobotState, SceneAction, ScenePhase, SceneRequest, SceneRequestWriter,
    SceneState, SceneStateReader, StateWriter,
};
use mars_profile::Profile;
use mars_runtime::task::PushTHil;
use mars_tasks::push_t::render::Camera;

/// The test's side of the wire: an arm, marsd's requests, the referee and camera readers.
struct Bench {
    arm: StateWriter,
    requests: SceneRequestWriter,
    scene: SceneStateReader,
    camera: ImageReader,
    task: PushTHil,
    q: Vec<f64>,
    seq: u64,
    last: SceneState,
    _node: iceoryx2::node::Node<iceoryx2::service::ipc::Service>,
}

impl Bench {
    fn open(robot: &str) -> Self {
        let ns = RobotNamespace::new(robot).unwrap();
        let (node, _) = create_node(&format!("test-scene-{robot}")).unwrap();
        let profile = Profile::load(&root().join("configs/fr3.toml")).unwrap();
        let task = PushTHil::load(&root().join("configs/push_t.toml"), &profile).unwrap();
        Self {
            arm: StateWriter::new(&node, &ns).unwrap(),
            requests: SceneRequestWriter::new(&node, &ns).unwrap(),
            scene: SceneStateReader::new(&node, &ns).unwrap(),
            camera: ImageReader::new(&node, &ns, &task.cfg.camera.name).unwrap(),
            q: task.start_pose.clone(),
            task,
            seq: 0,
            last: SceneState::default(),
            _node: node,
        }
    }

    /// One millisecond of the arm standing at `self.q`, and the scene's newest frame read.
    fn tick(&mut self) {
        self.seq += 1;
        let mut s = RobotState { seq: self.seq, timestamp_ns: monotonic_ns(), num_joints: 7, ..Default::default() };
        s.position[..7].copy_from_slice(&self.q);
        self.arm.send(&s).unwrap();
        while let Ok(Some(f)) = self.scene.receive() {
            self.last = f;
        }
        std::thread::sleep(Duration::from_millis(1));
    }

    /// Ticks until `pred` holds for the referee's frame; panics after 5 s.
    fn until(&mut self, what: &str, pred: impl Fn(&SceneState) -> bool) {
        let end = Instant::now() + Duration::from_secs(5);
        while !pred(&self.last) {
            assert!(Instant::now() < end, "{what}: the scene's last frame {:?}", self.last);
            self.tick();
        }
    }

    fn ask(&mut self, action: SceneAction, episode: u64, seed: u64) {
        self.requests
            .send(&SceneRequest { seq: self.seq, episode, seed, action: action as u32, _reserved: 0 })
            .unwrap();
    }

    /// Moves the flange in a straight line to table point `to` at 0.1 m/s, solving IK each millisecond.
    fn move_to(&mut self, to: [f64; 2]) {
        let e = self.task.effector();
        let from = e.xy(&self.q);
        let n = ((to[0] - from[0]).hypot(to[1] - from[1]) / 1e-4).ceil().max(1.0) as usize;
        for k in 1..=n {
            let s = k as f64 / n as f64;
            let p = [from[0] + s * (to[0] - from[0]), from[1] + s * (to[1] - from[1])];
            self.q = e.solve_from(p, &self.q).unwrap().as_slice().to_vec();
            self.tick();
        }
    }
}

#[test]
fn the_scene_resets_follows_the_flange_pushes_the_block_and_shows_it_on_camera() {
    let logs = TempDir::new("scene");
    let robot = robot("scene");
    let mut bench = Bench::open(&robot);
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_mars-hil"));
    cmd.current_dir(root()).args(["scene", "--robot", &robot]);
    let mut scene = Proc::spawn(cmd, "scene", logs.path());

    // Reset (asked again until heard: the scene's subscriber may connect after the first request).
    let mut asked = Instant::now() - Duration::from_secs(1);
    let end = Instant::now() + Duration::from_secs(10);
    while !(bench.last.episode == 1 && bench.last.phase() == Some(ScenePhase::Reset)) {
        assert!(Instant::now() < end && scene.running(), "no reset: {:?}\n{}", bench.last, scene.logs());
        if asked.elapsed() > Duration::from_millis(100) {
            bench.ask(SceneAction::Reset, 1, 7);
            asked = Instant::now();
        }
        bench.tick();
    }
    let start_block = bench.last.object;
    let cfg = &bench.task.cfg.world;
    let off = |i: usize| (start_block[i] - f64::from(cfg.start[i])).abs();
    assert!(off(0) <= 0.0101 && off(1) <= 0.0101 && off(2) <= 0.0501, "seeded start {start_block:?}");

    // While lifted (reset), the flange's moves touch nothing: straight through the block and back.
    let start_xy = bench.task.effector().xy(&bench.q);
    bench.move_to([start_block[0], start_block[1]]);
    bench.move_to(start_xy);
    bench.tick();
    assert_eq!(bench.last.object, start_block, "the lifted pusher moved the block");

    // Run: the pusher is put down where the flange is; going around the bar's upper end and pushing its back
    // moves the block toward the goal, and the referee sees the upper route.
    bench.ask(SceneAction::Run, 1, 0);
    bench.until("the scene running episode 1", |s| s.episode == 1 && s.phase() == Some(ScenePhase::Running));
    let (bx, by) = (start_block[0], start_block[1]);
    for p in [[bx + 0.04, by + 0.09], [bx - 0.05, by + 0.09], [bx - 0.05, by], [bx + 0.04, by]] {
        bench.move_to(p);
    }
    for _ in 0..50 {
        bench.tick();
    }
    let pushed = bench.last;
    assert!(
        pushed.object[0] > bx + 0.02,
        "the block did not move along the push: {:?} → {:?}",
        start_block,
        pushed.object
    );
    assert_eq!(pushed.mode(), Some(0), "route: {pushed:?}");
    assert!((pushed.effector[0] - (bx + 0.04)).abs() < 1e-3, "the scene's effector is the flange: {pushed:?}");

    // The camera: the trained size, stamped on this clock, and the pusher where the flange is.
    let size = bench.task.cfg.camera.size;
    let frame = (0..200)
        .find_map(|_| {
            bench.tick();
            bench.camera.receive().ok().flatten()
        })
        .expect("no camera frame");
    let h = *frame.header();
    assert_eq!((h.width, h.height, h.encoding), (size, size, ImageEncoding::Rgb8 as u32));
    assert!(monotonic_ns() - h.timestamp_ns < 1_000_000_000, "capture stamped on another clock: {h:?}");
    let cam = Camera::push_t(size);
    let [u, v] = cam.pixel(pushed.effector[0] as f32, pushed.effector[1] as f32);
    let i = (v as usize * size as usize + u as usize) * 3;
    assert_eq!(&frame.pixels()[i..i + 3], &[40, 70, 200], "the pusher is blue where the flange is");
    drop(frame);

    // A new episode resets the block to its own seeded start and lifts the pusher again.
    bench.ask(SceneAction::Reset, 2, 8);
    bench.until("the scene reset for episode 2", |s| s.episode == 2 && s.phase() == Some(ScenePhase::Reset));
    assert!(bench.last.object[0] < bx + 0.015, "episode 2 starts at its own start: {:?}", bench.last.object);
    assert_eq!(bench.last.mode, -1);
    scene.signal(libc::SIGTERM);
    assert_eq!(scene.exit_code(Duration::from_secs(5)), 0, "{}", scene.logs());
    assert!(scene.stderr_text().contains("2 episodes"), "{}", scene.stderr_text());
}
