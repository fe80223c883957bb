//! `marsd` as a systemd `Type=notify` service: the test plays systemd's notify socket. READY=1 must come only
//! after the HAL handshake, WATCHDOG=1 pings while the loops run, and STOPPING=1 on SIGTERM, before exit 0.

use std::os::unix::net::UnixDatagram;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

// One real-time rig at a time on this machine, across test binaries (see the file).

/// A child process killed when dropped, so a failing test leaves nothing running.
struct Proc(Child);
impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn root() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// Datagrams received until `deadline`, or until one contains `until`.
fn receive(sock: &UnixDatagram, until: &str, deadline: Instant) -> Vec<String> {
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    while Instant::now() < deadline {
        if let Ok(n) = sock.recv(&mut buf) {
            let msg = String::from_utf8_lossy(&buf[..n]).into_owned();
            let done = msg.contains(until);
            got.push(msg);
            if done {
                break;
            }
        }
    }
    got
}

#[test]
fn ready_after_the_hal_handshake_watchdog_pings_and_stopping_on_sigterm() {
    let _rt = mars_runtime::rt::rig_lock::rt_rig_lock().expect("taking the real-time rig lock");
    let dir = std::env::temp_dir().join(format!("marsd-notify-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let sock_path = dir.join("notify.sock");
    let _ = std::fs::remove_file(&sock_path);
    let sock = UnixDatagram::bind(&sock_path).unwrap();
    sock.set_read_timeout(Some(Duration::from_millis(50))).unwrap();
    let robot = format!("notify{}", std::process::id());

    let marsd = Proc(
        Command::new(env!("CARGO_BIN_EXE_mars-hil"))
            .current_dir(root())
            .args(["marsd", "--config", "configs/marsd.toml", "--robot", &robot, "--episodes", "0", "--out"])
            .arg(dir.join("out"))
            .env("NOTIFY_SOCKET", &sock_path)
            .env("WATCHDOG_USEC", "400000")
            .stderr(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .unwrap(),
    );
    // No HAL yet: no READY.
    let early = receive(&sock, "READY=1", Instant::now() + Duration::from_secs(2));
    assert!(early.iter().all(|m| !m.contains("READY=1")), "READY before any HAL: {early:?}");

    let _hal = Proc(
        Command::new(env!("CARGO_BIN_EXE_mars-hil"))
            .current_dir(root())
            // As the demo runs it: real-time, above marsd's servo loop on the servo's core.
            .args(["hal", "--profile", "configs/fr3.toml", "--robot", &robot, "--core", "1", "--rt-priority", "85"])
            .stderr(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let ready = receive(&sock, "READY=1", Instant::now() + Duration::from_secs(10));
    assert!(ready.iter().any(|m| m.contains("READY=1")), "no READY after the HAL started: {ready:?}");

    // WatchdogSec = 0.4 s: pings every 0.2 s while healthy.
    let pings = receive(&sock, "never", Instant::now() + Duration::from_secs(1));
    let n = pings.iter().filter(|m| m.contains("WATCHDOG=1")).count();
    assert!(n >= 3, "{n} watchdog pings in 1 s: {pings:?}");

    let mut marsd = marsd;
    // SAFETY: kill(2) on our child's pid.
    unsafe { libc::kill(marsd.0.id() as libc::pid_t, libc::SIGTERM) };
    let stopping = receive(&sock, "STOPPING=1", Instant::now() + Duration::from_secs(3));
    assert!(stopping.iter().any(|m| m.contains("STOPPING=1")), "{stopping:?}");
    let t = Instant::now();
    let status = loop {
        if let Some(s) = marsd.0.try_wait().unwrap() {
            break s;
        }
        assert!(t.elapsed() < Duration::from_secs(5), "marsd did not exit after SIGTERM");
        std::thread::sleep(Duration::from_millis(10));
    };
    assert_eq!(status.code(), Some(0));
    let _ = std::fs::remove_dir_all(&dir);
}
