//! The Franka Hand on threads of its own: its commands block for as long as the fingers move (seconds), so the
//! 1 kHz loop only hands a target over (a wait-free ring) and reads the last measured width (an atomic).
//!
//! - A *commander* thread takes the newest target: closing below `[fci] grasp_below_m` is a grasp (close with the
//!   profile's force until the fingers stop; it succeeds when they stop between 5 mm inside the target and where
//!   they started, i.e. on an object), sent once the target has stood still for 60 ms (a policy's closing ramp is
//!   one grasp, not many); any other target is a move, sent at once. A grasp that closes on nothing is reported (a warning, a counter) and never
//!   retried: the next attempt is the controller's to make.
//! - A *reader* thread reads the hand's state stream and publishes the width.
//!
//! Both end when the [`Hand`] is dropped (after the command in flight, which the robot finishes on its own).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use franka::Gripper;
use tracing::{info, warn};

use super::error::FciError;
use crate::gripper::GripperMove;

/// How long a closing target must stay unchanged before it is grasped.
const GRASP_SETTLE: Duration = Duration::from_millis(60);

/// What the hand did, counted since start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct HandCounts {
    pub moves: u64,
    pub grasps: u64,
    /// Grasps that closed on nothing (the fingers passed the target).
    pub grasp_failures: u64,
    /// Commands or reads that failed (the hand refused, or its connection broke).
    pub errors: u64,
}

#[derive(Default)]
struct Counters {
    moves: AtomicU64,
    grasps: AtomicU64,
    grasp_failures: AtomicU64,
    errors: AtomicU64,
}

pub struct Hand {
    targets: rtrb::Producer<GripperMove>,
    width: Arc<AtomicU64>,
    counters: Arc<Counters>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

/// The hand's address for a robot at `robot_addr`: the same host on the hand's own port (1338 unless given).
fn hand_addr(robot_addr: &str) -> String {
    match robot_addr.rsplit_once(':') {
        Some((host, port)) if port.parse::<u16>().is_ok() && !host.is_empty() => host.to_string(),
        _ => robot_addr.to_string(),
    }
}

impl Hand {
    /// Connects to the hand of the robot at `robot_addr` and reads its width, both within `timeout`.
    pub fn start(robot_addr: &str, timeout: Duration, grasp: Grasp) -> Result<Self, FciError> {
        let addr = hand_addr(robot_addr);
        let owned = addr.clone();
        let gripper = match super::connect::run_bounded("fci-hand-connect", timeout, move || Gripper::new(&owned)) {
            Ok(Ok(g)) => Arc::new(g),
            Ok(Err(e)) => return Err(FciError::from_franka(&format!("{addr} (hand)"), e)),
            Err(e) => return Err(e.into_error(&format!("{addr} (hand)"), "connecting to the hand", timeout)),
        };
        let g = Arc::clone(&gripper);
        let first = match super::connect::run_bounded("fci-hand-read", timeout, move || g.read_once()) {
            Ok(Ok(s)) => s,
            Ok(Err(e)) => return Err(FciError::from_franka(&format!("{addr} (hand)"), e)),
            Err(e) => return Err(e.into_error(&format!("{addr} (hand)"), "reading the hand", timeout)),
        };
        info!(width = first.width, max_width = first.max_width, "Franka Hand connected");
        let width = Arc::new(AtomicU64::new(first.width.to_bits()));
        let counters = Arc::new(Counters::default());
        let stop = Arc::new(AtomicBool::new(false));
        // Capacity 8: the loop sends at most one target per gripper interval; the commander keeps the newest.
        let (targets, mut rx) = rtrb::RingBuffer::<GripperMove>::new(8);

        let (g, w, c, s) = (Arc::clone(&gripper), Arc::clone(&width), Arc::clone(&counters), Arc::clone(&stop));
        let reader = std::thread::Builder::new()
            .name("fci-hand-state".into())
            .spawn(move || {
                while !s.load(Ordering::Acquire) {
                    match g.read_once() {
                        Ok(st) => w.store(st.width.to_bits(), Ordering::Release),
                        Err(e) => {
                            c.errors.fetch_add(1, Ordering::Relaxed);
                            warn!("reading the Franka Hand failed: {e}");
                            std::thread::sleep(Duration::from_millis(200));
                        }
                    }
                }
            })
            .map_err(|source| FciError::Thread { addr: addr.clone(), source })?;

        let (g, w, c, s) = (gripper, Arc::clone(&width), Arc::clone(&counters), Arc::clone(&stop));
        let commander = std::thread::Builder::new()
            .name("fci-hand-command".into())
            .spawn(move || {
                let mut pending: Option<(GripperMove, Instant)> = None;
                // After a successful grasp the hand holds its object with force: a narrower target changes nothing.
                let mut holding = false;
                while !s.load(Ordering::Acquire) {
                    while let Ok(mv) = rx.pop() {
                        pending = Some((mv, Instant::now()));
                    }
                    let Some((mv, since)) = pending else {
                        std::thread::sleep(Duration::from_millis(2));
                        continue;
                    };
                    let now = f64::from_bits(w.load(Ordering::Acquire));
                    // A closing target is grasped only once it stopped moving: the steps of a closing ramp would
                    // each be a grasp of their own (closing on nothing, fully).
                    if grasp.is_grasp(mv.width, now) && since.elapsed() < GRASP_SETTLE {
                        std::thread::sleep(Duration::from_millis(2));
                        continue;
                    }
                    pending = None;
                    if holding && grasp.is_grasp(mv.width, now) {
                        continue;
                    }
                    holding = execute(&g, &c, mv, now, grasp);
                }
            })
            .map_err(|source| FciError::Thread { addr: hand_addr(robot_addr), source })?;
        Ok(Hand { targets, width, counters, stop, threads: vec![reader, commander] })
    }

    /// The last measured opening (m).
    pub fn width(&self) -> f64 {
        f64::from_bits(self.width.load(Ordering::Acquire))
    }

    /// Hands a new target to the commander; wait-free, never allocates. False if the ring is full (the
    /// commander is stuck in a command while targets keep coming).
    pub fn request(&mut self, mv: GripperMove) -> bool {
        self.targets.push(mv).is_ok()
    }

    pub fn counts(&self) -> HandCounts {
        let c = &self.counters;
        HandCounts {
            moves: c.moves.load(Ordering::Relaxed),
            grasps: c.grasps.load(Ordering::Relaxed),
            grasp_failures: c.grasp_failures.load(Ordering::Relaxed),
            errors: c.errors.load(Ordering::Relaxed),
        }
    }
}

/// When a target is a grasp, and with what force.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grasp {
    /// Closing targets below this width (m) are grasps.
    pub below_m: f64,
    pub force_n: f64,
}

impl Grasp {
    fn is_grasp(&self, target: f64, now: f64) -> bool {
        target < now && target < self.below_m
    }
}

/// A grasp or a move to `mv.width` from `now` (see [`Grasp`]); whether the hand now holds an object.
fn execute(g: &Gripper, c: &Counters, mv: GripperMove, now: f64, grasp: Grasp) -> bool {
    let force = grasp.force_n;
    if grasp.is_grasp(mv.width, now) {
        c.grasps.fetch_add(1, Ordering::Relaxed);
        // Success when the fingers stop anywhere from 5 mm inside the target (libfranka's default tolerance) to
        // 5 mm beyond where they started: on an object. Closing past that means nothing was between them.
        match g.grasp(mv.width, mv.speed, force, 0.005, (now - mv.width).max(0.0) + 0.005) {
            Ok(true) => return true,
            Ok(false) => {
                c.grasp_failures.fetch_add(1, Ordering::Relaxed);
                warn!(target = mv.width, "the Franka Hand closed on nothing (grasp failed); not retried");
            }
            Err(e) => {
                c.errors.fetch_add(1, Ordering::Relaxed);
                warn!(target = mv.width, "the Franka Hand refused a grasp: {e}");
            }
        }
    } else {
        c.moves.fetch_add(1, Ordering::Relaxed);
        if let Err(e) = g
            .move_gripper(mv.width, mv.speed)
            .and_then(|ok| ok.then_some(()).ok_or_else(|| franka::FrankaError::Command("move unsuccessful".into())))
        {
            c.errors.fetch_add(1, Ordering::Relaxed);
            warn!(target = mv.width, "the Franka Hand did not move: {e}");
        }
    }
    false
}

impl Drop for Hand {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        // The reader wakes within the hand's state period; the commander after the command in flight. Neither is
        // joined past a bound: a hand that stopped answering must not hold the HAL's exit.
        let end = std::time::Instant::now() + Duration::from_secs(2);
        for t in self.threads.drain(..) {
            while !t.is_finished() && std::time::Instant::now() < end {
                std::thread::sleep(Duration::from_millis(5));
            }
            if t.is_finished() {
                let _ = t.join();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Grasp, hand_addr};

    #[test]
    fn only_closing_targets_below_the_threshold_are_grasps() {
        let g = Grasp { below_m: 0.05, force_n: 20.0 };
        assert!(g.is_grasp(0.02, 0.07), "closing toward an object");
        assert!(!g.is_grasp(0.07, 0.08), "closing to an opening is a move");
        assert!(!g.is_grasp(0.04, 0.03), "opening is a move");
    }

    #[test]
    fn the_hand_is_reached_on_the_robots_host_at_its_own_port() {
        assert_eq!(hand_addr("172.16.0.2"), "172.16.0.2");
        assert_eq!(hand_addr("127.0.0.1:1337"), "127.0.0.1");
        assert_eq!(hand_addr("robot.local"), "robot.local");
    }
}
