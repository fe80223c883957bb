#!/usr/bin/env python3
"""A Galaxea R1 Lite stand-in (right arm + gripper) on ROS 2's DDS wire, for testing `mars-hal --backend ros2`.

It is written with another DDS implementation than the HAL's (Eclipse Cyclone DDS's Python binding, not RustDDS), so
a test against it checks the wire itself: ROS 2's topic names (`rt/` + the ROS name), its type names
(`sensor_msgs::msg::dds_::JointState_`) and plain CDR, as a real R1 Lite's driver speaks them. No ROS installation.

What it does, as the robot does (Galaxea's docs and public drivers):
- subscribes /motion_target/target_joint_state_arm_right and /motion_target/target_position_gripper_right
  (`sensor_msgs/JointState`) BEST_EFFORT, as the robot's own subscribers are;
- publishes /hdas/feedback_arm_right and /hdas/feedback_gripper_right (`sensor_msgs/JointState`) RELIABLE, at
  --rate-hz; the arm's position holds its 6 joints (7 with --feedback-gripper-as-joint, as some docs show), the
  gripper's its stroke in mm (0 closed, 100 open);
- its joints track the newest arm target with a first-order lag (--time-constant-s), its gripper the newest
  gripper target at a limited speed; like the robot's controllers it *latches* the last target: it keeps going
  there after its commands stop;
- goes silent (stops publishing feedback, keeps receiving, tracking and logging) on SIGUSR1 or after
  --silent-after-s, and speaks again on SIGUSR2 (a robot driver that hung and came back);
- with --cameras, publishes its two cameras as the robot does, `sensor_msgs/CompressedImage` JPEG (encoded by
  Pillow's libjpeg-turbo) on /hdas/camera_head/left_raw/image_raw_color/compressed (1280×720) and
  /hdas/camera_wrist_right/color/image_raw/compressed (640×360), BEST_EFFORT, at --camera-hz, from a thread of
  their own: a test card of four flat quadrants (red, green / blue, grey) with a square in the middle whose grey
  level counts the frames (40 + 25·(k mod 8)); --camera-bad-every N cuts every N-th frame short (a truncated JPEG);
  each frame sent is logged (`camera_frame`);
- logs JSON lines (to --log, flushed per line): `ready`, `first_feedback`, every `arm_target` and
  `gripper_target` received (with CLOCK_MONOTONIC ns, the HAL's clock), `silent` (with the time of its last
  feedback), a `summary` every second and at exit (counts, last target, pose).

Discovery: with --loopback (the tests' setting) it is configured for this host only, without multicast (Linux's
`lo` has none): unicast to 127.0.0.1's well-known RTPS discovery ports, with a participant index of its own, so a
RustDDS participant that announces itself to 127.0.0.1 finds it and is found. --domain picks the DDS domain
(ROS_DOMAIN_ID), so tests running at the same time never see each other.
"""

import argparse
import json
import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field

# Cyclone DDS reads its configuration when the first domain is made: set before anything creates one.
LOOPBACK_CONFIG = """<CycloneDDS><Domain id="any">
  <General>
    <Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>
    <AllowMulticast>false</AllowMulticast>
  </General>
  <Discovery>
    <ParticipantIndex>auto</ParticipantIndex>
    <MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>
    <Peers><Peer address="127.0.0.1"/></Peers>
  </Discovery>
</Domain></CycloneDDS>"""


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0")))
    p.add_argument("--loopback", action="store_true", help="this host only, unicast discovery (see the docstring)")
    p.add_argument("--rate-hz", type=float, default=200.0, help="feedback rate (the profile's rate_hz)")
    p.add_argument("--start", default="0.0,1.0,-1.2,0.0,0.0,0.0", help="joint positions at start (rad)")
    p.add_argument("--start-gripper", type=float, default=100.0, help="gripper stroke at start (mm, 100 = open)")
    p.add_argument("--time-constant-s", type=float, default=0.05, help="first-order lag of the joints")
    p.add_argument("--gripper-speed", type=float, default=500.0, help="gripper stroke speed (mm/s)")
    p.add_argument("--silent-after-s", type=float, default=None, help="stop publishing feedback after this long")
    p.add_argument("--feedback-gripper-as-joint", action="store_true", help="arm feedback with 7 positions")
    p.add_argument("--duration-s", type=float, default=300.0, help="exit after this long (a leftover never lingers)")
    p.add_argument("--log", default=None, help="JSON-lines log file (default: stdout)")
    p.add_argument("--arm-feedback", default="/hdas/feedback_arm_right")
    p.add_argument("--gripper-feedback", default="/hdas/feedback_gripper_right")
    p.add_argument("--arm-target", default="/motion_target/target_joint_state_arm_right")
    p.add_argument("--gripper-target", default="/motion_target/target_position_gripper_right")
    p.add_argument("--cameras", action="store_true", help="publish the head and wrist cameras (JPEG)")
    p.add_argument("--camera-hz", type=float, default=15.0)
    p.add_argument("--camera-bad-every", type=int, default=0, help="truncate every N-th camera frame (0: none)")
    p.add_argument("--head-camera", default="/hdas/camera_head/left_raw/image_raw_color/compressed")
    p.add_argument("--wrist-camera", default="/hdas/camera_wrist_right/color/image_raw/compressed")
    return p.parse_args()


def test_card(w, h, k):
    """The cameras' picture: four flat quadrants and a centre square whose grey level counts frames (mod 8)."""
    from PIL import Image, ImageDraw

    img = Image.new("RGB", (w, h), (128, 128, 128))
    d = ImageDraw.Draw(img)
    d.rectangle([0, 0, w // 2 - 1, h // 2 - 1], fill=(200, 40, 40))
    d.rectangle([w // 2, 0, w - 1, h // 2 - 1], fill=(40, 200, 40))
    d.rectangle([0, h // 2, w // 2 - 1, h - 1], fill=(40, 40, 200))
    g = 40 + 25 * (k % 8)
    r = h // 8
    d.rectangle([w // 2 - r, h // 2 - r, w // 2 + r - 1, h // 2 + r - 1], fill=(g, g, g))
    return img


def dds_topic(ros_name):
    """ROS 2's DDS name of a topic: `rt` + the absolute ROS name."""
    return "rt" + ros_name


def main():
    args = parse_args()
    if args.loopback:
        os.environ["CYCLONEDDS_URI"] = LOOPBACK_CONFIG
    # Imported here, after the configuration is set.
    from cyclonedds.core import Qos, Policy
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl.annotations import final
    from cyclonedds.idl.types import float64, int32, sequence, uint8, uint32
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    # ROS 2's message types as rmw maps them to DDS: module `<pkg>::msg::dds_`, a trailing `_` on the type name,
    # final extensibility (plain CDR).
    @dataclass
    @final
    class Time_(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
        sec: int32 = 0
        nanosec: uint32 = 0

    @dataclass
    @final
    class Header_(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
        stamp: Time_ = field(default_factory=Time_)
        frame_id: str = ""

    @dataclass
    @final
    class JointState_(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
        header: Header_ = field(default_factory=Header_)
        name: sequence[str] = field(default_factory=list)
        position: sequence[float64] = field(default_factory=list)
        velocity: sequence[float64] = field(default_factory=list)
        effort: sequence[float64] = field(default_factory=list)

    # ROS 2's uint8[]: on the wire a length, then the bytes (Cyclone packs a `bytes` value given for it at once).
    @dataclass
    @final
    class CompressedImage_(IdlStruct, typename="sensor_msgs::msg::dds_::CompressedImage_"):
        header: Header_ = field(default_factory=Header_)
        format: str = ""
        data: sequence[uint8] = field(default_factory=list)

    log_file = open(args.log, "a", buffering=1) if args.log else sys.stdout
    log_lock = threading.Lock()

    def log(event, **fields):
        fields = {"ev": event, "t_ns": time.monotonic_ns(), "unix_s": time.time(), **fields}
        with log_lock:
            log_file.write(json.dumps(fields) + "\n")
            log_file.flush()

    q = [float(x) for x in args.start.split(",")]
    n = len(q)
    names = [f"right_arm_joint{i + 1}" for i in range(n)]
    dq = [0.0] * n
    target = list(q)
    gripper = args.start_gripper
    gripper_target = gripper

    dp = DomainParticipant(args.domain)
    reliable = Qos(Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)), Policy.History.KeepLast(10),
                   Policy.Durability.Volatile)
    best_effort = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(10), Policy.Durability.Volatile)
    arm_fb = DataWriter(dp, Topic(dp, dds_topic(args.arm_feedback), JointState_), qos=reliable)
    grip_fb = DataWriter(dp, Topic(dp, dds_topic(args.gripper_feedback), JointState_), qos=reliable)
    arm_cmd = DataReader(dp, Topic(dp, dds_topic(args.arm_target), JointState_), qos=best_effort)
    grip_cmd = DataReader(dp, Topic(dp, dds_topic(args.gripper_target), JointState_), qos=best_effort)

    silent = {"now": False, "logged": False, "resume": False}
    signal.signal(signal.SIGUSR1, lambda *_: silent.update(now=True))
    signal.signal(signal.SIGUSR2, lambda *_: silent.update(now=False, resume=True))
    stop = {"now": False}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(now=True))
    signal.signal(signal.SIGINT, lambda *_: stop.update(now=True))

    counts = {"arm_targets": 0, "gripper_targets": 0, "feedback": 0, "bad_targets": 0}
    last_arm_target = None
    last_gripper_target = None
    last_feedback_ns = None
    log("ready", pid=os.getpid(), domain=args.domain, start=q, start_gripper=gripper, rate_hz=args.rate_hz,
        time_constant_s=args.time_constant_s)

    # Its own pace since the last summary: the longest pause between two of its ticks and the longest feedback
    # write (a reliable write blocks while the reader's acknowledgements are due), so that a HAL without feedback
    # can tell whether this peer stopped sending.
    pace = {"max_tick_gap_ms": 0.0, "max_write_ms": 0.0}

    def summary(event):
        log(event, counts=counts, last_arm_target=last_arm_target, last_gripper_target=last_gripper_target,
            q=q, gripper=gripper, silent=silent["now"], last_feedback_ns=last_feedback_ns, **pace)
        pace.update(max_tick_gap_ms=0.0, max_write_ms=0.0)

    def stamp():
        t = time.time()
        return Header_(Time_(int(t), int((t % 1.0) * 1e9)), "")

    def cameras():
        import io

        specs = [("head_left", args.head_camera, 1280, 720), ("wrist_right", args.wrist_camera, 640, 360)]
        writers = [DataWriter(dp, Topic(dp, dds_topic(t), CompressedImage_), qos=best_effort) for _, t, _, _ in specs]
        k = 0
        next_frame = time.monotonic()
        while not stop["now"]:
            k += 1
            for (cam, _, w, h), writer in zip(specs, writers):
                buf = io.BytesIO()
                test_card(w, h, k).save(buf, format="JPEG", quality=90)
                data = buf.getvalue()
                bad = args.camera_bad_every > 0 and k % args.camera_bad_every == 0
                if bad:
                    data = data[: len(data) // 2]
                writer.write(CompressedImage_(stamp(), "rgb8; jpeg compressed bgr8", data))
                log("camera_frame", camera=cam, k=k, bad=bad, bytes=len(data))
            next_frame += 1.0 / args.camera_hz
            delay = next_frame - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_frame = time.monotonic()

    if args.cameras:
        threading.Thread(target=cameras, name="cameras", daemon=True).start()

    period = 1.0 / args.rate_hz
    started = time.monotonic()
    next_tick = started
    next_summary = started + 1.0
    last_now = started
    while not stop["now"]:
        now = time.monotonic()
        pace["max_tick_gap_ms"] = max(pace["max_tick_gap_ms"], (now - last_now) * 1e3)
        last_now = now
        if now - started > args.duration_s:
            break
        if args.silent_after_s is not None and now - started >= args.silent_after_s:
            silent["now"] = True
            args.silent_after_s = None  # once: SIGUSR2 may end it
        if silent["resume"]:
            silent.update(resume=False, logged=False)
            log("resumed", last_feedback_ns=last_feedback_ns)
        # Commands: every sample is logged; the newest valid one is the target (latched until the next).
        for m in arm_cmd.take(N=1000):
            if not isinstance(m, JointState_):
                continue  # an invalid sample (e.g. a writer gone)
            counts["arm_targets"] += 1
            pos = list(m.position)
            log("arm_target", pos=pos, names=list(m.name))
            if len(pos) >= n and all(math.isfinite(x) for x in pos[:n]):
                target = pos[:n]
                last_arm_target = target
            else:
                counts["bad_targets"] += 1
        for m in grip_cmd.take(N=1000):
            if not isinstance(m, JointState_):
                continue
            counts["gripper_targets"] += 1
            pos = list(m.position)
            log("gripper_target", pos=pos)
            if pos and math.isfinite(pos[0]):
                gripper_target = min(max(pos[0], 0.0), 100.0)
                last_gripper_target = gripper_target
        # The plant: a first-order lag toward the latched target; the gripper at a limited speed.
        a = 1.0 - math.exp(-period / args.time_constant_s) if args.time_constant_s > 0 else 1.0
        for i in range(n):
            step = a * (target[i] - q[i])
            dq[i] = step / period
            q[i] += step
        g_step = args.gripper_speed * period
        gripper += max(-g_step, min(g_step, gripper_target - gripper))
        if silent["now"]:
            if not silent["logged"]:
                log("silent", last_feedback_ns=last_feedback_ns, feedback=counts["feedback"])
                silent["logged"] = True
        else:
            # Stamped before the write: the HAL cannot have received this sample earlier.
            sent_ns = time.monotonic_ns()
            h = stamp()
            arm_pos = q + [gripper] if args.feedback_gripper_as_joint else list(q)
            arm_names = names + ["right_gripper"] if args.feedback_gripper_as_joint else names
            arm_vel = dq + [0.0] if args.feedback_gripper_as_joint else list(dq)
            arm_fb.write(JointState_(h, arm_names, arm_pos, arm_vel, [0.0] * len(arm_pos)))
            grip_fb.write(JointState_(h, ["right_gripper"], [gripper], [0.0], [0.0]))
            pace["max_write_ms"] = max(pace["max_write_ms"], (time.monotonic_ns() - sent_ns) * 1e-6)
            counts["feedback"] += 1
            last_feedback_ns = sent_ns
            if counts["feedback"] == 1:
                log("first_feedback", sent_ns=sent_ns, q=q, gripper=gripper)
        if now >= next_summary:
            summary("summary")
            next_summary += 1.0
        # Absolute deadlines: the rate holds on average even when one tick runs late.
        next_tick += period
        delay = next_tick - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        elif delay < -0.1:
            next_tick = time.monotonic()  # far behind (a stall): start afresh rather than burst
    summary("exit")


if __name__ == "__main__":
    main()
