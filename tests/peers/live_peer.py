"""A robot's live view on the Zenoh network, read and written from README's description of the frame (not from
our Rust code), with Zenoh's own Python binding (PyPI eclipse-zenoh), as a client of a router.

Reads one JSON object from the file named by its argument, or from stdin: {"connect": locator, "prefix": ..., "watch": robot or null, "robot": name,
"frame": frame, "seconds": s}. Puts `frame` on <prefix>/<robot>/live every 20 ms for `seconds`; with "watch", also
waits (at most 15 s) for one frame on <prefix>/<watch>/live and prints it as one JSON line. A frame in JSON:
{"seq", "timestamp_ns", "period_ns", "inference_budget_ns", "channels": 12 lists of [count, p50, p99, max,
over_period, start_ns, end_ns], "phase", "trip", "episode", "ticks", "policy_beats", "starved", "servo": 7 counters,
"hal": 6 counters, "camera": name}. Exits 1 with a message on stderr when no frame comes or one does not parse.
"""

import json
import struct
import sys
import time

import zenoh

# "MARL", version, flags; seq, timestamp, period, budget; 12 × 7 channel values; phase, trip; episode, ticks,
# policy beats, starved; the servo's 7 counters; the HAL's 6; the camera's name.
LIVE = struct.Struct("<4sHH4Q84QII4Q7Q6Q32s")
VERSION = 1
SCALARS = ("seq", "timestamp_ns", "period_ns", "inference_budget_ns")
COUNTS = ("episode", "ticks", "policy_beats", "starved")


def encode(f):
    channels = [v for c in f["channels"] for v in c]
    camera = f["camera"].encode().ljust(32, b"\0")
    return LIVE.pack(b"MARL", VERSION, 0, *(f[k] for k in SCALARS), *channels, f["phase"], f["trip"],
                     *(f[k] for k in COUNTS), *f["servo"], *f["hal"], camera)


def decode(b):
    if len(b) != LIVE.size:
        raise ValueError(f"a live frame of {len(b)} bytes, not {LIVE.size}")
    v = LIVE.unpack(b)
    if v[0] != b"MARL" or v[1] != VERSION:
        raise ValueError(f"not a version-{VERSION} live frame: {v[0]!r} {v[1]}")
    v = list(v[3:])
    f = dict(zip(SCALARS, v[:4]))
    f["channels"] = [v[4 + 7 * i:11 + 7 * i] for i in range(12)]
    v = v[88:]
    f["phase"], f["trip"] = v[0], v[1]
    f.update(zip(COUNTS, v[2:6]))
    f["servo"], f["hal"] = v[6:13], v[13:19]
    f["camera"] = v[19].rstrip(b"\0").decode()
    return f


def main():
    if len(sys.argv) > 1:
        with open(sys.argv[1]) as f:
            job = json.load(f)
    else:
        job = json.load(sys.stdin)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([job["connect"]]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as session:
        watched = job.get("watch")
        sub = session.declare_subscriber(f"{job['prefix']}/{watched}/live") if watched else None
        pub = session.declare_publisher(f"{job['prefix']}/{job['robot']}/live")
        payload = encode(job["frame"])
        start, seen = time.monotonic(), sub is None
        while True:
            elapsed = time.monotonic() - start
            if seen and elapsed >= job["seconds"]:
                break
            if not seen and elapsed > 15.0:
                sys.exit(f"no frame on {job['prefix']}/{watched}/live")
            pub.put(payload)
            sample = sub.try_recv() if sub is not None and not seen else None
            if sample is not None:
                print(json.dumps(decode(sample.payload.to_bytes())), flush=True)
                seen = True
            time.sleep(0.02)


if __name__ == "__main__":
    main()
