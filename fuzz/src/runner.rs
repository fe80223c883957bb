//! Runs one target's cases: each input made from the case's own generator (so any case can be made again from
//! `--seed` and its number), decoded under `catch_unwind`. A panic is a failure named by where it happened, its
//! first input saved; a case that asks for more memory than [`guard::ALLOCATION_CAP`] is a failure too; a case
//! that runs past the time limit stops the run, its input saved (a hang cannot be interrupted in-process).

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use rand::SeedableRng;
use rand::rngs::StdRng;

use crate::guard;

/// A decoder under test.
pub trait Target: Send + Sync {
    fn name(&self) -> &'static str;
    /// A new input: a mutation of one of the target's seeds, from the case's generator.
    fn generate(&self, rng: &mut StdRng) -> Vec<u8>;
    /// Decodes `input` as the product does, and uses what it accepted as the product would; true when the decoder
    /// accepted it. An error is the expected answer to a bad input; a panic (or an abort, or a hang) is a failure.
    fn run(&self, input: &[u8]) -> bool;
    /// The seeds as inputs, unmutated: each must be accepted (so that the mutants start from inputs that reach
    /// every check, not from ones refused at the first byte).
    fn seeds(&self) -> Vec<Vec<u8>>;
}

#[derive(Debug, Clone)]
pub struct Options {
    /// The first case's number: a run stopped at case N goes on with `first_case = N` and makes the same inputs
    /// the unstopped run would have made.
    pub first_case: u64,
    pub cases: u64,
    pub seed: u64,
    /// Where failing inputs are written.
    pub out: PathBuf,
    /// A case running longer than this stops the run as a hang.
    pub case_timeout: Duration,
    /// Print progress every this long (None: silent until the end).
    pub progress: Option<Duration>,
    /// Stop a target after this long, whatever `cases` says (the report gives the cases run).
    pub time_limit: Option<Duration>,
}

/// One distinct failure: where, what, how often, and the first input that caused it.
#[derive(Debug, Clone)]
pub struct Failure {
    pub what: String,
    pub first_case: u64,
    pub count: u64,
    pub input: PathBuf,
}

#[derive(Debug, Clone)]
pub struct Report {
    pub target: &'static str,
    /// The run's first case; it ran `first_case..first_case + cases`.
    pub first_case: u64,
    pub cases: u64,
    pub failures: Vec<Failure>,
    pub elapsed: Duration,
    /// The slowest case: its number and time.
    pub slowest: (u64, Duration),
    /// Cases whose input the decoder accepted (and that were then used).
    pub accepted: u64,
    /// Panics of the parquet reader that mars-lerobot contained (made the file's error; see its `contain`).
    pub contained: u64,
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = self.elapsed.as_secs_f64();
        write!(
            f,
            "{:<18} {:>11} cases  {:>3} distinct failures  {:>9.1} s  ({:.0} cases/s; {:.1} % accepted; slowest: case \
             {}, {:.1} ms)",
            self.target,
            self.cases,
            self.failures.len(),
            s,
            self.cases as f64 / s.max(1e-9),
            100.0 * self.accepted as f64 / self.cases.max(1) as f64,
            self.slowest.0,
            self.slowest.1.as_secs_f64() * 1e3
        )?;
        if self.first_case > 0 {
            write!(f, "  [cases {}..{}]", self.first_case, self.first_case + self.cases)?;
        }
        if self.contained > 0 {
            write!(f, "  [{} parquet-reader panics contained as errors]", self.contained)?;
        }
        for x in &self.failures {
            write!(
                f,
                "\n  FAILURE ×{} (first: case {}): {}\n    input: {}",
                x.count,
                x.first_case,
                x.what,
                x.input.display()
            )?;
        }
        Ok(())
    }
}

/// The generator of case `case` of `target` under `seed`: independent of every other case.
pub fn case_rng(seed: u64, target: &str, case: u64) -> StdRng {
    let name = target.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3));
    let mut z = seed ^ name.rotate_left(17) ^ case.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    StdRng::seed_from_u64(z ^ (z >> 31))
}

thread_local! {
    static IN_CASE: RefCell<bool> = const { RefCell::new(false) };
    static LAST_PANIC: RefCell<Option<(String, String)>> = const { RefCell::new(None) };
}

/// A panic hook that, inside a case, records where and why (quietly) and otherwise does what the previous one did.
fn install_panic_hook() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if IN_CASE.with(|c| *c.borrow()) {
                let at = info.location().map_or("?".into(), |l| format!("{}:{}:{}", l.file(), l.line(), l.column()));
                let msg = info
                    .payload()
                    .downcast_ref::<&str>()
                    .map(|s| (*s).to_owned())
                    .or_else(|| info.payload().downcast_ref::<String>().cloned())
                    .unwrap_or_default();
                LAST_PANIC.with(|p| *p.borrow_mut() = Some((at, msg)));
            } else {
                previous(info);
            }
        }));
    });
}

/// Runs `opts.cases` cases of `target` on a thread with the main thread's 8 MiB stack (what the product's
/// parsers run on), and reports.
pub fn run(target: Arc<dyn Target>, opts: &Options) -> Report {
    std::fs::create_dir_all(&opts.out).unwrap_or_else(|e| panic!("cannot make {}: {e}", opts.out.display()));
    let opts = opts.clone();
    std::thread::Builder::new()
        .name(format!("fuzz-{}", target.name()))
        .stack_size(8 << 20)
        .spawn(move || run_here(&*target, &opts))
        .expect("spawning the fuzz thread")
        .join()
        .expect("the fuzz thread itself panicked")
}

fn run_here(target: &dyn Target, opts: &Options) -> Report {
    install_panic_hook();
    let name = target.name();
    guard::set_crash_path(&opts.out.join(format!("{name}-abort.bin")));
    let watch = Watchdog::start(name, &opts.out, opts.case_timeout);
    let mut failures: BTreeMap<String, Failure> = BTreeMap::new();
    let (started, mut last_print) = (Instant::now(), Instant::now());
    let (contained_before, mut slowest, mut accepted) =
        (mars_lerobot::contain::contained_panics(), (0, Duration::ZERO), 0);
    let mut cases = 0;
    for case in opts.first_case..opts.first_case.saturating_add(opts.cases) {
        if opts.time_limit.is_some_and(|limit| started.elapsed() >= limit) {
            break;
        }
        cases += 1;
        let input = target.generate(&mut case_rng(opts.seed, name, case));
        watch.begin(case);
        let (outcome, took) = one_case(target, &input);
        watch.end();
        if took > slowest.1 {
            slowest = (case, took);
        }
        match outcome {
            Ok(yes) => accepted += u64::from(yes),
            Err(what) => record(&mut failures, what, case, &input, name, &opts.out),
        }
        if let Some(every) = opts.progress
            && last_print.elapsed() >= every
        {
            last_print = Instant::now();
            let s = started.elapsed().as_secs_f64();
            eprintln!(
                "{name}: {cases} cases in {s:.0} s ({:.0}/s), next case {}, {} distinct failures",
                cases as f64 / s,
                case + 1,
                failures.len()
            );
        }
    }
    watch.stop();
    Report {
        target: name,
        first_case: opts.first_case,
        cases,
        failures: failures.into_values().collect(),
        elapsed: started.elapsed(),
        slowest,
        accepted,
        contained: mars_lerobot::contain::contained_panics() - contained_before,
    }
}

/// Runs one input: whether it was accepted, or the failure it caused (a panic, an allocation above the cap).
fn one_case(target: &dyn Target, input: &[u8]) -> (Result<bool, String>, Duration) {
    guard::arm(input);
    LAST_PANIC.with(|p| p.borrow_mut().take());
    IN_CASE.with(|c| *c.borrow_mut() = true);
    let started = Instant::now();
    let outcome = catch_unwind(AssertUnwindSafe(|| target.run(input)));
    let took = started.elapsed();
    IN_CASE.with(|c| *c.borrow_mut() = false);
    guard::disarm();
    let outcome = match (outcome, guard::take_refused()) {
        (Err(_), _) => Err(LAST_PANIC
            .with(|p| p.borrow_mut().take())
            .map_or("a panic".into(), |(at, msg)| format!("panic at {at}: {msg}"))),
        (Ok(_), Some(n)) => Err(format!("asked for {n} bytes at once (above the {} cap)", guard::ALLOCATION_CAP)),
        (Ok(accepted), None) => Ok(accepted),
    };
    (outcome, took)
}

/// One input through `target` as a case of a run decodes it (a saved failure, made again): accepted or not, or
/// the failure.
pub fn check(target: &dyn Target, input: &[u8]) -> Result<bool, String> {
    install_panic_hook();
    one_case(target, input).0
}

fn record(failures: &mut BTreeMap<String, Failure>, what: String, case: u64, input: &[u8], name: &str, out: &Path) {
    // Distinct by where (a panic's message may carry the input's numbers; its location does not).
    let key = what.split(": ").next().unwrap_or(&what).to_owned();
    if let Some(f) = failures.get_mut(&key) {
        f.count += 1;
        return;
    }
    let hash = key.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3));
    let file = out.join(format!("{name}-{hash:016x}.bin"));
    if let Err(e) = std::fs::write(&file, input) {
        eprintln!("mars-fuzz: cannot save {}: {e}", file.display());
    }
    eprintln!("mars-fuzz: {name} case {case}: {what}\n  input saved to {}", file.display());
    failures.insert(key, Failure { what, first_case: case, count: 1, input: file });
}

/// Stops the process when a case runs past its time limit, after saving its input: a hang is a failure, and the
/// thread that hangs cannot be stopped from outside.
struct Watchdog {
    started_ms: Arc<AtomicU64>,
    case: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    epoch: Instant,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Watchdog {
    fn start(name: &str, out: &Path, limit: Duration) -> Self {
        let (started_ms, case, stop) =
            (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)), Arc::new(AtomicBool::new(false)));
        let epoch = Instant::now();
        let (s, c, st, name, out) = (started_ms.clone(), case.clone(), stop.clone(), name.to_owned(), out.to_owned());
        let thread = std::thread::spawn(move || {
            while !st.load(Ordering::Acquire) {
                std::thread::sleep(Duration::from_millis(50));
                let at = s.load(Ordering::Acquire);
                if at != 0 && epoch.elapsed().as_millis() as u64 > at + limit.as_millis() as u64 {
                    let file = out.join(format!("{name}-hang.bin"));
                    guard::copy_input_to(&file);
                    eprintln!(
                        "mars-fuzz: {name} case {} ran longer than {limit:?}: a hang; input saved to {}",
                        c.load(Ordering::Acquire),
                        file.display()
                    );
                    std::process::exit(3);
                }
            }
        });
        Self { started_ms, case, stop, epoch, thread: Some(thread) }
    }

    fn begin(&self, case: u64) {
        self.case.store(case, Ordering::Release);
        self.started_ms.store(self.epoch.elapsed().as_millis() as u64 + 1, Ordering::Release);
    }

    fn end(&self) {
        self.started_ms.store(0, Ordering::Release);
    }

    fn stop(mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
