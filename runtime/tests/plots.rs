//! Every run plot renders to a PNG with the bundled font, also from empty inputs.

use std::path::{Path, PathBuf};

use hdrhistogram::Histogram;
use mars_ipc::MAX_JOINTS;
use mars_runtime::report::latency::{Channel, Totals};
use mars_runtime::report::plots::{
    EPISODES_SIZE, EpisodeTrace, K_SIZE, LATENCY_SIZE, plot_episodes, plot_k, plot_latency,
};

/// Set `MARS_PLOT_DIR` to keep the PNGs for a look.
fn out_dir(test: &str) -> (PathBuf, bool) {
    let (dir, keep) = match std::env::var_os("MARS_PLOT_DIR") {
        Some(d) => (PathBuf::from(d).join(test), true),
        None => (std::env::temp_dir().join(format!("marsd-plots-{}-{test}", std::process::id())), false),
    };
    std::fs::create_dir_all(&dir).unwrap();
    (dir, keep)
}

/// A PNG of the given size (signature and IHDR), and not trivially small.
fn assert_png(path: &Path, size: (u32, u32)) {
    let bytes = std::fs::read(path).expect("png written");
    assert!(bytes.len() > 2000, "{} is only {} bytes", path.display(), bytes.len());
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    let be = |b: &[u8]| u32::from_be_bytes(b.try_into().unwrap());
    assert_eq!((be(&bytes[16..20]), be(&bytes[20..24])), size, "{}", path.display());
}

fn synthetic_totals() -> Totals {
    let hist = |c: Channel, f: &dyn Fn(u64) -> u64, n: u64| {
        let mut h = c.new_histogram();
        (0..n).for_each(|i| h.saturating_record(f(i)));
        (c, h)
    };
    // Long-tailed times (ns): a bulk and a rarer, slower tail.
    let tail = |base: u64| move |i: u64| base + (i * 7919) % base + if i.is_multiple_of(997) { 40 * base } else { 0 };
    Totals::from_histograms([
        hist(Channel::WakeJitter, &tail(3_000), 100_000),
        hist(Channel::TickCompute, &tail(20_000), 100_000),
        hist(Channel::StateAge, &tail(400_000), 100_000),
        hist(Channel::Inference, &tail(8_000_000), 5_000),
        hist(Channel::KRequested, &|i| [2, 4, 8][(i % 3) as usize], 5_000),
        hist(Channel::KUsed, &|i| [2, 4, 6][(i % 3) as usize], 5_000),
    ])
}

fn two_branches() -> Vec<EpisodeTrace> {
    (0..8)
        .map(|e| {
            let mode = e % 2;
            let side = if mode == 0 { 1.0 } else { -1.0 };
            let n = 60;
            let q = (0..n)
                .map(|t| {
                    let s = t as f64 / n as f64;
                    let mut q = [0.0; MAX_JOINTS];
                    q[0] = side * 0.8 * s + 0.02 * e as f64;
                    q[1] = -0.5 + s;
                    q
                })
                .collect();
            let w_inf = (0..n).map(|t| t as f32 / n as f32).collect();
            EpisodeTrace { mode: Some(mode), q, w_inf, ..Default::default() }
        })
        .collect()
}

#[test]
fn all_plots_render_with_the_bundled_font() {
    let (dir, keep) = out_dir("all");
    let totals = synthetic_totals();
    plot_latency(&totals, &dir.join("latency.png")).unwrap();
    assert_png(&dir.join("latency.png"), LATENCY_SIZE);
    plot_k(&totals, &dir.join("k.png")).unwrap();
    assert_png(&dir.join("k.png"), K_SIZE);
    plot_episodes(&two_branches(), &["rim".into(), "handle".into()], 0, 1, &dir.join("episodes.png")).unwrap();
    assert_png(&dir.join("episodes.png"), EPISODES_SIZE);
    if !keep {
        std::fs::remove_dir_all(&dir).ok();
    }
}

#[test]
fn empty_inputs_still_render_and_bad_joints_error() {
    let (dir, keep) = out_dir("empty");
    let none = Totals::from_histograms(std::iter::empty::<(Channel, Histogram<u64>)>());
    plot_latency(&none, &dir.join("latency.png")).unwrap();
    plot_k(&none, &dir.join("k.png")).unwrap();
    plot_episodes(&[], &[], 0, 1, &dir.join("episodes.png")).unwrap();
    let short = EpisodeTrace { mode: None, q: vec![[0.1; MAX_JOINTS]], w_inf: vec![], ..Default::default() };
    plot_episodes(&[short], &[], 2, 3, &dir.join("one_point.png")).unwrap();
    assert!(plot_episodes(&[], &[], 0, MAX_JOINTS, &dir.join("bad.png")).is_err());
    if !keep {
        std::fs::remove_dir_all(&dir).ok();
    }
}
