//! End-effector actions in the servo tick: a policy that acts on the table (Push-T: where the pusher should be)
//! hands the servo (x, y) references; each tick turns the reference into joint targets by inverse kinematics,
//! seeded from the previous tick's solution, and the joint velocity by the Jacobian, before ruckig limits the
//! joint-space motion as for any other task.
//!
//! Nothing here allocates (fixed-size nalgebra types; `tests/alloc_free_tick.rs` runs a planar tick), and nothing
//! returns a NaN: a reference outside the task's workspace is clamped into it, a target the arm cannot reach (or
//! reaches only along a singular direction) gives the closest configuration found, and each case is counted with
//! its reason for the report.

use mars_kinematics::{Arm, IkError, IkParams, Joints, Plane, flange_pose, jacobian, solve};
use nalgebra::{Matrix6, Vector6};
use serde::Serialize;

/// The rectangle of the table the effector may be sent to: x_min, x_max, y_min, y_max (m).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct Workspace {
    pub x: [f64; 2],
    pub y: [f64; 2],
}

impl Workspace {
    pub fn contains(&self, p: [f64; 2]) -> bool {
        (self.x[0]..=self.x[1]).contains(&p[0]) && (self.y[0]..=self.y[1]).contains(&p[1])
    }

    fn clamp(&self, p: [f64; 2]) -> [f64; 2] {
        [p[0].clamp(self.x[0], self.x[1]), p[1].clamp(self.y[0], self.y[1])]
    }
}

/// What the effector did to the references it was given, counted since the start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct EffectorCounts {
    /// References outside the workspace, moved to its edge.
    pub outside_workspace: u64,
    /// References the IK did not reach within its tolerance: the closest configuration was used.
    pub unreachable: u64,
    /// Non-finite references: the previous target was kept.
    pub not_finite: u64,
}

/// Damping of the velocity map near singular configurations (m): bounds q̇ where J loses rank.
const VELOCITY_DAMPING: f64 = 1e-3;

/// The FR3's flange on a plane above the table, pointing down. Positions are in the table's frame: the base's
/// x, y shifted by `origin` (where the table frame's origin lies in the base frame).
#[derive(Debug, Clone)]
pub struct PlanarEffector {
    arm: Arm,
    plane: Plane,
    origin: [f64; 2],
    workspace: Workspace,
    params: IkParams,
    /// The last solution: the next solve's seed (one tick of motion away).
    q: Joints,
    pub counts: EffectorCounts,
}

impl PlanarEffector {
    pub fn new(arm: Arm, plane: Plane, origin: [f64; 2], workspace: Workspace) -> Self {
        // One tick moves the reference a fraction of a millimetre: a few iterations from the previous solution
        // converge, and the cap bounds the tick's time when one does not. No pull toward the joints' mid-range
        // in the tick: it would move the arm along the null space from tick to tick (0.3 rad/s of joint 0 when
        // measured), which the Jacobian's velocity does not know of; the start pose is centred once instead.
        let params = IkParams { max_iterations: 25, centering: 0.0, ..IkParams::default() };
        Self { arm, plane, origin, workspace, params, q: Joints::zeros(), counts: EffectorCounts::default() }
    }

    pub fn workspace(&self) -> &Workspace {
        &self.workspace
    }

    /// Where the flange is on the table for joints `q` (its x, y; what the policy observes as the effector).
    pub fn xy(&self, q: &[f64]) -> [f64; 2] {
        let p = flange_pose(&self.arm, &joints(q));
        [p.translation.x - self.origin[0], p.translation.y - self.origin[1]]
    }

    /// The flange's target pose for table point `xy`.
    fn pose(&self, xy: [f64; 2]) -> mars_kinematics::Pose {
        self.plane.pose(xy[0] + self.origin[0], xy[1] + self.origin[1])
    }

    /// The joint configuration that puts the flange at `xy` on the plane, searched from `seed` with the full
    /// iteration budget (outside the tick: an episode's start pose).
    pub fn solve_from(&self, xy: [f64; 2], seed: &[f64]) -> Result<Joints, IkError> {
        let params = IkParams { max_iterations: 400, centering: IkParams::default().centering, ..self.params };
        solve(&self.arm, &self.pose(xy), &joints(seed), &params).map(|s| s.q)
    }

    /// Continue from joints `q` (the pose the arm holds when the policy takes over).
    pub fn seed(&mut self, q: &[f64]) {
        self.q = joints(q);
    }

    /// Joint targets (`q_out`) and velocities (`v_out`, the first 7 values each) for the planar reference `xy`
    /// moving at `v`: IK from the previous solution, q̇ = J⁺·(v, 0, 0, 0, 0) at the solution. A reference the IK
    /// does not reach holds the last solution, at rest, and is counted.
    pub fn joints(&mut self, xy: [f64; 2], v: [f64; 2], q_out: &mut [f64], v_out: &mut [f64]) {
        let (xy, v) = if xy.iter().chain(&v).all(|x| x.is_finite()) {
            (xy, v)
        } else {
            self.counts.not_finite += 1;
            (self.xy(self.q.as_slice()), [0.0; 2])
        };
        let inside = self.workspace.clamp(xy);
        // At the edge the reference stops there: its velocity would push the arm past it.
        let v = if inside != xy {
            self.counts.outside_workspace += 1;
            [0.0; 2]
        } else {
            v
        };
        match solve(&self.arm, &self.pose(inside), &self.q, &self.params) {
            Ok(s) => self.q = s.q,
            // Not reached: stay at the last solution rather than follow the closest configuration found, which
            // can drag the joints to their limits, from where the solver does not find its way back (measured:
            // one reference past the reachable region left every later one unreached).
            Err(IkError::Unreachable { .. }) => {
                self.counts.unreachable += 1;
                v_out[..mars_kinematics::JOINTS].fill(0.0);
                q_out[..mars_kinematics::JOINTS].copy_from_slice(self.q.as_slice());
                return;
            }
            // The target and the seed are finite by construction; keep the last solution.
            Err(IkError::NotFinite(_)) => self.counts.not_finite += 1,
        }
        let (_, j) = jacobian(&self.arm, &self.q);
        let twist = Vector6::new(v[0], v[1], 0.0, 0.0, 0.0, 0.0);
        let a: Matrix6<f64> = j * j.transpose() + Matrix6::identity() * VELOCITY_DAMPING.powi(2);
        let qd = a.try_inverse().map_or(Joints::zeros(), |a_inv| j.transpose() * (a_inv * twist));
        for i in 0..mars_kinematics::JOINTS {
            q_out[i] = self.q[i];
            v_out[i] = if qd[i].is_finite() { qd[i] } else { 0.0 };
        }
    }
}

fn joints(q: &[f64]) -> Joints {
    Joints::from_fn(|i, _| q[i])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn effector() -> PlanarEffector {
        PlanarEffector::new(
            Arm::fr3(),
            Plane::pointing_down(0.25),
            [0.12, 0.0],
            Workspace { x: [0.2, 0.6], y: [-0.2, 0.2] },
        )
    }

    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};

    /// The FR3's home (configs/fr3.toml).
    const HOME: [f64; 7] = [0.0, -FRAC_PI_4, 0.0, -3.0 * FRAC_PI_4, 0.0, FRAC_PI_2, FRAC_PI_4];

    #[test]
    fn a_line_on_the_table_is_followed_tick_by_tick_with_consistent_velocities() {
        let mut e = effector();
        let start = e.solve_from([0.45, 0.0], &HOME).unwrap();
        e.seed(start.as_slice());
        let (mut q, mut v) = ([0.0; 7], [0.0; 7]);
        let mut prev = start;
        // 0.15 m/s along y for 0.5 s at 1 kHz.
        for k in 1..=500 {
            let y = 0.15 * k as f64 * 1e-3;
            e.joints([0.45, y], [0.0, 0.15], &mut q, &mut v);
            let at = e.xy(&q);
            assert!((at[0] - 0.45).abs() < 1e-4 && (at[1] - y).abs() < 1e-4, "tick {k}: at {at:?}");
            // The Jacobian's velocity agrees with the solutions' own difference.
            for i in 0..7 {
                let fd = (q[i] - prev[i]) / 1e-3;
                assert!((v[i] - fd).abs() < 0.02, "tick {k} joint {i}: q̇ {} vs difference {fd}", v[i]);
            }
            prev = joints(&q);
        }
        assert_eq!(e.counts, EffectorCounts::default());
    }

    #[test]
    fn an_unreachable_reference_holds_the_last_solution_and_the_arm_comes_back() {
        // A workspace wider than the arm reaches: references past it are not reached.
        let mut e = PlanarEffector::new(
            Arm::fr3(),
            Plane::pointing_down(0.25),
            [0.0; 2],
            Workspace { x: [0.0, 1.0], y: [-0.5, 0.5] },
        );
        let start = e.solve_from([0.45, 0.0], &HOME).unwrap();
        e.seed(start.as_slice());
        let (mut q, mut v) = ([0.0; 7], [0.0; 7]);
        // Toward the base (x 0.45 → 0.10, unreachable pointing down below ~0.28) and back, 0.1 mm per tick.
        let path = (0..=3500).map(|k| 0.45 - 1e-4 * k as f64).chain((0..=3500).map(|k| 0.10 + 1e-4 * k as f64));
        let mut held = None;
        for x in path {
            e.joints([x, 0.0], [0.0; 2], &mut q, &mut v);
            assert!(q.iter().chain(&v).all(|x| x.is_finite()));
            if e.counts.unreachable > 0 && held.is_none() {
                held = Some(q);
            }
        }
        assert!(e.counts.unreachable > 100, "{:?}", e.counts);
        let back = e.xy(&q);
        assert!((back[0] - 0.45).abs() < 1e-4 && back[1].abs() < 1e-4, "did not come back: {back:?} {:?}", e.counts);
    }

    #[test]
    fn outside_the_workspace_and_non_finite_references_are_clamped_and_counted_never_nan() {
        let mut e = effector();
        e.seed(e.solve_from([0.45, 0.0], &HOME).unwrap().as_slice());
        let (mut q, mut v) = ([0.0; 7], [0.0; 7]);
        e.joints([0.9, 0.0], [1.0, 0.0], &mut q, &mut v);
        assert_eq!(e.counts.outside_workspace, 1);
        assert!(v.iter().all(|x| x.is_finite()) && q.iter().all(|x| x.is_finite()));
        e.joints([f64::NAN, 0.0], [0.0, 0.0], &mut q, &mut v);
        assert_eq!(e.counts.not_finite, 1);
        assert!(q.iter().all(|x| x.is_finite()) && v.iter().all(|x| *x == 0.0 || x.is_finite()));
    }
}
