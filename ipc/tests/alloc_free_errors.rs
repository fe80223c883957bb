//! A real-time loop calls `receive` every tick and must be able to count a refused frame without touching the
//! heap: the refusal of a frame from another schema version allocates nothing, and neither does an ordinary
//! receive. (Sending is not in this claim: iceoryx2 0.10 allocates its per-sample bookkeeping in every loan;
//! see `runtime/src/alloc_count.rs`.) Counted with a global allocator of this test binary, on this thread only.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU32, Ordering};

use mars_ipc::node::create_node;
use mars_ipc::*;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

struct Counting;

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        // SAFETY: forwarded unchanged.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded unchanged.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        // SAFETY: forwarded unchanged.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}

fn unique_ns() -> RobotNamespace {
    static N: AtomicU32 = AtomicU32::new(0);
    RobotNamespace::new(&format!("alloc{}n{}", std::process::id(), N.fetch_add(1, Ordering::Relaxed))).unwrap()
}

#[test]
fn refusing_a_frame_of_another_schema_and_receiving_allocate_nothing() {
    let ns = unique_ns();
    let (node, _) = create_node("ipc-alloc-test").unwrap();
    let w = CommandWriter::new(&node, &ns).unwrap();
    let r = CommandReader::new(&node, &ns).unwrap();
    let c = JointCommand::position(1, 1, 0, &[0.0; 7]);
    // Warm-up: iceoryx2 connects the ports lazily, on the first receive.
    w.send(&c).unwrap();
    assert!(r.receive().unwrap().is_some());

    for _ in 0..8 {
        w.send_with_header(&c, FrameHeader { schema_version: SCHEMA_VERSION + 1 }).unwrap();
        w.send(&c).unwrap();
    }
    let before = allocations();
    let (mut refused, mut read) = (0, 0);
    for _ in 0..17 {
        match r.receive() {
            Err(FrameReceiveError::Schema(_)) => refused += 1,
            Ok(Some(_)) => read += 1,
            Ok(None) => {}
            Err(e) => panic!("{e}"),
        }
    }
    let after = allocations();
    assert_eq!((refused, read), (8, 8));
    assert_eq!(after - before, 0, "receive (with 8 schema refusals) allocated {} times", after - before);
}

#[test]
fn refusing_images_and_receiving_them_allocate_nothing() {
    let ns = unique_ns();
    let (node, _) = create_node("ipc-alloc-test").unwrap();
    let w = ImageWriter::new(&node, &ns, "top", 96 * 96 * 3).unwrap();
    let r = ImageReader::new(&node, &ns, "top").unwrap();
    let good = ImageHeader { width: 96, height: 96, encoding: ImageEncoding::Rgb8 as u32, ..Default::default() };
    let other_schema = ImageHeader { schema_version: SCHEMA_VERSION + 1, ..good };
    // Warm-up: iceoryx2 connects the ports lazily, on the first receive.
    w.send_with(good, |_| ()).unwrap();
    assert!(r.receive().unwrap().is_some());

    // The service keeps 2 frames per subscriber: send and receive in pairs.
    let (mut refused, mut read) = (0, 0);
    let mut counted = 0;
    for i in 0..8 {
        match i % 3 {
            0 => w.send_with(other_schema, |_| ()).unwrap(),
            1 => w.send_raw(good, 100, |_| ()).unwrap(),
            _ => w.send_with(good, |px| px.fill(1)).unwrap(),
        };
        let before = allocations();
        match r.receive() {
            Err(ImageReceiveError::Schema(_) | ImageReceiveError::Length { .. }) => refused += 1,
            Ok(Some(f)) => read += usize::from(f.pixels()[0] == 1),
            other => panic!("{:?}", other.map(|f| f.map(|f| *f.header()))),
        }
        counted += allocations() - before;
    }
    assert_eq!((refused, read), (6, 2));
    assert_eq!(counted, 0, "receive (with 6 refusals) allocated {counted} times");
}
