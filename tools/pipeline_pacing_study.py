"""Why the pipeline takes longer inside the daemon than in ``tcm-companion bench``.

``bench`` runs frames back to back in one process; the daemon runs one frame every
40 ms while its camera thread decodes the next image. This times the same pipeline (the
default config, T90 at 360×220, one OpenCV thread, the allocator tuned as the CLI
tunes it) in one process under three pacings:

1. back to back, as ``bench`` does;
2. with a 40 ms sleep before each frame, as at 25 Hz (caches and branch predictors go
   cold, the core may clock down or be given to another process);
3. as 2, plus a thread that decodes a PNG of the same size 25 times a second, as the
   daemon's camera thread does with ``[camera] source = "frames"`` (``bench --daemon``).

Run: ``.venv/bin/python tools/pipeline_pacing_study.py [FRAMES]``
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from tcm_companion.bench.pipeline import rendered_frames, time_stages
from tcm_companion.config import AppConfig
from tcm_companion.io.allocator import tune_allocator


class _Decoder:
    """Decodes one PNG every ``period_s`` on a thread (what a frames-dir camera costs)."""

    def __init__(self, image: np.ndarray, period_s: float = 0.04) -> None:
        self.path = Path(tempfile.mkdtemp(prefix="tcm-pacing-")) / "frame.png"
        cv2.imwrite(str(self.path), image)
        self.period_s = period_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            cv2.imread(str(self.path), cv2.IMREAD_COLOR)

    def __enter__(self) -> _Decoder:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.path.unlink()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("frames", nargs="?", type=int, default=300, help="frames per pacing (300)")
    n = ap.parse_args().frames
    tune_allocator()  # as the CLI (and so the daemon) does
    cv2.setNumThreads(1)
    config = AppConfig()
    sim, frames = rendered_frames((360, 220), n)
    time_stages(config, sim, frames[:60])  # warm-up pass (one-off costs)
    print(f"pipeline total, ms per frame ({n} frames of T90, 360x220, default config)")
    print(f"{'pacing':<58} {'p50':>6} {'p90':>6} {'p99':>6}")
    variants = [
        ("back to back (as tcm-companion bench)", 0.0, False),
        ("one frame every 40 ms (25 Hz)", 0.04, False),
        ("every 40 ms + a thread decoding a PNG at 25 Hz", 0.04, True),
    ]
    for name, gap_s, decode in variants:
        t0 = time.monotonic()
        if decode:
            with _Decoder(frames[0][2]):
                t = time_stages(config, sim, frames, gap_s=gap_s)["total"]
        else:
            t = time_stages(config, sim, frames, gap_s=gap_s)["total"]
        p50, p90, p99 = np.percentile(t, [50, 90, 99])
        print(f"{name:<58} {p50:6.2f} {p90:6.2f} {p99:6.2f}   ({time.monotonic() - t0:.0f} s)")


if __name__ == "__main__":
    main()
