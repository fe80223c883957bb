//! Forward kinematics, the Jacobian and the IK solve allocate nothing (they run in the servo tick): every heap
//! allocation of this test binary is counted.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering};

use mars_kinematics::{Arm, IkParams, Joints, flange_pose, jacobian, solve};

struct Counting;
static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn kinematics_calls_allocate_nothing() {
    let arm = Arm::fr3();
    let params = IkParams::default();
    let home = start_pose();
    let mut q = home;
    q[0] += 0.3;
    q[3] += 0.2;
    let target = flange_pose(&arm, &q);
    let far = mars_kinematics::Pose::translation(3.0, 0.0, 0.0);
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    let mut sink = 0.0;
    for _ in 0..100 {
        sink += flange_pose(&arm, &home).translation.x;
        sink += jacobian(&arm, &home).1[(0, 0)];
        sink += solve(&arm, &target, &home, &params).map(|s| s.q[0]).unwrap_or(0.0);
        sink += solve(&arm, &far, &home, &params).map(|s| s.q[0]).unwrap_or(1.0);
    }
    let after = ALLOCATIONS.load(Ordering::Relaxed);
    assert!(sink.is_finite());
    assert_eq!(after - before, 0, "allocations in 100 rounds of FK, Jacobian and two IK solves");
}

/// libfranka's examples' start pose [0, −π/4, 0, −3π/4, 0, π/2, π/4].
fn start_pose() -> Joints {
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};
    Joints::from_row_slice(&[0.0, -FRAC_PI_4, 0.0, -3.0 * FRAC_PI_4, 0.0, FRAC_PI_2, FRAC_PI_4])
}
