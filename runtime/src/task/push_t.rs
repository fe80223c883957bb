//! Push-T on the FR3 (the paper's FR3 task): the flange, pointing down at a fixed height, is the pusher; a fixed
//! top-down camera sees the table; the policy acts in (x, y) on the table. The world itself (the T block, its
//! physics, the camera) is the scene process (`mars-hil scene`, `mars_hil::scene`); marsd sees only the camera
//! and the arm, and asks the scene to reset the block between episodes and whether the push succeeded.
//!
//! Read from TOML (`configs/push_t.toml`), which the scene reads too, and checked against the robot profile
//! before anything moves: the start pose is solved by IK and must lie inside the joint limits.

use std::path::Path;

use mars_kinematics::{Arm, Plane};
use mars_profile::Profile;
use mars_tasks::push_t::PushTConfig;
use mars_tasks::push_t::episode::Observe;
use serde::Deserialize;

use crate::servo::effector::{PlanarEffector, Workspace};
use mars_tasks::pick::{LIMIT_MARGIN_RAD, TaskError};

/// Where the table is for the arm.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Table {
    /// The flange's height above the robot's base while it pushes (m).
    pub height: f64,
    /// Where the table frame's origin lies in the robot base's x, y (m): the task's coordinates are the table's.
    pub origin: [f64; 2],
    /// Where a policy's (x, y) may send the flange; anything outside is clamped to the edge (and counted).
    pub workspace: Workspace,
}

/// The fixed top-down camera.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Its id: it publishes on `mars/<robot>/camera/<name>`.
    pub name: String,
    /// Square images of `size` × `size` RGB8 pixels (the policy's image size).
    pub size: u32,
    /// Frames per second the scene renders.
    pub rate_hz: f64,
    /// The policy acts only on a frame captured at most this long before it reads it.
    pub max_age_ms: f64,
}

/// The task as written in its TOML file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PushTHilConfig {
    /// `"push_t"`: what tells this file from a pick task.
    pub kind: String,
    pub name: String,
    pub policy_rate_hz: f64,
    /// An episode that has not succeeded after this long ends as a failure.
    pub timeout_s: f64,
    /// The scene must answer a reset or a start within this long.
    pub scene_timeout_s: f64,
    pub table: Table,
    pub camera: CameraConfig,
    /// The block, the pusher, the goal, the tolerances: the in-process task's configuration.
    pub world: PushTConfig,
}

/// The validated task.
#[derive(Debug, Clone)]
pub struct PushTHil {
    pub cfg: PushTHilConfig,
    /// The joints that put the flange at the world's `pusher_start`, from the profile's home.
    pub start_pose: Vec<f64>,
    effector: PlanarEffector,
}

impl PushTHil {
    pub fn load(path: &Path, profile: &Profile) -> Result<Self, TaskError> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|error| TaskError::Read { path: origin.clone(), error })?;
        Self::parse(&text, &origin, profile)
    }

    pub fn parse(text: &str, origin: &str, profile: &Profile) -> Result<Self, TaskError> {
        let invalid = |field: &str, problem: String| TaskError::Invalid {
            path: origin.to_owned(),
            field: field.to_owned(),
            problem,
        };
        let cfg: PushTHilConfig =
            toml::from_str(text).map_err(|e| TaskError::Parse { path: origin.to_owned(), error: Box::new(e) })?;
        validate(&cfg, profile).map_err(|(f, p)| invalid(&f, p))?;
        let plane = Plane::pointing_down(cfg.table.height);
        let effector = PlanarEffector::new(Arm::fr3(), plane, cfg.table.origin, cfg.table.workspace);
        let [x, y] = cfg.world.pusher_start.map(f64::from);
        let start = effector
            .solve_from([x, y], &profile.home)
            .map_err(|e| invalid("world.pusher_start", format!("({x}, {y}) at height {} m: {e}", cfg.table.height)))?;
        for (i, q) in start.iter().enumerate() {
            let (lo, hi) = (profile.q_min[i] + LIMIT_MARGIN_RAD, profile.q_max[i] - LIMIT_MARGIN_RAD);
            if !(lo..=hi).contains(q) {
                return Err(invalid(
                    "world.pusher_start",
                    format!(
                        "its IK solution puts joint {i} at {q:.4}, outside [{lo:.4}, {hi:.4}] (the limits less a margin)"
                    ),
                ));
            }
        }
        // Every point of the workspace must be reachable from the start (a 9 × 9 grid): the servo's IK then never
        // meets a reference it cannot reach inside it.
        let w = cfg.table.workspace;
        for i in 0..9 {
            for j in 0..9 {
                let p = [w.x[0] + (w.x[1] - w.x[0]) * i as f64 / 8.0, w.y[0] + (w.y[1] - w.y[0]) * j as f64 / 8.0];
                if let Err(e) = effector.solve_from(p, start.as_slice()) {
                    return Err(invalid(
                        "table.workspace",
                        format!(
                            "({:.3}, {:.3}) at height {} m is not reachable pointing down: {e}",
                            p[0], p[1], cfg.table.height
                        ),
                    ));
                }
            }
        }
        Ok(Self { cfg, start_pose: start.as_slice().to_vec(), effector })
    }

    /// The effector the servo turns the policy's (x, y) into joints with.
    pub fn effector(&self) -> PlanarEffector {
        self.effector.clone()
    }

    /// What the policy observes: the flange's (x, y) and the camera's image.
    pub fn observe(&self) -> Observe {
        Observe::Camera { size: self.cfg.camera.size }
    }

    pub fn obs_dim(&self) -> usize {
        self.observe().dim()
    }

    /// Action = where the flange should be on the table (x, y).
    pub fn action_dim(&self) -> usize {
        2
    }

    /// The modes: the two routes around the block.
    pub fn mode_names(&self) -> Vec<String> {
        vec!["upper".into(), "lower".into()]
    }

    /// "Stay where you start": the history before the first action.
    pub fn rest_action(&self) -> Vec<f32> {
        self.cfg.world.pusher_start.to_vec()
    }

    /// The flange's (x, y) on the table for joints `q` (the observation's state part).
    pub fn flange_xy(&self, q: &[f64]) -> [f64; 2] {
        self.effector.xy(q)
    }

    /// The policy's observation for measured joints `q` and a camera frame's RGB8 pixels: the flange's (x, y) on
    /// the table, then each byte / 255 — what `mars_tasks::push_t::episode::Observer` makes of the same scene in
    /// training (tested). Allocation-free.
    pub fn observation(&self, q: &[f64], rgb: &[u8], out: &mut [f32]) {
        let [x, y] = self.effector.xy(q);
        out[0] = x as f32;
        out[1] = y as f32;
        mars_policy_format::observation::pixels_to_observation(rgb, &mut out[2..]);
    }
}

fn validate(c: &PushTHilConfig, p: &Profile) -> Result<(), (String, String)> {
    let err = |field: &str, problem: String| Err((field.to_owned(), problem));
    if c.kind != "push_t" {
        return err("kind", format!("is {:?}; this file describes a Push-T task only if it is \"push_t\"", c.kind));
    }
    if p.joints != mars_kinematics::JOINTS || p.name != "fr3" {
        return err(
            "kind",
            format!("Push-T acts through the FR3's kinematics; the profile is {} ({} joints)", p.name, p.joints),
        );
    }
    // The upper bounds keep the conversions to nanoseconds (deadlines added to the clock) far from overflow.
    for (field, v, max) in [
        ("policy_rate_hz", c.policy_rate_hz, 10_000.0),
        ("timeout_s", c.timeout_s, 86_400.0),
        ("scene_timeout_s", c.scene_timeout_s, 86_400.0),
        ("table.height", c.table.height, 10.0),
        ("camera.rate_hz", c.camera.rate_hz, 10_000.0),
        ("camera.max_age_ms", c.camera.max_age_ms, 60_000.0),
    ] {
        if !(v.is_finite() && v > 0.0 && v <= max) {
            return err(field, format!("is {v:?}, must be a finite number > 0 and at most {max}"));
        }
    }
    check_world(&c.world).map_or(Ok(()), |(field, problem)| err(field, problem))?;
    let period = f64::from(c.world.control_period);
    if (c.policy_rate_hz * period - 1.0).abs() > 1e-6 {
        return err(
            "policy_rate_hz",
            format!(
                "{} must be 1 / world.control_period = {} (the demos' action rate)",
                c.policy_rate_hz,
                1.0 / period
            ),
        );
    }
    let ticks = p.rate_hz / c.policy_rate_hz;
    if (ticks - ticks.round()).abs() > 1e-9 {
        return err("policy_rate_hz", format!("{} must divide the profile's rate_hz {}", c.policy_rate_hz, p.rate_hz));
    }
    if !(8..=512).contains(&c.camera.size) {
        return err("camera.size", format!("is {}; images of 8 to 512 pixels a side", c.camera.size));
    }
    let w = &c.table.workspace;
    if !(w.x[0] < w.x[1] && w.y[0] < w.y[1]) || w.x.iter().chain(&w.y).any(|v| !v.is_finite()) {
        return err("table.workspace", format!("{w:?} is not a rectangle (x: [min, max], y: [min, max])"));
    }
    let [sx, sy] = c.world.pusher_start.map(f64::from);
    if !w.contains([sx, sy]) {
        return err("world.pusher_start", format!("({sx}, {sy}) lies outside table.workspace {w:?}"));
    }
    Ok(())
}

/// The world's numbers the physics and the scene divide by or size shapes with: finite, positive where a size or a
/// speed, and at most 1000 physics substeps a control period.
fn check_world(w: &PushTConfig) -> Option<(&'static str, String)> {
    let sizes = [("world.bar", &w.bar[..]), ("world.stem", &w.stem[..])];
    let positive = [("world.pusher_radius", w.pusher_radius), ("world.pusher_speed", w.pusher_speed)];
    if let Some((f, v)) = sizes.iter().find(|(_, v)| v.iter().any(|x| !(x.is_finite() && *x > 0.0))) {
        return Some((f, format!("{v:?} must be positive sizes (m)")));
    }
    if let Some((f, v)) = positive.iter().find(|(_, x)| !(x.is_finite() && *x > 0.0)) {
        return Some((f, format!("is {v}, must be a finite number > 0")));
    }
    let rest = [&w.start[..], &w.goal[..], &w.pusher_start[..], &w.start_noise[..], &w.tolerance[..]];
    if rest.iter().any(|v| v.iter().any(|x| !x.is_finite())) {
        return Some(("world", "start, goal, pusher_start, start_noise and tolerance must be finite".into()));
    }
    if !(1..=1000).contains(&w.substeps) {
        return Some(("world.substeps", format!("is {}, must be in 1..=1000", w.substeps)));
    }
    None
}

impl mars_tasks::Task for PushTHil {
    fn name(&self) -> &str {
        &self.cfg.name
    }

    fn obs_dim(&self) -> usize {
        PushTHil::obs_dim(self)
    }

    fn action_dim(&self) -> usize {
        PushTHil::action_dim(self)
    }

    fn mode_names(&self) -> Vec<String> {
        PushTHil::mode_names(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn profile() -> Profile {
        Profile::load(&crate::task::repo_path("configs/fr3.toml")).unwrap()
    }

    #[test]
    fn the_shipped_task_loads_and_its_start_pose_puts_the_flange_at_the_pusher_start() {
        let t = PushTHil::load(&crate::task::repo_path("configs/push_t.toml"), &profile()).unwrap();
        let xy = t.effector().xy(&t.start_pose);
        let [x, y] = t.cfg.world.pusher_start.map(f64::from);
        assert!((xy[0] - x).abs() < 1e-4 && (xy[1] - y).abs() < 1e-4, "{xy:?}");
        assert_eq!(t.obs_dim(), 2 + (t.cfg.camera.size * t.cfg.camera.size * 3) as usize);
    }

    /// marsd's observation of a scene (the flange from the measured joints, the camera's bytes) is the one the
    /// policy was trained on (the in-process world's pusher and render).
    #[test]
    fn marsd_observes_a_scene_as_training_did() {
        use mars_tasks::push_t::PushT;
        use mars_tasks::push_t::episode::Observer;
        use mars_tasks::push_t::render::Camera;
        let t = PushTHil::load(&crate::task::repo_path("configs/push_t.toml"), &profile()).unwrap();
        let world = PushT::new(&t.cfg.world, 3);
        let mut state = world.state();
        state.pusher = [0.27, 0.06];
        let trained = Observer::new(t.observe()).observe(&t.cfg.world, &state);
        let size = t.cfg.camera.size;
        let mut rgb = vec![0u8; (size * size * 3) as usize];
        Camera::push_t(size).render(&t.cfg.world, &state, &mut rgb);
        let pusher = state.pusher.map(f64::from);
        let q = t.effector().solve_from(pusher, &t.start_pose).unwrap();
        let mut ours = vec![0.0f32; t.obs_dim()];
        t.observation(q.as_slice(), &rgb, &mut ours);
        assert_eq!(ours.len(), trained.len());
        assert!((ours[0] - trained[0]).abs() < 1e-4 && (ours[1] - trained[1]).abs() < 1e-4, "{:?}", &ours[..2]);
        assert_eq!(ours[2..], trained[2..], "the image values");
    }

    #[test]
    fn a_bad_file_is_refused_with_the_field_and_why() {
        let text = std::fs::read_to_string(crate::task::repo_path("configs/push_t.toml")).unwrap();
        let p = profile();
        let bad = text.replace("policy_rate_hz = 10.0", "policy_rate_hz = 20.0");
        let e = PushTHil::parse(&bad, "t", &p).unwrap_err().to_string();
        assert!(e.contains("policy_rate_hz") && e.contains("control_period"), "{e}");
        let bad = text.replace("height = 0.25", "height = 1.5");
        let e = PushTHil::parse(&bad, "t", &p).unwrap_err().to_string();
        assert!(e.contains("world.pusher_start") && e.contains("not reached"), "{e}");
        let bad = text.replace("origin = [0.12, 0.0]", "origin = [-0.05, 0.0]");
        let e = PushTHil::parse(&bad, "t", &p).unwrap_err().to_string();
        assert!(e.contains("table.workspace") && e.contains("not reachable"), "{e}");
    }
}
