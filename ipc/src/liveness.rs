//! Liveness through iceoryx2 events: each side learns within milliseconds that the other died.
//!
//! Each side owns one event service, `mars/<robot>/liveness/hal` and `mars/<robot>/liveness/controller`, with
//! iceoryx2's [deadline](HEARTBEAT_DEADLINE) and a `notifier_dead_event`. A side sends [`Heartbeat`]s on its
//! own service (one every [`HEARTBEAT_PERIOD`]); the other side runs a [`PeerWatch`] on it: a thread blocked on
//! an iceoryx2 `WaitSet` with the listener attached *as a deadline*. The watch states are:
//!
//! - heartbeats arrive → [`Peer::Alive`];
//! - the WaitSet reports the deadline missed → [`Peer::Late`], and the watch asks whether the peer's processes
//!   are gone → [`Peer::Dead`] at once. It holds each process of the service's notifiers by a pidfd from the
//!   peer's first heartbeats on (`peer_process.rs`): one `poll`, asked again every millisecond while the
//!   peer stays late, so a dying peer whose exit the kernel takes tens of ms to finish is found within about a
//!   millisecond of its end. Where it cannot hold them, it looks the notifiers' nodes up in iceoryx2's registry
//!   (every node of the machine, 3–12 ms on a busy VM) at each missed deadline. After a death, or after each
//!   look-up, it asks iceoryx2 to clean up dead nodes, which also emits the service's `notifier_dead_event` on
//!   behalf of a dead notifier (→ [`Peer::Dead`] too, for a death another process found first); the clean-up
//!   removes files, so it waits on a busy disk, and the verdict does not wait for it. A peer that is only slow
//!   stays `Late` until its next heartbeat;
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

/// How often a watch asks a late peer's processes whether they are gone, and for how long after it turned late
/// (a peer silent longer is stalled, not dying: then only at each missed deadline).
const LATE_POLL: Duration = Duration::from_millis(1);
const LATE_POLL_SPAN: Duration = Duration::from_secs(1);

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
    stop: AtomicBool,
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
        Peer::from_u8(self.shared.state.load(Ordering::Acquire))
    }

    /// How many times the peer was found dead since the watch started.
    pub fn deaths(&self) -> u64 {
        self.shared.deaths.load(Ordering::Acquire)
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

fn watch_loop(
    node: &Node<ipc::Service>,
    service: &EventService,
    listener: &Listener<ipc::Service>,
    shared: &Shared,
    ready: std::sync::mpsc::Sender<Result<(), WireError>>,
) {
    let set = |p: Peer| shared.state.store(p as u8, Ordering::Release);
    let get = || Peer::from_u8(shared.state.load(Ordering::Acquire));
    let waitset = match WaitSetBuilder::new().create::<ipc::Service>() {
        Ok(w) => w,
        Err(e) => {
            let _ = ready.send(Err(WireError::Node(format!("creating the WaitSet: {e:?}"))));
            return;
        }
    };
    let deadline = listener.deadline().unwrap_or(HEARTBEAT_DEADLINE);
    let guard = match waitset.attach_deadline(listener, deadline) {
        Ok(g) => g,
        Err(e) => {
            let _ = ready.send(Err(WireError::Node(format!("attaching the heartbeat deadline: {e:?}"))));
            return;
        }
    };
    let _ = ready.send(Ok(()));
    // A death we declared ourselves, whose `notifier_dead_event` (from the clean-up) is still to come: that event
    // must not count it twice.
    let mut dead_event_due = false;
    // The peer's processes, held from its heartbeats on; when the peer turned late, while it stays so.
    let (mut peers, mut nodes) = (PeerProcesses::default(), Vec::with_capacity(MAX_PORTS));
    let mut late_since: Option<Instant> = None;
    let declare_dead = || {
        shared.deaths.fetch_add(1, Ordering::AcqRel);
        set(Peer::Dead);
    };
    while !shared.stop.load(Ordering::Acquire) {
        let mut missed = false;
        let mut events = false;
        let on_wake = |id: WaitSetAttachmentId<ipc::Service>| {
            if id.has_event_from(&guard) {
                events = true;
            } else if id.has_missed_deadline(&guard) {
                missed = true;
            }
            CallbackProgression::Continue
        };
        // Wake at least every 50 ms to notice `stop`; every millisecond while the peer is late, see below.
        late_since = match get() {
            Peer::Late => late_since.or(Some(Instant::now())),
            _ => None,
        };
        let polling = late_since.is_some_and(|t| t.elapsed() < LATE_POLL_SPAN);
        let timeout = if polling { LATE_POLL } else { Duration::from_millis(50) };
        if waitset.wait_and_process_once_with_timeout(on_wake, timeout).is_err() {
            std::thread::sleep(Duration::from_millis(1));
            continue;
        }
        if events {
            let (mut beat, mut dead, mut left) = (false, false, false);
            let _ = listener.try_wait(|a| match a.id.as_value() {
                HEARTBEAT => beat = true,
                DEAD => dead = true,
                DROPPED => left = true,
                _ => {}
            });
            if dead && std::mem::take(&mut dead_event_due) {
                dead = false;
            }
            if beat {
                // A new peer: a dead event still due would be about its predecessor, already counted.
                dead_event_due = false;
                notifier_nodes(service, &mut nodes);
                peers.follow::<ipc::Service>(&nodes, node.config());
            }
            if dead {
                declare_dead();
            } else if left {
                shared.exits.fetch_add(1, Ordering::AcqRel);
                set(Peer::Left);
            } else if beat {
                set(Peer::Alive);
            }
        }
        // A late peer may be a dying one whose process the kernel is still taking down (freeing its memory,
        // closing its files: 20–100 ms seen). Its pidfds tell the end of that at once, so while it stays late
        // they are asked every millisecond, not only at each missed deadline.
        let look_again = polling && !missed && get() == Peer::Late && peers.held();
        if (missed && matches!(get(), Peer::Alive | Peer::Late)) || look_again {
            set(Peer::Late);
            let held = peers.all_gone();
            let died = held.unwrap_or_else(|| peer_died(service, node.config()));
            if died {
                declare_dead();
                dead_event_due = true;
            }
            if died || held.is_none() {
                // Emits the dead notifier's notifier_dead_event to our listener (read on the next round), and
                // frees what the dead node held. Not while the held peer lives: it is file work (5–20 ms, timed once).
                node.try_cleanup_dead_nodes();
            }
        }
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
