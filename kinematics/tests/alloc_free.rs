//! Forward kinematics, the Jacobian and the IK solve allocate nothing (they run in the servo tick): this thread's
//! heap allocations are counted by the runtime's own counting allocator (mars-rt's `CountingAlloc`).

use mars_kinematics::{Arm, IkParams, Joints, flange_pose, jacobian, solve};
use mars_rt::alloc_count::{self, CountingAlloc};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

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
    let before = alloc_count::thread_counts().expect("CountingAlloc is this binary's global allocator");
    let mut sink = 0.0;
    for _ in 0..100 {
        sink += flange_pose(&arm, &home).translation.x;
        sink += jacobian(&arm, &home).1[(0, 0)];
        sink += solve(&arm, &target, &home, &params).map(|s| s.q[0]).unwrap_or(0.0);
        sink += solve(&arm, &far, &home, &params).map(|s| s.q[0]).unwrap_or(1.0);
    }
    let after = alloc_count::thread_counts().unwrap();
    assert!(sink.is_finite());
    assert_eq!(after.system - before.system, 0, "allocations in 100 rounds of FK, Jacobian and two IK solves");
}

/// libfranka's examples' start pose [0, −π/4, 0, −3π/4, 0, π/2, π/4].
fn start_pose() -> Joints {
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};
    Joints::from_row_slice(&[0.0, -FRAC_PI_4, 0.0, -3.0 * FRAC_PI_4, 0.0, FRAC_PI_2, FRAC_PI_4])
}
