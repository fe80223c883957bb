//! Prints, every 2 s for N s (default 30), what the stall witness saw in the last 2 s, and how many of those
//! windows were calm (`Evidence::is_calm`: what a rerun waits for). Run as root (the witness needs SCHED_FIFO).
fn main() {
    let secs: u64 = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(30);
    let w = stall_witness::witness();
    std::thread::sleep(std::time::Duration::from_secs(2));
    let mut calm = 0;
    for _ in 0..secs / 2 {
        std::thread::sleep(std::time::Duration::from_secs(2));
        let now = stall_witness::monotonic_ns();
        let Some(e) = w.seen_in(now - 2_000_000_000, now) else { return println!("no evidence: {:?}", w.unable()) };
        calm += u32::from(e.is_calm());
        println!("{e}");
    }
    println!("calm windows: {calm} of {}", secs / 2);
}
