"""A minimal live box feeder: a scenario's ``detections.csv`` sent to a running daemon.

What a detector process on the companion does (docs/box-feed.md), with the detector
replaced by a file: for each frame of the scenario, one ``tcm-boxes/1`` UDP datagram
with that frame's boxes (an empty list for a frame without rows), at the scenario's
frame rate, ``--latency-ms`` after the frame's capture time.

    .venv/bin/python tools/box_feeder_example.py SCENARIO_DIR --to udp:127.0.0.1:14660

and the daemon, e.g.::

    tcm-companion run --set detection.backend='"boxes"' \\
        --set daemon.box_feed='"udp:127.0.0.1:14660"'

**The capture time.** A real feeder stamps each message with the capture time of the
frame it ran its detector on, on the companion's CLOCK_MONOTONIC in µs (Python:
``time.monotonic_ns() // 1000``; C: ``clock_gettime(CLOCK_MONOTONIC)``; a GStreamer
buffer's running time plus the pipeline's base time when the pipeline runs on the system
monotonic clock) — the clock the daemon stamps its own frames with. This example has no
camera: it plays the scenario's frame times from the moment it starts, so frame ``k`` is
"captured" at ``start + (t_k - t_0)`` on this machine's CLOCK_MONOTONIC. Its boxes meet
the daemon's frames only in time, not in content; against a daemon whose camera is not
synchronised with it, set ``[detection] boxes_time_tolerance_s`` to half the frame
period (0.02 at 25 Hz) or each frame has a 50 % chance of finding its message.

Written for clarity, not speed: only the standard library and the scenario readers of
this package (``detections.csv`` is read and checked by ``tcm_companion.io``).
"""

from __future__ import annotations

import argparse
import csv
import json
import socket
import sys
import time
from pathlib import Path


def monotonic_us() -> int:
    """The companion's CLOCK_MONOTONIC in µs (what the daemon stamps its frames with)."""
    return time.monotonic_ns() // 1000


def frame_times_us(scenario: Path) -> list[int]:
    """``frames.csv``'s capture times (µs), in frame order."""
    with open(scenario / "frames.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows or rows[0] != ["frame", "t_us"]:
        raise SystemExit(f"{scenario / 'frames.csv'}: expected the header frame,t_us")
    return [int(r[1]) for r in rows[1:] if r]


def boxes_by_frame(scenario: Path, n_frames: int) -> dict[int, list[dict[str, object]]]:
    """``detections.csv``'s rows as each frame's boxes (the protocol's box objects)."""
    from tcm_companion.io.scenario_extras import read_detections_csv

    out: dict[int, list[dict[str, object]]] = {}
    for r in read_detections_csv(scenario / "detections.csv", n_frames=n_frames):
        box: dict[str, object] = {
            "x_min": r.x_min,
            "y_min": r.y_min,
            "x_max": r.x_max,
            "y_max": r.y_max,
            "score": r.score,
        }
        if r.label:
            box["label"] = r.label
        out.setdefault(int(r.frame), []).append(box)
    return out


def datagram(camera: int | str, capture_mono_us: int, boxes: list[dict[str, object]]) -> bytes:
    """One ``tcm-boxes/1`` message."""
    doc = {"v": 1, "camera": camera, "capture_mono_us": capture_mono_us, "boxes": boxes}
    return json.dumps(doc, separators=(",", ":")).encode()


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="box_feeder_example.py",
        description=(
            "Send a scenario's detections.csv to a running tcm-companion as live boxes"
            " (tcm-boxes/1 over UDP, docs/box-feed.md): one datagram per frame, at the"
            " scenario's frame rate, stamped on this machine's CLOCK_MONOTONIC."
        ),
    )
    p.add_argument("scenario", type=Path, help="a tcm-scenario/1 directory with detections.csv")
    p.add_argument(
        "--to",
        default="udp:127.0.0.1:14660",
        help="the daemon's [daemon] box_feed address (default %(default)s)",
    )
    p.add_argument(
        "--camera", default="0", help="camera index or [camera] name (default %(default)s)"
    )
    p.add_argument(
        "--latency-ms",
        type=float,
        default=20.0,
        help="send each frame's message this long after its capture time, as a detector"
        " taking that long would (default %(default)s)",
    )
    p.add_argument("--loop", action="store_true", help="start again after the last frame")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        help="stop after this many seconds (default: the end)",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no summary line at the end")
    args = p.parse_args(argv)
    host, _, port = args.to.removeprefix("udp:").rpartition(":")
    if not args.to.startswith("udp:") or not host or not port.isdigit():
        p.error(f"--to must be udp:HOST:PORT, got {args.to!r}")
    args.address = (host, int(port))
    args.camera = int(args.camera) if args.camera.isdigit() else args.camera
    if not args.latency_ms >= 0:
        p.error("--latency-ms must be >= 0")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    times = frame_times_us(args.scenario)
    if not times:
        print(f"{args.scenario}: no frames", file=sys.stderr)
        return 2
    boxes = boxes_by_frame(args.scenario, len(times))
    period_us = (times[-1] - times[0]) / max(len(times) - 1, 1)
    latency_us = round(args.latency_ms * 1000)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    start = monotonic_us()
    stop = None if args.duration is None else start + round(args.duration * 1e6)
    sent = lost = 0
    offset = start - times[0]  # scenario time -> this machine's CLOCK_MONOTONIC
    try:
        while True:
            for k, t in enumerate(times):
                capture = t + offset
                due = capture + latency_us
                wait_s = (due - monotonic_us()) / 1e6
                if wait_s > 0:
                    time.sleep(wait_s)
                if stop is not None and monotonic_us() >= stop:
                    raise StopIteration
                try:
                    sock.sendto(datagram(args.camera, capture, boxes.get(k, [])), args.address)
                    sent += 1
                except OSError:  # nobody listening yet (ICMP port unreachable): go on
                    lost += 1
            if not args.loop:
                break
            offset += times[-1] - times[0] + round(period_us)
    except (StopIteration, KeyboardInterrupt):
        pass
    finally:
        sock.close()
    if not args.quiet:
        print(f"sent {sent} messages to udp:{args.address[0]}:{args.address[1]} ({lost} failed)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
