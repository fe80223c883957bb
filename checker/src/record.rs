//! `mars-checker record`: a process of its own that subscribes to a robot's state frames (iceoryx2, as any
//! controller does) and writes each to a file, off the HAL's loop: the HAL publishes as always and never waits on
//! it. One thread reads (optionally at a low SCHED_FIFO priority, so a busy machine does not make it miss frames:
//! iceoryx2 keeps 16 per subscriber), another formats and writes.

use std::io::Write as _;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::Context;
use mars_ipc::node::create_node;
use mars_ipc::{RobotNamespace, RobotState, StateReader};

use crate::stream::{Frame, HEADER};

#[derive(clap::Args, Debug)]
pub struct RecordArgs {
    /// The robot's iceoryx2 namespace (the HAL's --robot).
    #[arg(long)]
    pub robot: String,
    /// The file to write (CSV, see `stream.rs`); it must not exist.
    #[arg(long)]
    pub out: PathBuf,
    /// Stop after this many seconds (default: at SIGTERM or SIGINT).
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// Read at this SCHED_FIFO priority (1–99; below the HAL's and the controller's loops) when the process may.
    #[arg(long, value_parser = clap::value_parser!(i32).range(1..=99))]
    pub rt_priority: Option<i32>,
}

/// How often the reader looks for frames: a fifth of the FR3's period, far inside iceoryx2's 16-frame buffer.
const POLL: Duration = Duration::from_micros(200);
/// How often read frames go to the writer.
const BATCH: Duration = Duration::from_millis(20);

pub fn run(args: &RecordArgs) -> anyhow::Result<()> {
    if let Some(d) = args.duration_s {
        anyhow::ensure!(d.is_finite() && d > 0.0, "--duration-s must be a positive number of seconds, got {d}");
    }
    let file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(signal, stop.clone()).context("registering the stop signals")?;
    }
    let ns = RobotNamespace::new(&args.robot)?;
    let (node, _) = create_node(&format!("checker-{}", std::process::id()))?;
    let reader = StateReader::new(&node, &ns)?;
    if let Some(p) = args.rt_priority {
        set_fifo(p);
    }
    let (tx, rx) = mpsc::channel::<Vec<Frame>>();
    let writer = std::thread::spawn(move || write_all(file, rx));
    // The caller waits for this line before it starts what it wants recorded.
    println!("ready");
    std::io::stdout().flush()?;
    let read = read_until_stopped(&reader, &stop, args.duration_s.map(Duration::from_secs_f64), &tx);
    drop(tx);
    let written = writer.join().map_err(|_| anyhow::anyhow!("the writer thread panicked"))??;
    let (frames, errors) = read;
    eprintln!(
        "mars-checker: {frames} frames read, {written} written to {}, {errors} receive errors",
        args.out.display()
    );
    Ok(())
}

/// Reads frames until stopped; returns (frames read, receive errors).
fn read_until_stopped(
    reader: &StateReader,
    stop: &AtomicBool,
    duration: Option<Duration>,
    tx: &mpsc::Sender<Vec<Frame>>,
) -> (u64, u64) {
    let start = Instant::now();
    let (mut frames, mut errors) = (0, 0);
    let mut batch = Vec::with_capacity(64);
    let mut sent = Instant::now();
    loop {
        // Drained once more after the stop, so the frames up to it are kept.
        let stopping = stop.load(Ordering::Acquire) || duration.is_some_and(|d| start.elapsed() >= d);
        loop {
            match reader.receive() {
                Ok(Some(s)) => batch.push(frame_of(&s, mars_ipc::clock::monotonic_ns())),
                Ok(None) => break,
                Err(_) => errors += 1,
            }
        }
        if stopping || sent.elapsed() >= BATCH {
            frames += batch.len() as u64;
            let _ = tx.send(std::mem::replace(&mut batch, Vec::with_capacity(64)));
            sent = Instant::now();
        }
        if stopping {
            return (frames, errors);
        }
        std::thread::sleep(POLL);
    }
}

fn frame_of(s: &RobotState, recv_ns: u64) -> Frame {
    let n = (s.num_joints as usize).min(s.applied_position.len());
    Frame {
        recv_ns,
        seq: s.seq,
        hal_ns: s.timestamp_ns,
        session: s.session,
        status: s.status,
        hold_reason: s.hold_reason,
        fault: s.fault,
        robot_mode: s.robot_mode,
        robot_cycles: s.robot_cycles,
        robot_errors: s.robot_errors,
        robot_reflex_errors: s.robot_reflex_errors,
        q: s.applied_position[..n].to_vec(),
    }
}

/// Writes the header and every batch; returns the frames written.
fn write_all(file: std::fs::File, rx: mpsc::Receiver<Vec<Frame>>) -> anyhow::Result<u64> {
    let mut out = std::io::BufWriter::new(file);
    writeln!(out, "{HEADER}")?;
    let mut written = 0;
    let mut text = String::new();
    for batch in rx {
        text.clear();
        for f in &batch {
            f.write_line(&mut text);
        }
        out.write_all(text.as_bytes())?;
        written += batch.len() as u64;
    }
    out.flush()?;
    Ok(written)
}

/// SCHED_FIFO at `priority` for the calling thread, or a warning why not.
fn set_fifo(priority: i32) {
    let param = libc::sched_param { sched_priority: priority };
    // SAFETY: pthread_setschedparam on this thread with a valid parameter; no memory is shared.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
    if rc != 0 {
        eprintln!(
            "mars-checker: could not read at SCHED_FIFO {priority} ({}); reading at normal priority",
            std::io::Error::from_raw_os_error(rc)
        );
    }
}
