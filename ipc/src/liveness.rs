//! Liveness through iceoryx2 events: each side learns within milliseconds that the other died.
//!
//! Each side owns one event service, `mars/<robot>/liveness/hal` and `mars/<robot>/liveness/controller`, with
//! iceoryx2's [deadline](HEARTBEAT_DEADLINE) and a `notifier_dead_event`. A side sends [`Heartbeat`]s on its
//! own service (one every [`HEARTBEAT_PERIOD`]); the other side runs a [`PeerWatch`] on it: a thread blocked on
//! an iceoryx2 `WaitSet` with the listener attached *as a deadline*. The watch states are:
//!
//! - heartbeats arrive → [`Peer::Alive`];
//! - the WaitSet reports the deadline missed → [`Peer::Late`]. A peer that is only slow stays `Late` until its
//!   next heartbeat;
//! - a process of the peer ended → [`Peer::Dead`] at once. The watch holds each process of the service's
//!   notifiers by a pidfd from the peer's first heartbeats on (`peer_process.rs`), attached to the same WaitSet,
//!   so the kernel's end of the process wakes it (for a HAL with locked memory that end comes tens of ms after
//!   a SIGKILL, well after the deadline). Where it cannot hold them ([`Route::Registry`]), it looks the
//!   notifiers' nodes up in iceoryx2's registry (every node of the machine, 3–12 ms on a busy VM) at each
//!   missed deadline instead. After a death it asks iceoryx2 to clean up dead nodes, which also emits the
//!   service's `notifier_dead_event` on behalf of a dead notifier (→ [`Peer::Dead`] too, for a death another
//!   process found first); the clean-up removes files, so it waits on a busy disk, and the verdict does not wait
//!   for it;
//! - the peer dropped its notifier (a clean exit: `notifier_dropped_event`) → [`Peer::Left`].
//!
//! The watch thread publishes its verdict in an atomic, so a real-time loop reads it with one load per tick and
//! never blocks on the wire. A new peer (a restarted controller) makes the state `Alive` again; [`PeerWatch::deaths`]
//! counts deaths so a caller can see one that was followed quickly by a restart.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use iceoryx2::identifiers::UniqueNodeId;
use iceoryx2::node::NodeView;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::{Notifier, NotifierNotifyError};
use iceoryx2::prelude::*;

use crate::names::RobotNamespace;
use crate::node::create_node;
use crate::peer_process::PeerProcesses;
use crate::wire::WireError;

/// Longest silence of a live peer: a heartbeat must arrive at least this often.
pub const HEARTBEAT_DEADLINE: Duration = Duration::from_millis(10);
/// How often [`Heartbeat::beat`] actually notifies (it may be called more often, e.g. every tick).
pub const HEARTBEAT_PERIOD: Duration = Duration::from_millis(2);

const HEARTBEAT: usize = 1;
const DROPPED: usize = 2;
const DEAD: usize = 3;
const MAX_PORTS: usize = 8;
const MAX_NODES: usize = 16;

/// Which side's liveness service.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    Hal,
    Controller,
}

impl Side {
    fn service(self, ns: &RobotNamespace) -> Result<ServiceName, WireError> {
        let name = format!("mars/{}/liveness/{}", ns.robot(), if self == Side::Hal { "hal" } else { "controller" });
        ServiceName::new(&name).map_err(|e| WireError::Service { service: name.clone(), reason: format!("{e:?}") })
    }
}

type EventService = iceoryx2::service::port_factory::event::PortFactory<ipc::Service>;

fn open(node: &Node<ipc::Service>, ns: &RobotNamespace, side: Side) -> Result<(ServiceName, EventService), WireError> {
    let name = side.service(ns)?;
    let service = node
        .service_builder(&name)
        .event()
        .deadline(HEARTBEAT_DEADLINE)
        .notifier_dead_event(EventId::new(DEAD))
        .notifier_dropped_event(EventId::new(DROPPED))
        .disable_notifier_created_event()
        .event_id_max_value(DEAD)
        .max_notifiers(MAX_PORTS)
        .max_listeners(MAX_PORTS)
        .max_nodes(MAX_NODES)
        .open_or_create()
        .map_err(|e| WireError::Service { service: name.as_str().to_owned(), reason: format!("{e:?}") })?;
    Ok((name, service))
}

/// Announces that this side is alive.
pub struct Heartbeat {
    name: ServiceName,
    notifier: Notifier<ipc::Service>,
    last: Option<Instant>,
}

impl Heartbeat {
    /// A heartbeat for `side` (the side that owns `node`).
    pub fn new(node: &Node<ipc::Service>, ns: &RobotNamespace, side: Side) -> Result<Self, WireError> {
        let (name, service) = open(node, ns, side)?;
        let notifier = service
            .notifier_builder()
            .default_event_id(EventId::new(HEARTBEAT))
            .create()
            .map_err(|e| WireError::Port { service: name.as_str().to_owned(), reason: format!("{e:?}") })?;
        Ok(Self { name, notifier, last: None })
    }

    /// Notify the watchers if [`HEARTBEAT_PERIOD`] passed since the last notification; cheap otherwise.
    pub fn beat(&mut self) -> Result<(), WireError> {
        let now = Instant::now();
        if self.last.is_some_and(|t| now.duration_since(t) < HEARTBEAT_PERIOD) {
            return Ok(());
        }
        self.last = Some(now);
        match self.notifier.notify() {
            // Delivered; we were merely silent for longer than the deadline (e.g. before the first beat).
            Ok(_) | Err(NotifierNotifyError::MissedDeadline) => Ok(()),
            Err(e) => Err(WireError::Port { service: self.name.as_str().to_owned(), reason: format!("{e:?}") }),
        }
    }
}

/// What a [`PeerWatch`] knows about the other side.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Peer {
    /// No heartbeat seen yet.
    Unknown = 0,
    Alive = 1,
    /// It missed its deadline but is not known to be dead.
    Late = 2,
    /// Its process died (iceoryx2's `notifier_dead_event`).
    Dead = 3,
    /// It closed its heartbeat (a clean exit).
    Left = 4,
}

impl Peer {
    fn from_u8(v: u8) -> Self {
        match v {
            1 => Self::Alive,
            2 => Self::Late,
            3 => Self::Dead,
            4 => Self::Left,
            _ => Self::Unknown,
        }
    }
}

struct Shared {
    state: AtomicU8,
    deaths: AtomicU64,
    exits: AtomicU64,
    route: AtomicU8,
    stop: AtomicBool,
}

impl Shared {
    fn peer(&self) -> Peer {
        Peer::from_u8(self.state.load(Ordering::Acquire))
    }

    fn route(&self) -> Route {
        match self.route.load(Ordering::Acquire) {
            1 => Route::Pidfd,
            2 => Route::Registry,
            _ => Route::Unknown,
        }
    }
}

/// How a [`PeerWatch`] learns that its peer's process died.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Route {
    /// No peer followed yet.
    Unknown = 0,
    /// Every peer process is held by a pidfd on the watch's WaitSet: its end wakes the watch at once.
    Pidfd = 1,
    /// At each missed deadline, from iceoryx2's node registry (3–12 ms per look-up on a busy VM): the peer's
    /// processes could not be held (another pid namespace, a process this one may not see).
    Registry = 2,
}

/// Watches the other side's heartbeat from a thread blocked on an iceoryx2 WaitSet with a deadline.
pub struct PeerWatch {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

/// The controller's view of the HAL.
pub type HalLiveness = PeerWatch;
/// The HAL's view of the controller.
pub type ControllerLiveness = PeerWatch;

impl PeerWatch {
    /// Watch the HAL of `ns` (for a controller).
    pub fn hal(ns: &RobotNamespace) -> Result<HalLiveness, WireError> {
        Self::spawn(ns, Side::Hal)
    }

    /// Watch the controller of `ns` (for the HAL).
    pub fn controller(ns: &RobotNamespace) -> Result<ControllerLiveness, WireError> {
        Self::spawn(ns, Side::Controller)
    }

    /// Watch `side`'s heartbeat. Returns once the listener is attached, so no later heartbeat is missed.
    pub fn spawn(ns: &RobotNamespace, side: Side) -> Result<Self, WireError> {
        Self::spawn_then(ns, side, || {})
    }

    /// As [`PeerWatch::spawn`], the watch thread first running `setup` (marsd raises it to a real-time priority
    /// there, so that a busy machine cannot delay the verdict).
    pub fn spawn_then(
        ns: &RobotNamespace,
        side: Side,
        setup: impl FnOnce() + Send + 'static,
    ) -> Result<Self, WireError> {
        let shared = Arc::new(Shared {
            state: AtomicU8::new(0),
            deaths: AtomicU64::new(0),
            exits: AtomicU64::new(0),
            route: AtomicU8::new(Route::Unknown as u8),
            stop: AtomicBool::new(false),
        });
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let ns = ns.clone();
        let thread_shared = shared.clone();
        let thread = std::thread::Builder::new()
            .name(format!("mars-watch-{side:?}").to_lowercase())
            .spawn(move || {
                setup();
                let opened = (|| {
                    let watcher = if side == Side::Hal { "controller" } else { "hal" };
                    let (node, _) = create_node(&format!("mars-{watcher}-watch-{}", ns.robot()))?;
                    let (name, service) = open(&node, &ns, side)?;
                    let listener = service
                        .listener_builder()
                        .create()
                        .map_err(|e| WireError::Port { service: name.as_str().to_owned(), reason: format!("{e:?}") })?;
                    Ok::<_, WireError>((node, service, listener))
                })();
                match opened {
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                    }
                    Ok((node, service, listener)) => watch_loop(&node, &service, &listener, &thread_shared, ready_tx),
                }
            })
            .map_err(|e| WireError::Node(format!("spawning the liveness watch: {e}")))?;
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(Self { shared, thread: Some(thread) }),
            Ok(Err(e)) => Err(e),
            Err(_) => Err(WireError::Node("the liveness watch thread died during setup".into())),
        }
    }

    /// The current verdict (one atomic load).
    pub fn peer(&self) -> Peer {
        self.shared.peer()
    }

    /// How many times the peer was found dead since the watch started.
    pub fn deaths(&self) -> u64 {
        self.shared.deaths.load(Ordering::Acquire)
    }

    /// How the watch learns of the peer's death, as decided when it last saw a new peer.
    pub fn route(&self) -> Route {
        self.shared.route()
    }

    /// A read-only handle on how the watch reaches its verdict, for another thread (the watch stays with its owner).
    pub fn view(&self) -> PeerView {
        PeerView { shared: self.shared.clone() }
    }

    /// How many times a peer closed its heartbeat (clean exits) since the watch started.
    pub fn exits(&self) -> u64 {
        self.shared.exits.load(Ordering::Acquire)
    }

    /// Deaths plus clean exits: a count that grows whenever a peer went away, for edge-triggered reactions.
    pub fn losses(&self) -> u64 {
        self.deaths() + self.exits()
    }
}

/// What another thread may read of a [`PeerWatch`]: how it reaches its verdict (marsd's supervisor logs it).
#[derive(Clone)]
pub struct PeerView {
    shared: Arc<Shared>,
}

impl PeerView {
    /// How the watch learns of the peer's death, as decided when it last saw a new peer.
    pub fn route(&self) -> Route {
        self.shared.route()
    }
}

impl Drop for PeerWatch {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The nodes of the service's notifiers, each once, into `into` (cleared first).
fn notifier_nodes(service: &EventService, into: &mut Vec<UniqueNodeId>) {
    into.clear();
    service.dynamic_config().list_notifiers(|n| {
        if !into.contains(&n.node_id) {
            into.push(n.node_id);
        }
        CallbackProgression::Continue
    });
}

/// The peer's process is gone: the service has notifiers and the node of every one is dead, as iceoryx2's node
/// registry says (no clean-up, which writes, so a busy disk does not delay the answer; but a listing of every
/// node of the machine, 3–12 ms on a busy VM: the fallback where [`PeerProcesses`] cannot answer).
fn peer_died(service: &EventService, config: &Config) -> bool {
    let mut nodes = Vec::with_capacity(MAX_PORTS);
    notifier_nodes(service, &mut nodes);
    let mut dead = 0;
    let listed = Node::<ipc::Service>::list(config, |state| {
        if let NodeState::Dead(view) = &state
            && nodes.contains(view.id())
        {
            dead += 1;
        }
        CallbackProgression::Continue
    });
    listed.is_ok() && dead > 0 && dead == nodes.len()
}

/// What ended one stretch of watching a fixed set of peer processes.
enum Change {
    /// The watch was asked to stop.
    Stop,
    /// The heartbeat's notifier nodes changed: resolve the peer's processes again.
    Notifiers,
    /// A held process exited: let go of it.
    Exited,
    /// The held processes could not be attached to the WaitSet: fall back to iceoryx2's look-up.
    Unattachable,
}

/// The watch thread's state, apart from the peer's processes (which its WaitSet borrows while it waits).
struct Watch<'a> {
    node: &'a Node<ipc::Service>,
    service: &'a EventService,
    listener: &'a Listener<ipc::Service>,
    shared: &'a Shared,
    /// A death we declared ourselves, whose `notifier_dead_event` (from the clean-up) is still to come: that event
    /// must not count it twice.
    dead_event_due: bool,
    /// The heartbeat's notifier nodes, as last listed.
    nodes: Vec<UniqueNodeId>,
}

fn watch_loop(
    node: &Node<ipc::Service>,
    service: &EventService,
    listener: &Listener<ipc::Service>,
    shared: &Shared,
    ready: std::sync::mpsc::Sender<Result<(), WireError>>,
) {
    let waitset = match WaitSetBuilder::new().create::<ipc::Service>() {
        Ok(w) => w,
        Err(e) => {
            let _ = ready.send(Err(WireError::Node(format!("creating the WaitSet: {e:?}"))));
            return;
        }
    };
    let deadline = listener.deadline().unwrap_or(HEARTBEAT_DEADLINE);
    let beats = match waitset.attach_deadline(listener, deadline) {
        Ok(g) => g,
        Err(e) => {
            let _ = ready.send(Err(WireError::Node(format!("attaching the heartbeat deadline: {e:?}"))));
            return;
        }
    };
    let _ = ready.send(Ok(()));
    let mut watch = Watch { node, service, listener, shared, dead_event_due: false, nodes: Vec::new() };
    let mut peers = PeerProcesses::default();
    loop {
        // The WaitSet wakes on the held processes' ends too, for as long as the set of them stays the same.
        let change = match peers.ends().iter().map(|e| waitset.attach_notification(e)).collect::<Result<Vec<_>, _>>() {
            Ok(ends) => watch.until_change(&waitset, &beats, &ends, &peers),
            Err(_) => Change::Unattachable,
        };
        match change {
            Change::Stop => return,
            // The route stays: the peer was held, and a new one is resolved at its first heartbeat.
            Change::Exited => {
                peers.drop_exited();
                continue;
            }
            Change::Notifiers => peers.follow::<ipc::Service>(&watch.nodes, node.config()),
            Change::Unattachable => peers.release(),
        }
        let route = if peers.held() { Route::Pidfd } else { Route::Registry };
        shared.route.store(route as u8, Ordering::Release);
    }
}

impl Watch<'_> {
    fn get(&self) -> Peer {
        self.shared.peer()
    }

    fn set(&self, p: Peer) {
        self.shared.state.store(p as u8, Ordering::Release);
    }

    fn declare_dead(&self) {
        self.shared.deaths.fetch_add(1, Ordering::AcqRel);
        self.set(Peer::Dead);
    }

    /// Waits and judges until the set of peer processes to hold changes (or the watch stops).
    fn until_change(
        &mut self,
        waitset: &WaitSet<ipc::Service>,
        beats: &WaitSetGuard<ipc::Service>,
        ends: &[WaitSetGuard<ipc::Service>],
        peers: &PeerProcesses,
    ) -> Change {
        while !self.shared.stop.load(Ordering::Acquire) {
            let (mut events, mut missed, mut ended) = (false, false, false);
            let on_wake = |id: WaitSetAttachmentId<ipc::Service>| {
                if id.has_event_from(beats) {
                    events = true;
                } else if id.has_missed_deadline(beats) {
                    missed = true;
                } else if ends.iter().any(|e| id.has_event_from(e)) {
                    ended = true;
                }
                CallbackProgression::Continue
            };
            // Wake at least every 50 ms to notice `stop`.
            if waitset.wait_and_process_once_with_timeout(on_wake, Duration::from_millis(50)).is_err() {
                std::thread::sleep(Duration::from_millis(1));
                continue;
            }
            if events && self.on_events() && self.nodes != peers.nodes() {
                return Change::Notifiers;
            }
            if ended {
                self.on_process_end(peers);
                return Change::Exited;
            }
            if missed && matches!(self.get(), Peer::Alive | Peer::Late) {
                self.on_missed_deadline(peers);
            }
        }
        Change::Stop
    }

    /// Reads the listener's events; true if a heartbeat came (the notifier nodes were listed again).
    fn on_events(&mut self) -> bool {
        let (mut beat, mut dead, mut left) = (false, false, false);
        let _ = self.listener.try_wait(|a| match a.id.as_value() {
            HEARTBEAT => beat = true,
            DEAD => dead = true,
            DROPPED => left = true,
            _ => {}
        });
        if dead && std::mem::take(&mut self.dead_event_due) {
            dead = false;
        }
        if beat {
            // A new peer: a dead event still due would be about its predecessor, already counted.
            self.dead_event_due = false;
            notifier_nodes(self.service, &mut self.nodes);
        }
        if dead {
            self.declare_dead();
        } else if left {
            self.shared.exits.fetch_add(1, Ordering::AcqRel);
            self.set(Peer::Left);
        } else if beat {
            self.set(Peer::Alive);
        }
        beat
    }

    /// A held process ended. The kernel has finished it (freed its memory, closed its files: 20–100 ms after a
    /// SIGKILL for a process with locked memory), which is the moment iceoryx2 too could first tell it dead.
    fn on_process_end(&mut self, peers: &PeerProcesses) {
        // A peer that left cleanly, or one already declared dead, exits without a new verdict.
        if matches!(self.get(), Peer::Alive | Peer::Late) && peers.all_gone() == Some(true) {
            self.declare_dead();
            self.dead_event_due = true;
            // Emits the dead notifier's notifier_dead_event to our listener (read on a next round) and frees what
            // the dead node held: file work (5–20 ms, timed once), done after the verdict.
            self.node.try_cleanup_dead_nodes();
        }
    }

    /// The peer missed its deadline: late, and dead if iceoryx2's registry says so where its processes are not
    /// held (held ones wake the WaitSet themselves when they end).
    fn on_missed_deadline(&mut self, peers: &PeerProcesses) {
        self.set(Peer::Late);
        if peers.held() {
            return;
        }
        if peer_died(self.service, self.node.config()) {
            self.declare_dead();
            self.dead_event_due = true;
        }
        self.node.try_cleanup_dead_nodes();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicU32;

    fn unique_ns() -> RobotNamespace {
        static N: AtomicU32 = AtomicU32::new(0);
        RobotNamespace::new(&format!("live{}-{}", std::process::id(), N.fetch_add(1, Ordering::Relaxed))).unwrap()
    }

    fn wait_for(watch: &PeerWatch, want: Peer, timeout: Duration) -> Duration {
        let start = Instant::now();
        while watch.peer() != want {
            assert!(start.elapsed() < timeout, "still {:?} after {timeout:?}, wanted {want:?}", watch.peer());
            std::thread::sleep(Duration::from_micros(200));
        }
        start.elapsed()
    }

    #[test]
    fn heartbeats_make_the_peer_alive_silence_makes_it_late_and_a_clean_exit_left() {
        let ns = unique_ns();
        let watch = PeerWatch::hal(&ns).unwrap();
        assert_eq!(watch.peer(), Peer::Unknown);
        let (node, _) = create_node("hb-test").unwrap();
        let mut hb = Heartbeat::new(&node, &ns, Side::Hal).unwrap();
        let start = Instant::now();
        while start.elapsed() < Duration::from_millis(100) {
            hb.beat().unwrap();
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(watch.peer(), Peer::Alive);
        assert_eq!(watch.route(), Route::Pidfd, "a peer on this machine is held by pidfd");
        // Silent but alive: late, never dead.
        wait_for(&watch, Peer::Late, Duration::from_secs(2));
        std::thread::sleep(Duration::from_millis(100));
        assert_eq!(watch.peer(), Peer::Late);
        assert_eq!(watch.deaths(), 0);
        hb.last = None;
        hb.beat().unwrap();
        wait_for(&watch, Peer::Alive, Duration::from_secs(2));
        drop(hb);
        wait_for(&watch, Peer::Left, Duration::from_secs(2));
        assert_eq!((watch.deaths(), watch.exits(), watch.losses()), (0, 1, 1));
    }

    #[test]
    fn watching_the_other_side_does_not_see_our_own_heartbeat() {
        let ns = unique_ns();
        let watch = PeerWatch::controller(&ns).unwrap();
        let (node, _) = create_node("hb-test").unwrap();
        let mut hb = Heartbeat::new(&node, &ns, Side::Hal).unwrap();
        for _ in 0..20 {
            hb.beat().unwrap();
            std::thread::sleep(Duration::from_millis(2));
        }
        assert_eq!(watch.peer(), Peer::Unknown);
    }
}
