//! The iceoryx2 frames' checks, on both sides of the wire: a command frame as the HAL takes it (its control, with
//! the session logic and the safety filter's judgement), a state frame as marsd's servo tick takes it (its frame
//! check, then the smoother), an image frame's header as a camera reader and the policy's camera check take it.
//! An input is a sequence of frames, each field read from the bytes (numbers as raw bits: NaN, infinities,
//! huge counts); between them, ticks where the HAL and the servo talk to each other as in a run.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::{Bundles, read, repo};
use crate::runner::Target;
use mars_hal::backend::Measurement;
use mars_hal::control::HalControl;
use mars_hal::events::{EventLogger, EventSender};
use mars_ipc::{ImageEncoding, ImageHeader, JointCommand, MAX_JOINTS, RobotState, SCHEMA_VERSION};
use mars_profile::Profile;
use mars_runtime::config::DaemonConfig;
use mars_runtime::observe::camera::{CameraCheck, CameraSpec};
use mars_runtime::servo::{ServoTick, TickInput};

/// Little-endian fields out of the input, zeros once it is used up.
struct Fields<'a>(&'a [u8]);

impl Fields<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        let n = N.min(self.0.len());
        out[..n].copy_from_slice(&self.0[..n]);
        self.0 = &self.0[n..];
        out
    }
    fn u8(&mut self) -> u8 {
        self.take::<1>()[0]
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn f64(&mut self) -> f64 {
        f64::from_bits(self.u64())
    }
    fn joints(&mut self) -> [f64; MAX_JOINTS] {
        std::array::from_fn(|_| self.f64())
    }
}

/// The frames in the order [`Fields`] reads them (what the seeds are written as).
#[derive(Default)]
struct Writer(Vec<u8>);

impl Writer {
    fn u8(&mut self, v: u8) -> &mut Self {
        self.0.push(v);
        self
    }
    fn u32(&mut self, v: u32) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn u64(&mut self, v: u64) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn joints(&mut self, q: &[f64]) -> &mut Self {
        (0..MAX_JOINTS).fold(self, |w, i| w.u64(q.get(i).copied().unwrap_or(0.0).to_bits()))
    }
}

fn command(f: &mut Fields) -> JointCommand {
    JointCommand {
        seq: f.u64(),
        timestamp_ns: f.u64(),
        state_seq: f.u64(),
        session: f.u64(),
        position: f.joints(),
        velocity: f.joints(),
        acceleration: f.joints(),
        gripper: f.f64(),
        gripper_speed: f.f64(),
        mode: f.u32(),
        num_joints: f.u32(),
    }
}

fn state(f: &mut Fields) -> RobotState {
    RobotState {
        seq: f.u64(),
        timestamp_ns: f.u64(),
        session: f.u64(),
        last_command_seq: f.u64(),
        position: f.joints(),
        velocity: f.joints(),
        gripper: f.f64(),
        status: f.u32(),
        fault: f.u32(),
        hold_reason: f.u32(),
        num_joints: f.u32(),
        ..RobotState::default()
    }
}

fn image(f: &mut Fields) -> (ImageHeader, usize) {
    let h = ImageHeader {
        schema_version: f.u32(),
        width: f.u32(),
        height: f.u32(),
        encoding: f.u32(),
        seq: f.u64(),
        timestamp_ns: f.u64(),
    };
    (h, f.u64() as usize)
}

/// What the frames meet: the FR3's profile and the shipped marsd config, and the HAL's event queue with its logger
/// thread (events are dropped: only panics matter here).
struct Rig {
    profile: Profile,
    cfg: DaemonConfig,
    events: Mutex<(EventSender, EventLogger)>,
}

pub fn frames() -> Arc<dyn Target> {
    let profile = Profile::load(&repo("configs/fr3.toml")).expect("the FR3 profile");
    let cfg = DaemonConfig::parse(std::str::from_utf8(&read("configs/marsd.toml")).expect("UTF-8"), "marsd.toml")
        .expect("the shipped marsd.toml");
    let events = EventLogger::start(1024, Duration::from_millis(5), |_| {}).expect("an event logger");
    let files = seeds(&profile);
    let rig = Rig { profile, cfg, events: Mutex::new(events) };
    Bundles::of_files("wire-frames", files, false, move |_, bytes| rig.exchange(bytes))
}

/// A run as it should be (talking ticks, a command in session 1 at home, a state frame and an image in order,
/// stamped on the loop's clock: 1 s, then 1 ms a frame), and one frame of each kind on its own.
fn seeds(p: &Profile) -> Vec<Vec<u8>> {
    let cmd = |w: &mut Writer, seq: u64| {
        w.u8(0).u64(seq).u64(1_000_000 * seq).u64(seq).u64(1).joints(&p.home).joints(&[]).joints(&[]);
        w.u64(0.03f64.to_bits()).u64(0.0f64.to_bits()).u32(1).u32(p.joints as u32);
    };
    let st = |w: &mut Writer, seq: u64| {
        w.u8(1).u64(seq).u64(1_000_000_000 + 4_000_000 * seq).u64(1).u64(seq).joints(&p.home).joints(&[]);
        w.u64(0.03f64.to_bits()).u32(0).u32(0).u32(0).u32(p.joints as u32);
    };
    let img = |w: &mut Writer, seq: u64| {
        w.u8(2).u32(SCHEMA_VERSION).u32(96).u32(96).u32(ImageEncoding::Rgb8 as u32).u64(seq);
        w.u64(1_000_000_000 + 4_000_000 * (seq - 1)).u64(96 * 96 * 3);
    };
    let mut run = Writer::default();
    for seq in 1..6 {
        run.u8(3);
        cmd(&mut run, seq);
        st(&mut run, seq);
        img(&mut run, seq);
    }
    let one = |f: &dyn Fn(&mut Writer, u64)| {
        let mut w = Writer::default();
        f(&mut w, 1);
        w.0
    };
    vec![run.0, one(&cmd), one(&st), one(&img)]
}

/// One exchange between a HAL and a servo tick, fed frames from the input.
struct Session<'a> {
    hal: HalControl,
    servo: ServoTick,
    camera: CameraCheck,
    at_home: Measurement,
    ev: &'a mut EventSender,
    now: u64,
    to_hal: Option<JointCommand>,
    followed: bool,
}

impl Rig {
    /// Accepted: some frame of the input was used (a command followed, a state frame or an image acted on).
    fn exchange(&self, input: &[u8]) -> bool {
        let mut events = self.events.lock().unwrap_or_else(|e| e.into_inner());
        let p = &self.profile;
        let mut at_home = Measurement { gripper: 0.03, ..Measurement::default() };
        at_home.position[..p.joints].copy_from_slice(&p.home);
        let spec = CameraSpec { width: 96, height: 96, encoding: ImageEncoding::Rgb8, max_age_ns: 50_000_000 };
        let mut s = Session {
            hal: HalControl::start(p, &at_home).expect("the HAL takes over an arm at home"),
            servo: ServoTick::new(&self.cfg, p, 1).expect("the servo of the shipped config"),
            camera: CameraCheck::new(spec),
            at_home,
            ev: &mut events.0,
            now: 1_000_000_000,
            to_hal: None,
            followed: false,
        };
        let mut f = Fields(input);
        for _ in 0..64 {
            if f.0.is_empty() {
                break;
            }
            s.tick(&mut f, p.joints);
        }
        s.followed || s.servo.frames().counts.used > 0 || s.camera.counts.used > 0
    }
}

impl Session<'_> {
    /// One HAL tick; its frame, or the HAL's own state frame, to the servo; an image header to the camera checks.
    fn tick(&mut self, f: &mut Fields, joints: usize) {
        self.now += 1_000_000;
        let (now, kind) = (self.now, f.u8() % 4);
        self.hal.begin_tick(now);
        self.hal.on_read(Ok(self.at_home), self.ev);
        match kind {
            0 => self.hal.on_command(&command(f), self.ev),
            1 => self.to_hal = self.servo.tick(&tick(now, &state(f))).command,
            2 => {
                let (h, len) = image(f);
                if mars_ipc::wire::check_image(&h, len).is_ok() {
                    let _ = self.camera.judge(&h, now);
                }
            }
            _ => {
                if let Some(c) = self.to_hal.take() {
                    self.hal.on_command(&c, self.ev);
                }
            }
        }
        let _ = self.hal.step(20, self.ev);
        self.hal.on_apply(Ok(()), self.ev);
        let frame = self.hal.state_frame(now);
        let applied = &frame.applied_position[..joints];
        assert!(applied.iter().all(|q| q.is_finite()), "the HAL applied a setpoint that is not finite: {applied:?}");
        self.followed |= frame.session != 0;
        if kind == 3 {
            self.to_hal = self.servo.tick(&tick(now, &frame)).command;
        }
    }
}

fn tick(now_ns: u64, frame: &RobotState) -> TickInput<'_> {
    TickInput {
        now_ns,
        missed: 0,
        frame: Some(frame),
        chunk: None,
        request: None,
        stop_requested: false,
        hal_gone: false,
    }
}
