//! marsd's side of a task's scene (Push-T): the top-down camera the policy sees, the reset and start requests
//! between episodes, and the referee's frames that say whether the episode succeeded and which way it went.
//! Opened on the policy thread (iceoryx2 ports stay on the thread that made them); polling allocates nothing.

use mars_ipc::clock::monotonic_ns;
use mars_ipc::{
    ImageEncoding, RobotNamespace, SceneAction, ScenePhase, SceneRequest, SceneRequestWriter, SceneState,
    SceneStateReader,
};

use crate::observe::camera::{Camera, CameraSpec};
use crate::task::PushTHil;

pub struct SceneLink {
    requests: SceneRequestWriter,
    states: SceneStateReader,
    pub camera: Camera,
    /// A second subscriber to the camera for a recording (`--record`): it reads every period's newest frame
    /// without taking any from the policy's reader, whose judging and counts stay as without a recording.
    recording_view: Option<mars_ipc::ImageReader>,
    latest: SceneState,
    /// When the newest referee frame arrived (0: none yet).
    latest_at_ns: u64,
    seq: u64,
    _node: iceoryx2::node::Node<iceoryx2::service::ipc::Service>,
}

impl SceneLink {
    /// `recording`: also open the recording's view of the camera.
    pub fn open(robot: &str, task: &PushTHil, recording: bool) -> anyhow::Result<Self> {
        let ns = RobotNamespace::new(robot)?;
        let (node, _) = mars_ipc::node::create_node(&format!("marsd-{robot}-scene"))?;
        let c = &task.cfg.camera;
        let spec = CameraSpec {
            width: c.size,
            height: c.size,
            encoding: ImageEncoding::Rgb8,
            max_age_ns: (c.max_age_ms * 1e6) as u64,
        };
        let camera = Camera::new(mars_ipc::ImageReader::new(&node, &ns, &c.name)?, spec);
        let recording_view = if recording { Some(mars_ipc::ImageReader::new(&node, &ns, &c.name)?) } else { None };
        Ok(Self {
            recording_view,
            requests: SceneRequestWriter::new(&node, &ns)?,
            states: SceneStateReader::new(&node, &ns)?,
            camera,
            latest: SceneState::default(),
            latest_at_ns: 0,
            seq: 0,
            _node: node,
        })
    }

    /// The recording's view: copies the newest well-formed camera frame waiting into `out` (its size); false if
    /// none came since the last call (or no recording view is open). Not judged: the policy never acts on it.
    pub fn newest_for_recording(&mut self, out: &mut [u8]) -> bool {
        let Some(reader) = &self.recording_view else { return false };
        let mut got = false;
        while let Ok(Some(f)) = reader.receive() {
            if f.pixels().len() == out.len() {
                out.copy_from_slice(f.pixels());
                got = true;
            }
        }
        got
    }

    /// Asks the scene to reset for `episode` from `seed`, or to start it.
    pub fn request(&mut self, action: SceneAction, episode: u64, seed: u64) {
        self.seq += 1;
        let r = SceneRequest { seq: self.seq, episode, seed, action: action as u32, _reserved: 0 };
        // A failed send is seen as no answer: the caller asks again and times out.
        let _ = self.requests.send(&r);
    }

    /// Reads every referee frame waiting; the newest.
    pub fn poll(&mut self) -> &SceneState {
        while let Ok(Some(s)) = self.states.receive() {
            self.latest = s;
            self.latest_at_ns = monotonic_ns();
        }
        &self.latest
    }

    /// The scene is in `phase` for `episode`.
    pub fn is(&mut self, episode: u64, phase: ScenePhase) -> bool {
        let s = self.poll();
        s.episode == episode && s.phase() == Some(phase)
    }

    /// How long since the referee's newest frame (u64::MAX before the first).
    pub fn silent_ns(&self, now_ns: u64) -> u64 {
        if self.latest_at_ns == 0 { u64::MAX } else { now_ns.saturating_sub(self.latest_at_ns) }
    }
}
