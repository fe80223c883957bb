"""A robot asking `marsd serve` for chunks, written from README's description of the wire (not from our Rust code),
with Zenoh's own Python binding (PyPI eclipse-zenoh).

Reads one JSON object from stdin: {"connect": locator, "prefix": ..., "robot": ..., "requests": [{seq, episode,
period, budget_ns, seed, observation, history, committed (optional)}, ...]}. Waits (at most 10 s) until the host answers its clock
query, then sends each request and prints one JSON line per reply: {"seq", "status", "k_requested", "k_used",
"capped", "over_budget", "w_inf", "chunk"}. Exits 1 with a message on stderr when a reply does not come or does not
parse.
"""

import json
import struct
import sys
import time

import zenoh

# Request: "MARQ", version, flags; seq, episode, period, capture_ns, sent_ns, budget_ns, seed; the three lengths.
REQUEST_HEAD = struct.Struct("<4sHH7QIII")
VERSION = 2
# Reply: "MARP", version, status; seq, received_ns, sent_ns; k_requested, k_used, flags; encode_ns; w_inf; length.
REPLY_HEAD = struct.Struct("<4sHH3QIIIQfI")


def encode(r):
    obs, hist, committed = r["observation"], r["history"], r.get("committed", [])
    head = REQUEST_HEAD.pack(b"MARQ", VERSION, 0, r["seq"], r["episode"], r["period"], 0, time.monotonic_ns(),
                             r["budget_ns"], r["seed"], len(obs), len(hist), len(committed))
    arrays = [struct.pack(f"<{len(a)}f", *a) for a in (obs, hist, committed)]
    return head + b"".join(arrays)


def decode(b):
    magic, version, status, seq, _recv, _sent, k_req, k_used, flags, _enc, w_inf, n = REPLY_HEAD.unpack_from(b)
    if magic != b"MARP" or version != VERSION:
        raise ValueError(f"not a version-{VERSION} reply: {magic!r} {version}")
    if len(b) != REPLY_HEAD.size + 4 * n:
        raise ValueError(f"a reply of {len(b)} bytes announcing {n} values")
    chunk = list(struct.unpack_from(f"<{n}f", b, REPLY_HEAD.size))
    return {"seq": seq, "status": status, "k_requested": k_req, "k_used": k_used, "capped": bool(flags & 1),
            "over_budget": bool(flags & 2), "w_inf": w_inf, "chunk": chunk}


def first_reply(session, key, payload, timeout):
    for reply in session.get(key, payload=payload, timeout=timeout):
        if reply.ok is not None:
            return reply.ok.payload.to_bytes()
        raise RuntimeError(f"{key}: error reply {reply.err.payload.to_string()}")
    return None


def main():
    job = json.load(sys.stdin)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([job["connect"]]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as session:
        deadline = time.monotonic() + 10.0
        while first_reply(session, f"{job['prefix']}/clock", b"", 0.2) is None:
            if time.monotonic() > deadline:
                sys.exit("the host never answered its clock")
        key = f"{job['prefix']}/{job['robot']}/infer"
        for r in job["requests"]:
            payload = first_reply(session, key, encode(r), 5.0)
            if payload is None:
                sys.exit(f"no reply to seq {r['seq']}")
            print(json.dumps(decode(payload)), flush=True)


if __name__ == "__main__":
    main()
