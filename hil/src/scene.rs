//! The HIL scene (`mars-hil scene`): the world around the arm for Push-T. It reads the robot's state frames like
//! any observer, puts the pusher where the flange is (forward kinematics of the measured joints), steps the T
//! block's physics, renders the fixed top-down camera and publishes its frames on `mars/<robot>/camera/<name>`,
//! and as the task's referee publishes where the block is, whether it is home and which route the pusher took
//! ([`mars_ipc::SceneState`]). Between episodes marsd asks it to reset the block ([`mars_ipc::SceneRequest`]):
//! the pusher is then lifted (it touches nothing while the arm moves to its start) until marsd says `Run`.
//!
//! A real bench has the same three parts: the camera driver, the objects, and a referee (a person or a
//! motion-capture system); marsd never acts on the referee's frames, the policy sees only the camera and the arm.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::Context;
use mars_ipc::clock::monotonic_ns;
use mars_ipc::{
    ImageEncoding, ImageHeader, ImageWriter, RobotNamespace, SceneAction, ScenePhase, SceneRequestReader, SceneState,
    SceneStateWriter, StateReader,
};
use mars_profile::Profile;
use mars_tasks::push_t::expert::route_taken;
use mars_tasks::push_t::render::Camera;
use mars_tasks::push_t::{PushT, PushTState};

use mars_runtime::rt::Ticker;
use mars_runtime::task::PushTHil;

/// A robot state older than this and the scene says so in its frames (the pusher stays where it was seen).
const STALE_ROBOT_NS: u64 = 100_000_000;

#[derive(Debug, Clone, clap::Args)]
pub struct SceneArgs {
    /// The Push-T task file (the same one marsd runs).
    #[arg(long, default_value = "configs/push_t.toml")]
    pub task: PathBuf,
    #[arg(long, default_value = "configs/fr3.toml")]
    pub profile: PathBuf,
    /// The robot's namespace (marsd's and the HAL's `--robot`).
    #[arg(long, default_value = "fr3")]
    pub robot: String,
    /// Stop after this long (default: until SIGTERM/SIGINT).
    #[arg(long)]
    pub duration_s: Option<f64>,
}

/// What the scene did, printed at exit.
#[derive(Debug, Default, Clone, Copy)]
pub struct SceneCounts {
    pub substeps: u64,
    pub frames: u64,
    pub episodes: u64,
    pub robot_states: u64,
}

/// One episode's world and what the referee saw of it.
struct Episode {
    number: u64,
    world: PushT,
    phase: ScenePhase,
    pusher: Vec<[f32; 2]>,
    block: Vec<[f32; 3]>,
}

pub fn run(args: &SceneArgs) -> anyhow::Result<SceneCounts> {
    let profile = Profile::load(&args.profile)?;
    let task = PushTHil::load(&args.task, &profile).with_context(|| format!("task {}", args.task.display()))?;
    let effector = task.effector();
    let (cfg, cam) = (&task.cfg.world, &task.cfg.camera);
    let ns = RobotNamespace::new(&args.robot)?;
    let (node, _) = mars_ipc::node::create_node(&format!("mars-scene-{}", args.robot))?;
    let states = StateReader::new(&node, &ns)?;
    let requests = SceneRequestReader::new(&node, &ns)?;
    let scene = SceneStateWriter::new(&node, &ns)?;
    let size = cam.size;
    let images = ImageWriter::new(&node, &ns, &cam.name, (size * size * 3) as usize)?;
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(sig, stop.clone())?;
    }

    let substep = Duration::from_secs_f64(f64::from(cfg.control_period) / cfg.substeps as f64);
    let frames_every = (1.0 / (cam.rate_hz * substep.as_secs_f64())).round().max(1.0) as u64;
    let mut camera = Camera::push_t(size);
    let mut rgb = vec![0u8; (size * size * 3) as usize];
    let mut episode: Option<Episode> = None;
    let (mut q, mut seen_ns) = ([0.0f64; mars_ipc::MAX_JOINTS], 0u64);
    let mut counts = SceneCounts::default();
    let mut out = SceneState::default();
    let end_ns = args.duration_s.map(|s| monotonic_ns() + (s * 1e9) as u64);
    let mut ticker = Ticker::new(substep);
    eprintln!(
        "scene: Push-T on mars/{}/…, physics every {:.1} ms, camera {}×{} every {} substeps on mars/{}/camera/{}",
        args.robot,
        substep.as_secs_f64() * 1e3,
        size,
        size,
        frames_every,
        args.robot,
        cam.name
    );
    while !stop.load(Ordering::Relaxed) && end_ns.is_none_or(|e| monotonic_ns() < e) {
        ticker.wait();
        while let Ok(Some(s)) = states.receive() {
            if s.position[..7].iter().all(|x| x.is_finite()) {
                q = s.position;
                seen_ns = monotonic_ns();
                counts.robot_states += 1;
            }
        }
        let now = monotonic_ns();
        let stale = seen_ns == 0 || now.saturating_sub(seen_ns) > STALE_ROBOT_NS;
        let flange = effector.xy(&q[..7]).map(|v| v as f32);
        while let Ok(Some(r)) = requests.receive() {
            match r.action() {
                Some(SceneAction::Reset) if episode.as_ref().is_none_or(|e| e.number != r.episode) => {
                    episode = Some(Episode {
                        number: r.episode,
                        world: PushT::new(cfg, r.seed),
                        phase: ScenePhase::Reset,
                        pusher: Vec::new(),
                        block: Vec::new(),
                    });
                    counts.episodes += 1;
                }
                Some(SceneAction::Run) => {
                    if let Some(e) = episode.as_mut().filter(|e| e.number == r.episode && e.phase == ScenePhase::Reset)
                    {
                        e.world.place_pusher(flange);
                        e.phase = ScenePhase::Running;
                    }
                }
                _ => {}
            }
        }
        let mut view = PushTState { pusher: flange, block: cfg.start };
        out =
            SceneState { seq: out.seq + 1, timestamp_ns: now, stale_robot: u32::from(stale), ..SceneState::default() };
        if let Some(e) = episode.as_mut() {
            if e.phase == ScenePhase::Running && !stale {
                e.world.follow(flange);
                counts.substeps += 1;
                let s = e.world.state();
                e.pusher.push(s.pusher);
                e.block.push(s.block);
            }
            view.block = e.world.state().block;
            let (d, a) = e.world.goal_error();
            out.episode = e.number;
            out.phase = e.phase as u32;
            out.success = u32::from(e.phase == ScenePhase::Running && e.world.success());
            out.mode = route_taken(&e.pusher, &e.block).map_or(-1, |r| r.index() as i32);
            out.goal_error = [f64::from(d), f64::from(a)];
        }
        out.object = view.block.map(f64::from);
        out.effector = flange.map(f64::from);
        let _ = scene.send(&out);
        if out.seq % frames_every == 0 {
            camera.render(cfg, &view, &mut rgb);
            let header = ImageHeader {
                width: size,
                height: size,
                encoding: ImageEncoding::Rgb8 as u32,
                seq: counts.frames + 1,
                timestamp_ns: now,
                ..ImageHeader::default()
            };
            images.send_with(header, |px| px.copy_from_slice(&rgb))?;
            counts.frames += 1;
        }
    }
    eprintln!(
        "scene: {} episodes, {} physics substeps, {} camera frames, {} robot states read",
        counts.episodes, counts.substeps, counts.frames, counts.robot_states
    );
    Ok(counts)
}
