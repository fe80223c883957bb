//! Latency histograms recorded in the real-time loops without allocating, merged and logged off the loop.
//!
//! Each loop thread owns a [`Recorder`]: HdrHistograms for its channels, preallocated with fixed bounds, so
//! recording is an index computation and an increment. Once per interval the thread swaps its filled set for
//! an empty one through two wait-free single-producer/single-consumer rings (`rtrb`) shared with the
//! [`Collector`] thread, which merges the set into the run's totals, appends it to an HdrHistogram interval log
//! (so a run can be inspected over time with the standard tools) and returns it emptied. Nothing on the loop
//! side blocks, spins or allocates: if the collector has not returned a set yet, the loop keeps recording into
//! the current one (the interval just gets longer).

use std::fmt;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, SystemTime};

use anyhow::Context;
use hdrhistogram::Histogram;
use hdrhistogram::serialization::V2DeflateSerializer;
use hdrhistogram::serialization::interval_log::{IntervalLogWriter, IntervalLogWriterBuilder, Tag};
use serde::{Deserialize, Serialize};
use tracing::warn;

use crate::rt::monotonic_ns;

/// Largest K the K histograms hold (larger values are clamped to it).
pub const K_MAX: u64 = 64;
/// Largest time the time histograms hold: 10 s (a longer stall is clamped to it, and is a failure anyway).
pub const TIME_MAX_NS: u64 = 10_000_000_000;
/// Largest ‖w‖∞ the histograms hold, in thousandths (w is a noise scale of order 1).
pub const W_INF_MAX: u64 = 1_000_000;
/// The interval log's file name inside the collector's directory.
pub const LOG_FILE: &str = "latency.hlog";

/// What is measured. Time channels are recorded in nanoseconds; the K channels are unitless.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Channel {
    /// Servo wake-up lateness past its deadline.
    WakeJitter,
    /// Work done in one servo tick.
    TickCompute,
    /// Age of the state frame when it is used.
    StateAge,
    /// State frame receipt → command sent.
    StateToCommand,
    /// One policy call.
    Inference,
    /// ODE steps the policy asked for.
    KRequested,
    /// ODE steps actually run (after the deadline cap).
    KUsed,
    /// A camera frame's capture → the policy reading it as its input (Push-T).
    CameraAge,
    /// Encoding one observation in the engine (the cameras' ResNets, the encoder, w), before the ODE.
    Encode,
    /// A camera frame's capture → the first servo command that follows the chunk computed from it.
    CaptureToCommand,
    /// ‖w‖∞ of each policy call (how much noise MARS injected), recorded in thousandths.
    WInf,
}

/// The live view (`marsd top`) carries every channel.
const _: () = assert!(Channel::COUNT <= mars_ipc::LIVE_CHANNELS);

impl Channel {
    pub const COUNT: usize = 11;
    pub const ALL: [Channel; Channel::COUNT] = [
        Channel::WakeJitter,
        Channel::TickCompute,
        Channel::StateAge,
        Channel::StateToCommand,
        Channel::Inference,
        Channel::KRequested,
        Channel::KUsed,
        Channel::CameraAge,
        Channel::Encode,
        Channel::CaptureToCommand,
        Channel::WInf,
    ];

    /// The tag of its histograms in the interval log.
    pub fn tag(self) -> &'static str {
        match self {
            Channel::WakeJitter => "wake_jitter",
            Channel::TickCompute => "tick_compute",
            Channel::StateAge => "state_age",
            Channel::StateToCommand => "state_to_command",
            Channel::Inference => "inference",
            Channel::KRequested => "k_requested",
            Channel::KUsed => "k_used",
            Channel::CameraAge => "camera_age",
            Channel::Encode => "encode",
            Channel::CaptureToCommand => "capture_to_command",
            Channel::WInf => "w_inf",
        }
    }

    pub fn from_tag(tag: &str) -> Option<Channel> {
        Channel::ALL.into_iter().find(|c| c.tag() == tag)
    }

    pub fn is_time(self) -> bool {
        !matches!(self, Channel::KRequested | Channel::KUsed | Channel::WInf)
    }

    /// The unit of its summary values: µs for time channels (recorded in ns), K for step counts, w for ‖w‖∞.
    pub fn unit(self) -> &'static str {
        match self {
            Channel::KRequested | Channel::KUsed => "K",
            Channel::WInf => "w",
            _ => "us",
        }
    }

    /// Summary value per recorded unit: ns → µs, thousandths of w → w.
    pub fn scale(self) -> f64 {
        match self {
            Channel::KRequested | Channel::KUsed => 1.0,
            _ => 1e-3,
        }
    }

    /// ‖w‖∞ as this channel records it (thousandths).
    pub fn w_inf_units(w_inf: f32) -> u64 {
        (f64::from(w_inf) * 1e3).round().max(0.0) as u64
    }

    /// An empty histogram with this channel's fixed bounds (3 significant digits).
    pub fn new_histogram(self) -> Histogram<u64> {
        let high = match self {
            Channel::KRequested | Channel::KUsed => K_MAX,
            Channel::WInf => W_INF_MAX,
            _ => TIME_MAX_NS,
        };
        Histogram::new_with_bounds(1, high, 3).expect("constant bounds are valid")
    }

    /// Its position in [`Channel::ALL`] (and in a live frame's channels).
    pub fn index(self) -> usize {
        self as usize
    }
}

/// One recorder's histograms for one interval: the unit handed between a recorder and the collector.
struct Interval {
    /// Indexed by [`Channel::index`]; `None` for channels the recorder does not own.
    hists: [Option<Histogram<u64>>; Channel::COUNT],
    start_ns: u64,
    end_ns: u64,
    /// Samples for channels the recorder does not own: a bug in the caller, counted rather than lost silently.
    stray: u64,
    /// The loop's counters at the interval's end, if it handed them over ([`Recorder::end_interval_with`]).
    counters: Option<LoopCounters>,
}

/// Counters the servo loop hands over with an interval (for the live view): its own, and the HAL's as its newest
/// frame says, since the handshake. A copy of plain integers once per interval, into the set it hands over anyway.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LoopCounters {
    pub servo: crate::servo::ServoCounters,
    pub hal: crate::servo::HalCounts,
}

impl Interval {
    fn new(channels: &[Channel]) -> Box<Interval> {
        let mut hists: [Option<Histogram<u64>>; Channel::COUNT] = Default::default();
        for c in channels {
            hists[c.index()] = Some(c.new_histogram());
        }
        Box::new(Interval { hists, start_ns: 0, end_ns: 0, stray: 0, counters: None })
    }
}

/// One interval of one loop as the collector received it, shown to the live hook ([`Collector::start_with`])
/// before it is merged into the totals.
pub struct IntervalView<'a> {
    set: &'a Interval,
}

impl IntervalView<'_> {
    /// CLOCK_MONOTONIC start and end (ns).
    pub fn span_ns(&self) -> (u64, u64) {
        (self.set.start_ns, self.set.end_ns)
    }

    /// The loop's counters at the interval's end, if it handed them over.
    pub fn counters(&self) -> Option<&LoopCounters> {
        self.set.counters.as_ref()
    }

    /// The interval's histogram of `channel`; `None` if this loop does not record it.
    pub fn histogram(&self, channel: Channel) -> Option<&Histogram<u64>> {
        self.set.hists[channel.index()].as_ref()
    }
}

/// Called on the collector thread with every interval it receives and the loops' starved count so far (for a
/// live view; never on a real-time thread).
pub type OnInterval = Box<dyn FnMut(&IntervalView<'_>, u64)>;
/// Makes the [`OnInterval`] on the collector's thread (it may own what cannot leave that thread, such as an
/// iceoryx2 port).
pub type LiveHook = Box<dyn FnOnce() -> OnInterval + Send>;

/// What a recorder and the collector both read about the recorder.
struct PoolInfo {
    name: String,
    /// `end_interval` calls that found no empty set.
    starved: AtomicU64,
}

/// The collector's ends of one recorder's rings. Every set is always in exactly one place: the recorder's
/// hand, `full` or `empty` (or the collector's hand, briefly), so neither ring can ever be full.
struct Pool {
    info: Arc<PoolInfo>,
    /// Filled sets: the loop thread (recorder) produces, the collector consumes.
    full: rtrb::Consumer<Box<Interval>>,
    /// Emptied sets: the collector produces, the loop thread (recorder) consumes.
    empty: rtrb::Producer<Box<Interval>>,
}

/// A loop thread's histograms. `record` and `end_interval` never allocate, lock, spin or block.
pub struct Recorder {
    /// Always `Some` until dropped.
    current: Option<Box<Interval>>,
    /// Producer end of the filled-set ring (the collector consumes).
    full: rtrb::Producer<Box<Interval>>,
    /// Consumer end of the emptied-set ring (the collector produces).
    empty: rtrb::Consumer<Box<Interval>>,
    info: Arc<PoolInfo>,
}

impl Recorder {
    /// Records one sample (ns for time channels); values beyond the channel's bounds are clamped.
    #[inline]
    pub fn record(&mut self, channel: Channel, value: u64) {
        let Some(cur) = self.current.as_mut() else { return };
        match cur.hists[channel.index()].as_mut() {
            Some(h) => h.saturating_record(value),
            None => cur.stray += 1,
        }
    }

    /// Ends the current interval at `now_ns` (on [`monotonic_ns`]): hands the filled set to the collector and
    /// continues in an empty one. Returns false if none was free; recording then continues in the same set.
    pub fn end_interval(&mut self, now_ns: u64) -> bool {
        self.hand_over(now_ns, None)
    }

    /// [`Self::end_interval`], with the loop's counters at this moment (a copy into the set; no allocation).
    pub fn end_interval_with(&mut self, now_ns: u64, counters: LoopCounters) -> bool {
        self.hand_over(now_ns, Some(counters))
    }

    fn hand_over(&mut self, now_ns: u64, counters: Option<LoopCounters>) -> bool {
        if let Some(cur) = self.current.as_mut() {
            // Also when no fresh set is free: the set then goes on, and carries the newer counters.
            cur.counters = counters.or(cur.counters);
        }
        let Ok(mut fresh) = self.empty.pop() else {
            self.info.starved.fetch_add(1, Ordering::Relaxed);
            return false;
        };
        fresh.start_ns = now_ns;
        fresh.counters = None;
        if let Some(mut filled) = self.current.replace(fresh) {
            filled.end_ns = now_ns;
            let handed = self.full.push(filled);
            debug_assert!(handed.is_ok(), "the full queue holds every set, so it cannot be full");
        }
        true
    }

    /// Intervals extended so far because the collector had not returned a set.
    pub fn starved(&self) -> u64 {
        self.info.starved.load(Ordering::Relaxed)
    }
}

impl Drop for Recorder {
    /// Hands the last, partial interval over, so samples recorded after the last `end_interval` are kept.
    fn drop(&mut self) {
        if let Some(mut last) = self.current.take() {
            last.end_ns = monotonic_ns();
            let _ = self.full.push(last);
        }
    }
}

struct Registry {
    pools: Vec<Pool>,
    /// Channels some recorder owns: these appear in the summary, with a count of 0 if nothing was recorded.
    channels: [bool; Channel::COUNT],
}

struct Shared {
    registry: Mutex<Registry>,
    stop: AtomicBool,
}

/// The non-real-time thread that merges, logs and recycles the recorders' interval sets.
pub struct Collector {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<Totals>>,
    log_path: PathBuf,
}

impl Collector {
    /// Creates `dir` and its [`LOG_FILE`], and starts the thread, which looks for filled sets every `poll`.
    pub fn start(dir: &Path, poll: Duration) -> anyhow::Result<Collector> {
        Self::start_with(dir, poll, None)
    }

    /// [`Self::start`], and `live` sees every interval as it arrives, with the loops' starved count so far.
    pub fn start_with(dir: &Path, poll: Duration, live: Option<LiveHook>) -> anyhow::Result<Collector> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let log_path = dir.join(LOG_FILE);
        let file = File::create(&log_path).with_context(|| format!("creating {}", log_path.display()))?;
        let shared = Arc::new(Shared {
            registry: Mutex::new(Registry { pools: Vec::new(), channels: [false; Channel::COUNT] }),
            stop: AtomicBool::new(false),
        });
        let worker = shared.clone();
        let path = log_path.clone();
        let thread = std::thread::Builder::new()
            .name("marsd-latency".into())
            .spawn(move || collect(&worker, file, path, poll, live))
            .context("spawning the latency collector thread")?;
        Ok(Collector { shared, thread: Some(thread), log_path })
    }

    /// A recorder for `channels` with `sets` preallocated interval sets (at least 2: one being filled, one
    /// coming back). More sets ride out a slower collector. Call at setup, not in a loop: this allocates.
    pub fn recorder(&self, name: &str, channels: &[Channel], sets: usize) -> Recorder {
        let sets = sets.max(2);
        let info = Arc::new(PoolInfo { name: name.to_string(), starved: AtomicU64::new(0) });
        let (full_in, full_out) = rtrb::RingBuffer::new(sets);
        let (mut empty_in, empty_out) = rtrb::RingBuffer::new(sets);
        for _ in 1..sets {
            let _ = empty_in.push(Interval::new(channels));
        }
        let mut first = Interval::new(channels);
        first.start_ns = monotonic_ns();
        let mut reg = self.shared.registry.lock().expect("latency registry poisoned");
        for c in channels {
            reg.channels[c.index()] = true;
        }
        reg.pools.push(Pool { info: info.clone(), full: full_out, empty: empty_in });
        Recorder { current: Some(first), full: full_in, empty: empty_out, info }
    }

    pub fn log_path(&self) -> &Path {
        &self.log_path
    }

    /// Stops the thread after it has taken in every handed-over set, and returns the run's totals. Drop (or
    /// join the threads owning) the recorders first: a live recorder's current interval is not included.
    pub fn finish(mut self) -> Totals {
        self.shared.stop.store(true, Ordering::Release);
        let thread = self.thread.take().expect("finish runs once");
        thread.thread().unpark();
        match thread.join() {
            Ok(totals) => totals,
            Err(panic) => std::panic::resume_unwind(panic),
        }
    }
}

impl Drop for Collector {
    fn drop(&mut self) {
        if let Some(t) = self.thread.take() {
            self.shared.stop.store(true, Ordering::Release);
            t.thread().unpark();
            let _ = t.join();
        }
    }
}

/// The collector thread: poll, merge, log, recycle; a last pass after `stop`.
fn collect(shared: &Shared, file: File, path: PathBuf, poll: Duration, live: Option<LiveHook>) -> Totals {
    let mut live = live.map(|make| make());
    // Interval timestamps are seconds since the collector started (BaseTime), as the HdrHistogram tools expect.
    let (base_wall, base_ns) = (SystemTime::now(), monotonic_ns());
    let mut serializer = V2DeflateSerializer::new();
    // Unbuffered: each line reaches the file as it is written, so a crashed run still leaves a readable log.
    let mut out = &file;
    let mut log: Option<IntervalLogWriter<_, _>> = None;
    let mut log_error = None;
    match IntervalLogWriterBuilder::new()
        .add_comment("marsd latency: time channels in ns, k_requested/k_used in ODE steps")
        .with_start_time(base_wall)
        .with_base_time(base_wall)
        .begin_log_with(&mut out, &mut serializer)
    {
        Ok(w) => log = Some(w),
        Err(e) => log_error = Some(format!("writing {}: {e}", path.display())),
    }
    let mut totals = Totals::empty(path);
    loop {
        let stopping = shared.stop.load(Ordering::Acquire);
        // The registry's lock is only taken here and in `Collector::recorder` (setup): never by a loop thread.
        let mut reg = shared.registry.lock().expect("latency registry poisoned");
        let starved: u64 = reg.pools.iter().map(|p| p.info.starved.load(Ordering::Relaxed)).sum();
        for pool in &mut reg.pools {
            while let Ok(mut set) = pool.full.pop() {
                if let Some(hook) = live.as_mut() {
                    hook(&IntervalView { set: &set }, starved);
                }
                if let Some(w) = log.as_mut()
                    && let Err(e) = write_interval(w, &set, base_ns)
                {
                    warn!("latency log {}: {e}; no further intervals are logged", totals.log.display());
                    log_error = Some(e);
                    log = None;
                }
                totals.absorb(&mut set);
                let _ = pool.empty.push(set);
            }
        }
        if stopping {
            for pool in &reg.pools {
                totals.starved += pool.info.starved.load(Ordering::Relaxed);
                // The recorder's producer end lives as long as the recorder.
                if !pool.full.is_abandoned() {
                    warn!(
                        recorder = pool.info.name,
                        "latency recorder still alive at finish: its last interval is lost"
                    );
                }
            }
            totals.registered = reg.channels;
            break;
        }
        drop(reg);
        std::thread::park_timeout(poll);
    }
    totals.log_error = log_error;
    totals.summarize();
    totals
}

fn write_interval(
    w: &mut IntervalLogWriter<&File, V2DeflateSerializer>,
    set: &Interval,
    base_ns: u64,
) -> Result<(), String> {
    let start = Duration::from_nanos(set.start_ns.saturating_sub(base_ns));
    let length = Duration::from_nanos(set.end_ns.saturating_sub(set.start_ns));
    for c in Channel::ALL {
        if let Some(h) = set.hists[c.index()].as_ref().filter(|h| !h.is_empty()) {
            w.write_histogram(h, start, length, Tag::new(c.tag())).map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}

/// A channel's percentiles: µs for time channels, K for the K channels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChannelStats {
    pub channel: Channel,
    pub unit: String,
    pub count: u64,
    pub mean: f64,
    pub p50: f64,
    pub p90: f64,
    pub p99: f64,
    #[serde(rename = "p99.9")]
    pub p99_9: f64,
    #[serde(rename = "p99.99")]
    pub p99_99: f64,
    pub max: f64,
}

impl ChannelStats {
    pub fn of(channel: Channel, h: &Histogram<u64>) -> ChannelStats {
        let scale = channel.scale();
        let q = |p: f64| h.value_at_quantile(p) as f64 * scale;
        ChannelStats {
            channel,
            unit: channel.unit().to_string(),
            count: h.len(),
            mean: h.mean() * scale,
            p50: q(0.5),
            p90: q(0.9),
            p99: q(0.99),
            p99_9: q(0.999),
            p99_99: q(0.9999),
            max: h.max() as f64 * scale,
        }
    }
}

/// A run's merged histograms and their percentile table (`Display`; `Serialize` for a summary file).
#[derive(Debug, Clone, Serialize)]
pub struct Totals {
    pub channels: Vec<ChannelStats>,
    /// Interval sets merged.
    pub intervals: u64,
    /// Interval ends that found no free set, so that interval was extended (no samples lost).
    pub starved: u64,
    /// Samples recorded for channels their recorder does not own (dropped; a bug if not 0).
    pub stray: u64,
    pub log: PathBuf,
    pub log_error: Option<String>,
    #[serde(skip)]
    hists: [Option<Histogram<u64>>; Channel::COUNT],
    #[serde(skip)]
    registered: [bool; Channel::COUNT],
}

impl Totals {
    fn empty(log: PathBuf) -> Totals {
        Totals {
            channels: Vec::new(),
            intervals: 0,
            starved: 0,
            stray: 0,
            log,
            log_error: None,
            hists: Default::default(),
            registered: [false; Channel::COUNT],
        }
    }

    /// Totals of histograms gathered elsewhere (another run's log, a test); same-channel ones are merged.
    pub fn from_histograms(hists: impl IntoIterator<Item = (Channel, Histogram<u64>)>) -> Totals {
        let mut t = Totals::empty(PathBuf::new());
        for (c, h) in hists {
            t.merge(c, &h);
            t.registered[c.index()] = true;
        }
        t.summarize();
        t
    }

    /// The merged histogram of a channel that got samples.
    pub fn histogram(&self, channel: Channel) -> Option<&Histogram<u64>> {
        self.hists[channel.index()].as_ref()
    }

    pub fn stats(&self, channel: Channel) -> Option<&ChannelStats> {
        self.channels.iter().find(|s| s.channel == channel)
    }

    fn merge(&mut self, c: Channel, h: &Histogram<u64>) {
        let total = self.hists[c.index()].get_or_insert_with(|| c.new_histogram());
        // Clamped on the way in: anything recorded fits the same bounds; a foreign histogram is clamped too.
        if total.add(h).is_err() {
            for v in h.iter_recorded() {
                total.saturating_record_n(v.value_iterated_to(), v.count_at_value());
            }
        }
    }

    fn absorb(&mut self, set: &mut Interval) {
        for c in Channel::ALL {
            if let Some(h) = set.hists[c.index()].as_mut().filter(|h| !h.is_empty()) {
                self.merge(c, h);
                h.reset();
            }
        }
        self.stray += std::mem::take(&mut set.stray);
        self.intervals += 1;
    }

    fn summarize(&mut self) {
        self.channels = Channel::ALL
            .into_iter()
            .filter(|c| self.registered[c.index()] || self.hists[c.index()].is_some())
            .map(|c| match &self.hists[c.index()] {
                Some(h) => ChannelStats::of(c, h),
                None => ChannelStats::of(c, &c.new_histogram()),
            })
            .collect();
    }
}

impl fmt::Display for Totals {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{:<17} {:>4} {:>10} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}",
            "channel", "unit", "count", "p50", "p90", "p99", "p99.9", "p99.99", "max"
        )?;
        for s in &self.channels {
            let v = |x: f64| if s.channel == Channel::WInf { format!("{x:.3}") } else { num(x, s.channel.is_time()) };
            writeln!(
                f,
                "{:<17} {:>4} {:>10} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}",
                s.channel.tag(),
                if s.channel.is_time() { "µs" } else { s.channel.unit() },
                s.count,
                v(s.p50),
                v(s.p90),
                v(s.p99),
                v(s.p99_9),
                v(s.p99_99),
                v(s.max)
            )?;
        }
        write!(f, "{} intervals", self.intervals)?;
        if self.starved > 0 {
            write!(f, ", {} extended for want of a free set (no samples lost)", self.starved)?;
        }
        if self.stray > 0 {
            write!(f, ", {} samples for channels their recorder does not own (dropped)", self.stray)?;
        }
        if let Some(e) = &self.log_error {
            write!(f, "; interval log incomplete: {e}")?;
        }
        Ok(())
    }
}

/// Three significant digits or so, without a wall of decimals.
fn num(x: f64, time: bool) -> String {
    if !time || x >= 1000.0 {
        format!("{x:.0}")
    } else if x >= 10.0 {
        format!("{x:.1}")
    } else {
        format!("{x:.2}")
    }
}
