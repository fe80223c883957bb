//! A TCP link with a delay, for running marsd's `[remote]` against `marsd serve` as if over a slow network: every
//! byte sent either way is held for the one-way delay before it goes on, and the link can be cut (bytes held until
//! it is restored, as TCP retransmits across a partition) for a while.
//!
//! Why not `tc netem`: this VM's kernel is built without it (`CONFIG_NET_SCH_NETEM` is not set; nor FQ, whose
//! departure times a BPF program could set), so the delay is added in user space, between two TCP sockets on
//! localhost. Zenoh sees a TCP peer whose bytes arrive late, as over a long link; what is not modelled is loss
//! and reordering below TCP (TCP hides both from Zenoh as delay anyway).

use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::thread;
use std::time::{Duration, Instant};

/// What the link does to traffic, changeable while it runs.
#[derive(Debug, Default)]
pub struct Shape {
    one_way_us: AtomicU64,
    cut: AtomicBool,
    /// Bytes carried, both ways.
    bytes: AtomicU64,
}

impl Shape {
    pub fn set_delay(&self, one_way: Duration) {
        self.one_way_us.store(one_way.as_micros() as u64, Ordering::Release);
    }

    pub fn delay(&self) -> Duration {
        Duration::from_micros(self.one_way_us.load(Ordering::Acquire))
    }

    /// While cut, nothing goes through; what was sent waits and goes on, in order, when the link is restored.
    pub fn set_cut(&self, cut: bool) {
        self.cut.store(cut, Ordering::Release);
    }

    pub fn bytes(&self) -> u64 {
        self.bytes.load(Ordering::Acquire)
    }
}

/// A running link: connections to `local` are carried to `upstream`, shaped by [`ShapedLink::shape`].
pub struct ShapedLink {
    pub local: SocketAddr,
    shape: Arc<Shape>,
}

impl ShapedLink {
    /// Listens on an ephemeral localhost port; every connection made to it is carried to `upstream`.
    pub fn start(upstream: SocketAddr, one_way: Duration) -> std::io::Result<Self> {
        let listener = TcpListener::bind("127.0.0.1:0")?;
        let local = listener.local_addr()?;
        let shape = Arc::new(Shape::default());
        shape.set_delay(one_way);
        let s = shape.clone();
        thread::Builder::new().name("shaped-link".into()).spawn(move || {
            for conn in listener.incoming().flatten() {
                if let Ok(up) = TcpStream::connect(upstream) {
                    carry(conn, up, &s);
                }
            }
        })?;
        Ok(Self { local, shape })
    }

    pub fn shape(&self) -> &Arc<Shape> {
        &self.shape
    }
}

/// Both directions of one connection.
fn carry(a: TcpStream, b: TcpStream, shape: &Arc<Shape>) {
    for s in [&a, &b] {
        let _ = s.set_nodelay(true);
    }
    let (a2, b2) = (a.try_clone(), b.try_clone());
    if let (Ok(a2), Ok(b2)) = (a2, b2) {
        pipe(a, b2, shape.clone());
        pipe(b, a2, shape.clone());
    }
}

/// Bytes read from `from` are written to `to` one delay after they were read, in order.
fn pipe(mut from: TcpStream, mut to: TcpStream, shape: Arc<Shape>) {
    let (tx, rx) = mpsc::channel::<(Instant, Vec<u8>)>();
    let s = shape.clone();
    let _ = thread::Builder::new().name("shaped-link-in".into()).spawn(move || {
        let mut buf = vec![0u8; 64 * 1024];
        loop {
            match from.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => {
                    s.bytes.fetch_add(n as u64, Ordering::AcqRel);
                    if tx.send((Instant::now(), buf[..n].to_vec())).is_err() {
                        break;
                    }
                }
            }
        }
    });
    let _ = thread::Builder::new().name("shaped-link-out".into()).spawn(move || {
        for (read_at, bytes) in rx {
            loop {
                let due = read_at + shape.delay();
                let now = Instant::now();
                if shape.cut.load(Ordering::Acquire) {
                    thread::sleep(Duration::from_millis(1));
                } else if now < due {
                    thread::sleep(due - now);
                } else {
                    break;
                }
            }
            if to.write_all(&bytes).is_err() {
                break;
            }
        }
        let _ = to.shutdown(Shutdown::Write);
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn echo_server() -> SocketAddr {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = l.local_addr().unwrap();
        thread::spawn(move || {
            for mut c in l.incoming().flatten() {
                thread::spawn(move || {
                    let mut buf = [0u8; 256];
                    while let Ok(n) = c.read(&mut buf) {
                        if n == 0 || c.write_all(&buf[..n]).is_err() {
                            break;
                        }
                    }
                });
            }
        });
        addr
    }

    fn round_trip(c: &mut TcpStream) -> Duration {
        let t = Instant::now();
        c.write_all(b"ping").unwrap();
        let mut buf = [0u8; 4];
        c.read_exact(&mut buf).unwrap();
        assert_eq!(&buf, b"ping");
        t.elapsed()
    }

    /// A 20 ms one-way delay makes a round trip of at least 40 ms; a cut holds the bytes until restored.
    #[test]
    fn bytes_arrive_one_delay_late_each_way_and_wait_out_a_cut() {
        let link = ShapedLink::start(echo_server(), Duration::from_millis(20)).unwrap();
        let mut c = TcpStream::connect(link.local).unwrap();
        c.set_nodelay(true).unwrap();
        let rtt = round_trip(&mut c);
        assert!(rtt >= Duration::from_millis(40), "{rtt:?}");
        link.shape().set_delay(Duration::ZERO);
        link.shape().set_cut(true);
        let restore = link.shape().clone();
        let t = thread::spawn(move || {
            thread::sleep(Duration::from_millis(100));
            restore.set_cut(false);
        });
        let rtt = round_trip(&mut c);
        t.join().unwrap();
        assert!(rtt >= Duration::from_millis(100), "{rtt:?}");
        assert_eq!(link.shape().bytes(), 16);
    }
}
