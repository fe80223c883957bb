"""A camera for marsd, in Python: publish frames on mars/<robot>/camera/<camera> over iceoryx2, zero-copy.

Any process can be a camera. Each frame is an `ImageHeader` (the iceoryx2 user header) followed by the pixels as a
`[u8]` slice, written straight into shared memory; marsd reads it in place. Stamp each frame with its capture
time on CLOCK_MONOTONIC (time.monotonic_ns()), the clock every mars process shares: marsd refuses frames that are
too old, "from the future" (a wall-clock stamp), of another size or encoding than the policy's, or of another
schema version. Check what arrives with:

    marsd camera --robot fr3 --camera top --width 96 --height 96

Needs only `pip install iceoryx2==0.10.0` (the version of the Rust side). This example draws a moving test
pattern; a real driver would copy (or capture directly) into `sample.payload()` instead.

    python examples/python/camera_publisher.py --robot fr3 --camera top --width 96 --height 96 --fps 30
"""

import argparse
import ctypes
import sys
import time

import iceoryx2 as iox2

# Must equal mars_ipc::SCHEMA_VERSION (ipc/src/schema.rs); marsd refuses frames of any other version.
SCHEMA_VERSION = 9
ENCODINGS = {"rgb8": (1, 3), "bgr8": (2, 3), "mono8": (3, 1)}


class ImageHeader(ctypes.Structure):
    """mars_ipc::ImageHeader, field for field (#[repr(C)])."""

    _fields_ = [
        ("schema_version", ctypes.c_uint32),
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
        ("encoding", ctypes.c_uint32),
        ("seq", ctypes.c_uint64),
        ("timestamp_ns", ctypes.c_uint64),
    ]

    @staticmethod
    def type_name() -> str:
        return "mars::ImageHeader"


class CameraPublisher:
    """One camera's publisher, with the service settings of mars_ipc::wire (iceoryx2 refuses to open a service
    with incompatible ones, so a camera started before or after marsd meets it either way)."""

    def __init__(self, robot: str, camera: str, max_bytes: int):
        iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
        self.node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
        service = (
            self.node.service_builder(iox2.ServiceName.new(f"mars/{robot}/camera/{camera}"))
            .publish_subscribe(iox2.Slice[ctypes.c_uint8])
            .user_header(ImageHeader)
            .subscriber_max_buffer_size(2)
            .history_size(0)
            .max_publishers(2)
            .max_subscribers(8)
            .max_nodes(16)
            .open_or_create()
        )
        self.publisher = (
            service.publisher_builder()
            .initial_max_slice_len(max_bytes)
            .allocation_strategy(iox2.AllocationStrategy.PowerOfTwo)
            .create()
        )

    def send(self, pixels: bytes, width: int, height: int, encoding: int, seq: int, timestamp_ns: int,
             schema_version: int = SCHEMA_VERSION) -> None:
        """Loan len(pixels) bytes of shared memory, fill in the header, copy the pixels there once, deliver."""
        sample = self.publisher.loan_slice_uninit(len(pixels))
        h = sample.user_header().contents
        h.schema_version = schema_version
        h.width, h.height, h.encoding = width, height, encoding
        h.seq, h.timestamp_ns = seq, timestamp_ns
        ctypes.memmove(sample.payload().as_ptr(), pixels, len(pixels))
        sample.assume_init().send()


def test_pattern(width: int, height: int, channels: int):
    """Frame `seq` of a pattern anyone can check: byte (y, x, c) = (x + 2y + 3c + seq) mod 256."""
    base = bytes((x + 2 * y + 3 * c) & 255 for y in range(height) for x in range(width) for c in range(channels))
    shifts = [bytes((v + s) & 255 for v in range(256)) for s in range(256)]
    return lambda seq: base.translate(shifts[seq & 255])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robot", required=True)
    p.add_argument("--camera", required=True)
    p.add_argument("--width", type=int, default=96)
    p.add_argument("--height", type=int, default=96)
    p.add_argument("--encoding", choices=sorted(ENCODINGS), default="rgb8")
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--frames", type=int, default=0, help="stop after this many frames (0: run until Ctrl-C)")
    a = p.parse_args()
    code, channels = ENCODINGS[a.encoding]
    frame = test_pattern(a.width, a.height, channels)
    camera = CameraPublisher(a.robot, a.camera, a.width * a.height * channels)
    period_ns = int(1e9 / a.fps)
    next_ns = time.monotonic_ns()
    seq = 0
    try:
        while a.frames == 0 or seq < a.frames:
            seq += 1
            # A real camera stamps the exposure; here the "exposure" is now.
            camera.send(frame(seq), a.width, a.height, code, seq, time.monotonic_ns())
            next_ns += period_ns
            time.sleep(max(0.0, (next_ns - time.monotonic_ns()) / 1e9))
    except KeyboardInterrupt:
        pass
    print(f"published {seq} frames", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
