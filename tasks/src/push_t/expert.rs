//! The scripted demonstrator: around the block by its route, then push the back of the bar toward the goal,
//! steering the block's angle by pushing off-centre (the bar is wide enough to turn the T either way). Closed loop: every action is computed from the
//! current state, in the block's own frame.

use super::{PushTConfig, PushTState, wrap};

/// Which side of the block the pusher passes on its way to the stem.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Route {
    /// Over the bar's +y end.
    Upper,
    /// Under its −y end.
    Lower,
}

impl Route {
    pub fn side(self) -> f32 {
        match self {
            Route::Upper => 1.0,
            Route::Lower => -1.0,
        }
    }

    /// The mode index a dataset records (0 upper, 1 lower).
    pub fn index(self) -> usize {
        match self {
            Route::Upper => 0,
            Route::Lower => 1,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Heading for waypoint i of the way around.
    Around(usize),
    Push,
}

pub struct Expert {
    cfg: PushTConfig,
    route: Route,
    phase: Phase,
}

/// A point in the block's frame (x, y) → the table frame, for block pose b.
fn to_world(b: [f32; 3], p: [f32; 2]) -> [f32; 2] {
    let (s, c) = b[2].sin_cos();
    [b[0] + c * p[0] - s * p[1], b[1] + s * p[0] + c * p[1]]
}

/// A table point in block pose b's frame.
pub fn to_block(b: [f32; 3], p: [f32; 2]) -> [f32; 2] {
    let (s, c) = b[2].sin_cos();
    let (dx, dy) = (p[0] - b[0], p[1] - b[1]);
    [c * dx + s * dy, -s * dx + c * dy]
}

fn dist(a: [f32; 2], b: [f32; 2]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

impl Expert {
    pub fn new(cfg: &PushTConfig, route: Route) -> Self {
        Self { cfg: cfg.clone(), route, phase: Phase::Around(0) }
    }

    pub fn route(&self) -> Route {
        self.route
    }

    /// Where the pusher waits behind the bar (x in the block frame) and its clearance beside the bar (y).
    fn behind_and_beside(&self) -> (f32, f32) {
        let c = &self.cfg;
        (-c.bar[1] / 2.0 - c.pusher_radius - 0.02, c.bar[0] / 2.0 + c.pusher_radius + 0.03)
    }

    /// Where the pusher should go next.
    pub fn act(&mut self, s: &PushTState) -> [f32; 2] {
        let (behind, clear) = self.behind_and_beside();
        let side = self.route.side();
        let b = s.block;
        let ways = [[0.04, side * clear], [behind, side * clear], [behind, 0.0]];
        if let Phase::Around(i) = self.phase {
            let w = to_world(b, ways[i]);
            if dist(s.pusher, w) > 0.01 {
                return w;
            }
            self.phase = if i + 1 < ways.len() { Phase::Around(i + 1) } else { Phase::Push };
            if let Phase::Around(j) = self.phase {
                return to_world(b, ways[j]);
            }
        }
        self.push(s, behind)
    }

    fn push(&mut self, s: &PushTState, behind: f32) -> [f32; 2] {
        let c = &self.cfg;
        let b = s.block;
        let [gx, gy, ga] = c.goal;
        let (ex, ey) = (gx - b[0], gy - b[1]);
        let e = (ex * ex + ey * ey).sqrt();
        let turn = wrap(ga - b[2]);
        if e < 0.005 && turn.abs() < 0.05 {
            return s.pusher;
        }
        // Push along the goal direction (in the block frame); steer the angle by the contact's offset along the
        // bar: pushing at +y turns the block clockwise, at −y counter-clockwise.
        let dir = if e > 1e-4 { to_block([0.0, 0.0, b[2]], [ex / e, ey / e]) } else { [1.0, 0.0] };
        let offset = (-0.15 * turn).clamp(-0.3 * c.bar[0], 0.3 * c.bar[0]);
        let face = -c.bar[1] / 2.0 - c.pusher_radius;
        let local = to_block(b, s.pusher);
        // Lost contact (the block turned or slid away): back behind the bar first.
        if (local[1] - offset).abs() > 0.03 || local[0] < behind - 0.02 || local[0] > 0.0 {
            self.phase = Phase::Around(2);
            return to_world(b, [behind, 0.0]);
        }
        // The block coasts ~1.5 cm after a push at full speed (damping 8/s): stop advancing that far before the goal.
        let depth = (e - 0.015).clamp(0.0, 0.02);
        to_world(b, [face + dir[0] * depth, offset + dir[1] * depth])
    }
}

/// The route a pusher path took around a block path: the side of the bar the pusher was on when it first got
/// behind the bar's plane (it cannot pass through the bar). `None` if it never got behind.
pub fn route_taken(pusher: &[[f32; 2]], block: &[[f32; 3]]) -> Option<Route> {
    pusher
        .iter()
        .zip(block)
        .map(|(p, b)| to_block(*b, *p))
        .find(|l| l[0] < 0.0)
        .map(|l| if l[1] >= 0.0 { Route::Upper } else { Route::Lower })
}
