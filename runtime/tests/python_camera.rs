//! A camera written in Python (`examples/python/camera_publisher.py`, with the `iceoryx2` package from PyPI) feeds
//! the runtime's camera check over real shared memory: its frames arrive pixel for pixel, and each kind of bad
//! frame a camera process can send is refused with its reason. `marsd camera` says the same from the command line.
//! The Python side is a peer no Rust code here wrote: the header layout, type name, service settings and schema
//! version it uses are checked by iceoryx2 and by our reader, not assumed.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use mars_ipc::node::create_node;
use mars_ipc::{ImageEncoding, ImageReader, RobotNamespace, SCHEMA_VERSION, SchemaMismatch};
use mars_runtime::observe::camera::{Camera, CameraRefusal, CameraSpec};

const MS: u64 = 1_000_000;

fn root() -> PathBuf {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/..")).canonicalize().unwrap()
}

/// The Python of `.ci/franka-sim-venv`, which installs iceoryx2's bindings too (returns at once when it has).
fn python() -> PathBuf {
    let installed = Command::new(root().join(".ci/franka-sim-venv")).current_dir(root()).status().unwrap();
    assert!(installed.success(), ".ci/franka-sim-venv failed");
    root().join(".venv-sim/bin/python")
}

fn robot(name: &str) -> String {
    format!("t{}-{name}", std::process::id())
}

/// Kills the child when dropped (a failed assertion must not leave a publisher running).
struct Kill(Child);
impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The example's test pattern: byte (y, x, c) of frame `seq` is (x + 2y + 3c + seq) mod 256.
fn pattern_matches(px: &[u8], width: usize, channels: usize, seq: u64) -> bool {
    px.iter().enumerate().all(|(i, b)| {
        let (c, x, y) = (i % channels, (i / channels) % width, i / channels / width);
        *b as u64 == (x as u64 + 2 * y as u64 + 3 * c as u64 + seq) % 256
    })
}

fn camera(robot: &str, spec: CameraSpec) -> (iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>, Camera) {
    let (node, _) = create_node("python-camera-test").unwrap();
    let reader = ImageReader::new(&node, &RobotNamespace::new(robot).unwrap(), "top").unwrap();
    (node, Camera::new(reader, spec))
}

#[test]
fn frames_from_the_python_example_arrive_pixel_for_pixel() {
    let python = python();
    let robot = robot("py-cam");
    // A generous age limit: this test is about the shared clock and the bytes, not about how fast CI is.
    let spec = CameraSpec { width: 32, height: 24, encoding: ImageEncoding::Rgb8, max_age_ns: 2_000 * MS };
    let (_node, mut cam) = camera(&robot, spec);
    let child = Command::new(&python)
        .arg(root().join("examples/python/camera_publisher.py"))
        .args(["--robot", &robot, "--camera", "top", "--width", "32", "--height", "24", "--fps", "200"])
        .args(["--frames", "60"])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut child = Kill(child);
    let (mut seqs, started) = (Vec::new(), Instant::now());
    loop {
        let exited = child.0.try_wait().unwrap().is_some();
        let polled = cam.poll();
        assert_eq!(polled.refusal, None);
        let got = polled.frame.is_some();
        if let Some(f) = polled.frame {
            let h = *f.header();
            assert_eq!((h.width, h.height, h.encoding), (32, 24, ImageEncoding::Rgb8 as u32));
            assert!(pattern_matches(f.pixels(), 32, 3, h.seq), "frame {} differs from the example's pattern", h.seq);
            seqs.push(h.seq);
        }
        if exited && !got {
            break;
        }
        assert!(started.elapsed() < Duration::from_secs(60), "the example did not finish: got {seqs:?}");
        std::thread::sleep(Duration::from_millis(1));
    }
    let status = child.0.wait().unwrap();
    let mut err = String::new();
    std::io::Read::read_to_string(child.0.stderr.as_mut().unwrap(), &mut err).unwrap();
    assert!(status.success(), "the example failed: {err}");
    eprintln!("used {} frames of 60 ({} superseded): {seqs:?}", seqs.len(), cam.check.counts.superseded);
    // Frames the subscriber's 2-frame buffer dropped while this thread slept are simply not seen; every one seen
    // was newer than the one before and exact.
    assert!(!seqs.is_empty() && seqs.windows(2).all(|w| w[0] < w[1]) && *seqs.last().unwrap() <= 60, "{seqs:?}");
    assert_eq!(cam.check.counts.refused(), 0);
}

#[test]
fn every_kind_of_bad_python_frame_is_refused_with_its_reason() {
    let python = python();
    let robot = robot("py-faults");
    let spec = CameraSpec { width: 32, height: 24, encoding: ImageEncoding::Rgb8, max_age_ns: 2_000 * MS };
    let (_node, mut cam) = camera(&robot, spec);
    let child = Command::new(&python)
        .arg(root().join("runtime/tests/fixtures/camera_faults.py"))
        .args([&robot, "top"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut child = Kill(child);
    let mut stdin = child.0.stdin.take().unwrap();
    let mut stdout = BufReader::new(child.0.stdout.take().unwrap());

    // Sends one frame and returns what the camera made of it.
    let mut send = |kind: &str| -> Result<u64, CameraRefusal> {
        writeln!(stdin, "{kind}").unwrap();
        let mut line = String::new();
        stdout.read_line(&mut line).unwrap();
        assert!(line.starts_with(&format!("sent {kind}")), "the fixture said {line:?}");
        let started = Instant::now();
        loop {
            let polled = cam.poll();
            if let Some(f) = polled.frame {
                return Ok(f.header().seq);
            }
            if let Some(r) = polled.refusal {
                return Err(r);
            }
            assert!(started.elapsed() < Duration::from_secs(20), "no {kind} frame arrived");
            std::thread::sleep(Duration::from_millis(1));
        }
    };

    assert_eq!(send("good"), Ok(1));
    let schema = SchemaMismatch { expected: SCHEMA_VERSION, found: SCHEMA_VERSION + 1 };
    assert_eq!(send("schema"), Err(CameraRefusal::Schema(schema)));
    assert_eq!(send("short"), Err(CameraRefusal::Length { expected: Some(32 * 24 * 3), found: 100 }));
    let size = send("size").unwrap_err();
    assert_eq!(size, CameraRefusal::Size { width: 16, height: 12, want_width: 32, want_height: 24 });
    assert_eq!(send("encoding"), Err(CameraRefusal::Encoding { found: 3, want: ImageEncoding::Rgb8 }));
    assert!(matches!(send("stale"), Err(CameraRefusal::Stale { age_ns, .. }) if age_ns >= 5_000 * MS));
    let wall = send("wall-clock").unwrap_err();
    assert!(matches!(wall, CameraRefusal::Future { .. }), "{wall:?}");
    eprintln!("a wall-clock stamp: {wall}");
    assert_eq!(send("replay"), Err(CameraRefusal::OutOfOrder { seq: 1, last_used: 1 }));
    // After all that, the next good frame is used.
    assert_eq!(send("good"), Ok(9));
    let c = cam.check.counts;
    assert_eq!((c.used, c.refused()), (2, 7), "{c:?}");
}

#[test]
fn marsd_camera_reports_a_healthy_camera_and_names_a_wrong_size() {
    let python = python();
    let robot = robot("py-watch");
    let child = Command::new(&python)
        .arg(root().join("examples/python/camera_publisher.py"))
        .args(["--robot", &robot, "--camera", "top", "--width", "32", "--height", "24", "--fps", "100"])
        .spawn()
        .unwrap();
    let _child = Kill(child);
    let dir = std::env::temp_dir().join(format!("mars-camera-watch-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let watch = |width: &str, seconds: &str, json: &Path| {
        Command::new(env!("CARGO_BIN_EXE_marsd"))
            .args(["camera", "--robot", &robot, "--camera", "top", "--width", width, "--height", "24"])
            .args(["--max-age-ms", "2000", "--seconds", seconds, "--frames", "20", "--json"])
            .arg(json)
            .output()
            .unwrap()
    };
    let out = watch("32", "30", &dir.join("ok.json"));
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{text}{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("ok.json")).unwrap()).unwrap();
    assert!(report["counts"]["used"].as_u64().unwrap() >= 20, "{report}");
    assert!(text.contains("capture → read age µs") && text.contains("usable frames/s"), "{text}");

    // The policy wants 64 px wide: every frame is refused, the reason names both sizes, and marsd exits 2.
    let out = watch("64", "2", &dir.join("bad.json"));
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(2), "{text}");
    assert!(text.contains("32×24 pixels where the policy expects 64×24"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}
