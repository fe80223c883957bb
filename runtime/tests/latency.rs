//! Latency recording: allocation-free on the loop thread, logged in a re-readable interval log, summarised
//! correctly, and never blocked by a slow collector.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use hdrhistogram::Histogram;
use hdrhistogram::serialization::Deserializer;
use hdrhistogram::serialization::interval_log::{IntervalLogIterator, LogEntry};
use mars_runtime::report::latency::{Channel, Collector, LOG_FILE, LoopCounters};
use mars_runtime::rt::monotonic_ns;

/// Counts allocator calls made by threads that opted in, so the collector thread's own work is not counted.
struct Counting;

thread_local! {
    static WATCHED: Cell<bool> = const { Cell::new(false) };
}
static CALLS: AtomicUsize = AtomicUsize::new(0);

fn note() {
    if WATCHED.try_with(Cell::get).unwrap_or(false) {
        CALLS.fetch_add(1, Ordering::Relaxed);
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note();
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note();
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        note();
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Allocator calls made by the calling thread while running `f`.
fn allocations_in(f: impl FnOnce()) -> usize {
    // Only this thread is watched, so the global counter measures it alone even with other tests running
    // (each watching test runs its closure on its own thread and reads the difference).
    let before = CALLS.load(Ordering::SeqCst);
    WATCHED.with(|w| w.set(true));
    f();
    WATCHED.with(|w| w.set(false));
    CALLS.load(Ordering::SeqCst) - before
}

fn out_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("marsd-latency-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// Counters as the servo loop hands them over, numbered by `i`.
fn counters(i: u64) -> LoopCounters {
    let mut c = LoopCounters::default();
    c.servo.commands_sent = i;
    c.hal.clamped = 2 * i;
    c
}

#[test]
fn the_live_hook_sees_every_interval_with_the_counters_handed_over() {
    let dir = out_dir("live");
    let (tx, rx) = std::sync::mpsc::channel();
    let hook: mars_runtime::report::latency::LiveHook = Box::new(move || {
        Box::new(move |view: &mars_runtime::report::latency::IntervalView<'_>, _starved: u64| {
            let wake = view.histogram(Channel::WakeJitter).map(|h| h.len());
            let _ = tx.send((view.counters().copied(), wake, view.histogram(Channel::Inference).is_some()));
        })
    });
    let collector = Collector::start_with(&dir, Duration::from_millis(1), Some(hook)).unwrap();
    let mut rec = collector.recorder("servo", &[Channel::WakeJitter], 4);
    for i in 1..=3u64 {
        for v in 0..10 * i {
            rec.record(Channel::WakeJitter, 1000 + v);
        }
        assert!(rec.end_interval_with(monotonic_ns(), counters(i)));
        std::thread::sleep(Duration::from_millis(20)); // the collector returns the set
    }
    rec.end_interval(monotonic_ns());
    drop(rec);
    collector.finish();
    let seen: Vec<_> = rx.try_iter().collect();
    // Three intervals with their counters and samples, the one without counters, and the empty last one.
    assert_eq!(seen.len(), 5, "{seen:?}");
    for (i, (c, wake, inference)) in seen.iter().take(3).enumerate() {
        assert_eq!(*c, Some(counters(i as u64 + 1)));
        assert_eq!(*wake, Some(10 * (i as u64 + 1)));
        assert!(!inference, "a channel this loop does not record has no histogram");
    }
    assert_eq!(seen[3].0, None);
}

#[test]
fn record_and_end_interval_never_allocate() {
    // The counter works: an allocation on a watched thread is seen.
    assert!(allocations_in(|| drop(std::hint::black_box(Vec::<u8>::with_capacity(8)))) > 0);
    let dir = out_dir("alloc");
    // A prompt collector (sets come back) and a stalled one (the pool runs dry): both paths are checked.
    for poll in [Duration::from_millis(1), Duration::from_secs(3600)] {
        let collector = Collector::start(&dir, poll).unwrap();
        let mut rec = collector.recorder("servo", &Channel::ALL, 3);
        let n = std::thread::scope(|s| {
            s.spawn(|| {
                allocations_in(|| {
                    for i in 0..40u64 {
                        for v in 0..500u64 {
                            for c in Channel::ALL {
                                rec.record(c, v * 997 + i);
                            }
                        }
                        rec.record(Channel::WakeJitter, u64::MAX); // clamped, still no allocation
                        if i % 2 == 0 {
                            rec.end_interval(monotonic_ns());
                        } else {
                            rec.end_interval_with(monotonic_ns(), counters(i));
                        }
                        std::thread::sleep(Duration::from_micros(200));
                    }
                })
            })
            .join()
            .unwrap()
        });
        let starved = rec.starved();
        drop(rec);
        let totals = collector.finish();
        assert_eq!(n, 0, "the recording thread allocated {n} times (poll {poll:?})");
        assert_eq!(totals.stats(Channel::TickCompute).unwrap().count, 40 * 500);
        assert_eq!(totals.stats(Channel::WakeJitter).unwrap().count, 40 * 501);
        assert_eq!(totals.starved, starved);
        if poll > Duration::from_secs(1) {
            assert!(starved > 0, "the stalled collector should have run the pool dry");
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Standard base64 (the interval log's encoding), enough for the test.
fn base64_decode(s: &str) -> Vec<u8> {
    use base64::Engine;
    base64::engine::general_purpose::STANDARD.decode(s).expect("an interval's histogram is base64")
}

#[test]
fn the_interval_log_reads_back_with_the_recorded_counts() {
    let dir = out_dir("log");
    let collector = Collector::start(&dir, Duration::from_millis(2)).unwrap();
    let mut rec = collector.recorder("policy", &[Channel::Inference, Channel::KUsed], 8);
    let mut expected: BTreeMap<&str, u64> = BTreeMap::new();
    for i in 1..=5u64 {
        for _ in 0..100 * i {
            rec.record(Channel::Inference, 1_000_000 * i);
            rec.record(Channel::KUsed, i);
        }
        *expected.entry("inference").or_default() += 100 * i;
        *expected.entry("k_used").or_default() += 100 * i;
        std::thread::sleep(Duration::from_millis(5));
        assert!(rec.end_interval(monotonic_ns()), "8 sets: enough for 5 intervals even with no collector");
    }
    drop(rec);
    let totals = collector.finish();

    let bytes = std::fs::read(dir.join(LOG_FILE)).unwrap();
    let mut deserializer = Deserializer::new();
    let (mut counts, mut merged): (BTreeMap<String, u64>, BTreeMap<String, Histogram<u64>>) = Default::default();
    let (mut base_time, mut last_start, mut intervals) = (false, Duration::ZERO, 0);
    for entry in IntervalLogIterator::new(&bytes) {
        match entry.expect("parsable log") {
            LogEntry::BaseTime(_) => base_time = true,
            LogEntry::StartTime(_) => {}
            LogEntry::Interval(h) => {
                let tag = h.tag().expect("every interval is tagged").as_str().to_string();
                assert!(Channel::from_tag(&tag).is_some(), "unknown tag {tag}");
                assert!(h.start_timestamp() >= last_start, "intervals out of order");
                last_start = h.start_timestamp();
                let hist: Histogram<u64> =
                    deserializer.deserialize(&mut &base64_decode(h.encoded_histogram())[..]).expect("V2 histogram");
                *counts.entry(tag.clone()).or_default() += hist.len();
                merged.entry(tag).or_insert_with(|| Histogram::new(3).unwrap()).add(&hist).unwrap();
                intervals += 1;
            }
        }
    }
    assert!(base_time, "the log states its BaseTime");
    // Five intervals with two non-empty channels each (the last, partial set is empty and logs nothing).
    assert_eq!(intervals, 10);
    let expected: BTreeMap<String, u64> = expected.into_iter().map(|(k, v)| (k.to_string(), v)).collect();
    assert_eq!(counts, expected);
    assert_eq!(totals.stats(Channel::Inference).unwrap().count, 1500);
    assert_eq!(merged["k_used"].max(), 5);
    assert_eq!(merged["inference"].value_at_quantile(1.0), totals.histogram(Channel::Inference).unwrap().max());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_percentile_table_is_right_for_a_known_distribution() {
    let dir = out_dir("table");
    let collector = Collector::start(&dir, Duration::from_millis(5)).unwrap();
    let mut rec = collector.recorder("servo", &[Channel::StateAge, Channel::KRequested], 2);
    // Uniform 1..=100 000 ns: percentile p is p·1000 ns = p µs.
    for v in 1..=100_000 {
        rec.record(Channel::StateAge, v);
    }
    for (k, n) in [(2, 300), (4, 600), (8, 100)] {
        (0..n).for_each(|_| rec.record(Channel::KRequested, k));
    }
    rec.record(Channel::Inference, 5); // not owned by this recorder
    drop(rec);
    let totals = collector.finish();

    let age = totals.stats(Channel::StateAge).unwrap();
    assert_eq!(age.count, 100_000);
    assert_eq!(age.unit, "us");
    // 3 significant digits: within 0.1 % (plus the bucket's upper edge).
    for (got, want) in [(age.p50, 50.0), (age.p90, 90.0), (age.p99, 99.0), (age.p99_9, 99.9), (age.max, 100.0)] {
        assert!((got - want).abs() / want < 2e-3, "{got} µs, want {want} µs");
    }
    assert!((age.mean - 50.0).abs() < 0.1, "mean {}", age.mean);
    let k = totals.stats(Channel::KRequested).unwrap();
    assert_eq!((k.count, k.p50, k.p90, k.p99, k.max), (1000, 4.0, 4.0, 8.0, 8.0));
    assert!((k.mean - 3.8).abs() < 1e-9);
    assert_eq!(totals.stray, 1);

    let table = totals.to_string();
    for needle in ["p99.9", "state_age", "k_requested", "100000", "50.0"] {
        assert!(table.contains(needle), "{needle} missing from\n{table}");
    }
    let json = serde_json::to_value(&totals).unwrap();
    let first = &json["channels"][0];
    assert_eq!(first["channel"], "state_age");
    assert!((first["p99.9"].as_f64().unwrap() - 99.9).abs() < 0.2);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_slow_collector_loses_no_samples_and_never_blocks() {
    let dir = out_dir("slow");
    // The collector thread takes one look at start and then sleeps for an hour (until `finish`).
    let collector = Collector::start(&dir, Duration::from_secs(3600)).unwrap();
    let mut rec = collector.recorder("servo", &[Channel::TickCompute], 2);
    let (mut slowest, t0) = (Duration::ZERO, Instant::now());
    for i in 0..20u64 {
        for v in 0..500 {
            rec.record(Channel::TickCompute, 1000 + v + i);
        }
        let t = Instant::now();
        rec.end_interval(monotonic_ns());
        slowest = slowest.max(t.elapsed());
    }
    assert!(t0.elapsed() < Duration::from_secs(2), "recording took {:?}", t0.elapsed());
    assert!(slowest < Duration::from_millis(50), "an end_interval took {slowest:?}");
    // Two sets: at most two hand-offs can succeed before the collector returns any.
    assert!(rec.starved() >= 17, "starved {}", rec.starved());
    let starved = rec.starved();
    drop(rec);
    let totals = collector.finish();
    assert_eq!(totals.stats(Channel::TickCompute).unwrap().count, 20 * 500);
    assert_eq!(totals.starved, starved);
    assert!(totals.to_string().contains("no samples lost"), "{totals}");
    std::fs::remove_dir_all(&dir).ok();
}
