//! `marsd camera`: watch one camera's frames for a few seconds through the same check the policy uses, and say
//! what arrived, what was refused and why, how old frames were when read, and at what rate they came. The first
//! thing to run when a camera driver (yours, in any language) is meant to feed a policy.

use std::fmt;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use hdrhistogram::Histogram;
use mars_ipc::clock::monotonic_ns;
use mars_ipc::node::create_node;
use mars_ipc::{ImageEncoding, ImageReader, RobotNamespace};
use serde::Serialize;

use crate::observe::camera::{Camera, CameraCounts, CameraSpec};

#[derive(clap::Args, Debug, Clone)]
pub struct CameraArgs {
    /// The robot whose camera to watch (the service is mars/<robot>/camera/<camera>).
    #[arg(long)]
    pub robot: String,
    #[arg(long)]
    pub camera: String,
    /// The width the policy expects (px).
    #[arg(long)]
    pub width: u32,
    /// The height the policy expects (px).
    #[arg(long)]
    pub height: u32,
    /// The encoding the policy expects: rgb8, bgr8 or mono8.
    #[arg(long, default_value = "rgb8", value_parser = parse_encoding)]
    pub encoding: ImageEncoding,
    /// Oldest capture the policy may act on (ms).
    #[arg(long, default_value_t = 50.0)]
    pub max_age_ms: f64,
    /// How long to watch (s).
    #[arg(long, default_value_t = 3.0)]
    pub seconds: f64,
    /// Stop early after this many usable frames.
    #[arg(long)]
    pub frames: Option<u64>,
    /// Also write the report as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

fn parse_encoding(s: &str) -> Result<ImageEncoding, String> {
    ImageEncoding::from_name(s).ok_or_else(|| format!("unknown encoding {s:?}: use rgb8, bgr8 or mono8"))
}

/// What the watch saw (also its JSON).
#[derive(Debug, Clone, Serialize)]
pub struct CameraReport {
    pub service: String,
    pub seconds: f64,
    pub counts: CameraCounts,
    /// The first refusal of each kind, in the order they happened.
    pub refusals: Vec<String>,
    /// Capture → read age of the usable frames (µs): p50, p99, max.
    pub age_us: Option<[f64; 3]>,
    /// Usable frames per second, from the first to the last one's capture time.
    pub rate_hz: Option<f64>,
}

impl CameraReport {
    /// True when the camera delivered usable frames and nothing was refused.
    pub fn healthy(&self) -> bool {
        self.counts.used > 0 && self.counts.refused() == 0
    }
}

pub fn run(a: &CameraArgs) -> anyhow::Result<CameraReport> {
    anyhow::ensure!(a.max_age_ms > 0.0 && a.seconds > 0.0, "--max-age-ms and --seconds must be positive");
    let ns = RobotNamespace::new(&a.robot)?;
    let (node, _) = create_node("marsd-camera")?;
    let reader = ImageReader::new(&node, &ns, &a.camera).context("opening the camera's service")?;
    let spec =
        CameraSpec { width: a.width, height: a.height, encoding: a.encoding, max_age_ns: (a.max_age_ms * 1e6) as u64 };
    let mut camera = Camera::new(reader, spec);
    let mut ages = Histogram::<u64>::new_with_bounds(1, 60_000_000, 3)?;
    let (mut first, mut last) = (None, 0u64);
    let mut refusals: Vec<String> = Vec::new();
    let mut kinds_seen = Vec::new();
    let started = Instant::now();
    while started.elapsed().as_secs_f64() < a.seconds && a.frames.is_none_or(|n| camera.check.counts.used < n) {
        let polled = camera.poll();
        // Read after the poll: no frame it used was read later than this.
        let now = monotonic_ns();
        if let Some(r) = polled.refusal {
            let kind = std::mem::discriminant(&r);
            if !kinds_seen.contains(&kind) {
                kinds_seen.push(kind);
                refusals.push(r.to_string());
            }
        }
        if let Some(f) = polled.frame {
            let t = f.header().timestamp_ns;
            ages.saturating_record((now.saturating_sub(t) / 1000).max(1));
            first.get_or_insert(t);
            last = t;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let used = camera.check.counts.used;
    let rate_hz = first.filter(|f| used > 1 && last > *f).map(|f| (used - 1) as f64 / ((last - f) as f64 / 1e9));
    let age_us = (!ages.is_empty())
        .then(|| [ages.value_at_quantile(0.5) as f64, ages.value_at_quantile(0.99) as f64, ages.max() as f64]);
    let report = CameraReport {
        service: camera.service().to_owned(),
        seconds: started.elapsed().as_secs_f64(),
        counts: camera.check.counts,
        refusals,
        age_us,
        rate_hz,
    };
    if let Some(path) = &a.json {
        std::fs::write(path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(report)
}

impl fmt::Display for CameraReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let c = &self.counts;
        writeln!(
            f,
            "{} over {:.1} s: {} frames used, {} superseded by a newer one, {} refused",
            self.service,
            self.seconds,
            c.used,
            c.superseded,
            c.refused()
        )?;
        if c.refused() > 0 {
            writeln!(
                f,
                "  refused: schema {}, length {}, size {}, encoding {}, stale {}, future {}, out of order {}, port {}",
                c.schema, c.length, c.size, c.encoding, c.stale, c.future, c.out_of_order, c.port
            )?;
        }
        for r in &self.refusals {
            writeln!(f, "  refused because {r}")?;
        }
        if let Some([p50, p99, max]) = self.age_us {
            writeln!(f, "  capture → read age µs: p50 {p50:.0} p99 {p99:.0} max {max:.0}")?;
        }
        if let Some(hz) = self.rate_hz {
            writeln!(f, "  rate: {hz:.1} usable frames/s")?;
        }
        if c.used == 0 && c.refused() == 0 {
            writeln!(f, "  no frame arrived: is the camera publishing on this robot and camera id?")?;
        }
        Ok(())
    }
}
