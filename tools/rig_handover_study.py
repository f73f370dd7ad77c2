"""Issue 26's handover target on the paper's flights: one track id per object across cameras.

The paper's flights keep their object on the vehicle's right (T90's ball 58°-118° right
of the nose), inside the quad rig's ``right`` camera, so ``eval --sim NAME --rig quad``
never hands an object over. This study sees each flight through two 100° pinholes at yaw
45° and 135° (320×240 unless ``--resolution``; a 10° overlap around 90°, which the
objects cross again and again) and scores it as ``eval`` scores a rig
(:func:`tcm_companion.eval.rig.evaluate_rig`: per camera, overall, handover), TCM at the
configured threshold.

Usage: ``python tools/rig_handover_study.py [NAME ...] [--duration S] [--resolution WxH]``
(default TS T45 T90, their own 40 s; ~65 s of CPU a flight at 320×240).
"""

from __future__ import annotations

import argparse
import math
import time

from tcm_companion.config import AppConfig
from tcm_companion.core.camera import CameraModel, Pinhole
from tcm_companion.eval.evaluate import summarize
from tcm_companion.eval.rig import evaluate_rig, handover_text
from tcm_companion.sim.scene.export import make_scenario
from tcm_companion.sim.scene.rig_scenario import SimulatedRig


def side_pair(width: int, height: int) -> list[tuple[str, CameraModel]]:
    """Two level 100° pinholes, ``fwd`` at yaw 45° and ``aft`` at 135°."""
    f = (width / 2) / math.tan(math.radians(50.0))
    return [
        (name, Pinhole(width, height, (0.0, 0.0, yaw), fx=f, fy=f, cx=width / 2, cy=height / 2))
        for name, yaw in (("fwd", 45.0), ("aft", 135.0))
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", default=["TS", "T45", "T90"])
    ap.add_argument("--duration", type=float, default=None)
    ap.add_argument("--resolution", default="320x240")
    args = ap.parse_args()
    w, h = (int(x) for x in args.resolution.split("x"))
    cams = side_pair(w, h)
    cfg = AppConfig()
    cls = cfg.pipeline.classifier
    for name in args.names:
        t = time.process_time()
        rig = SimulatedRig(make_scenario(name, cams[0][1], duration_s=args.duration), cams)
        ev = evaluate_rig(rig, cfg, with_bsm=False)
        for e in [*ev.cameras, ev.overall]:
            tcm = next((s for s in summarize(e.records, cls) if s.method == "tcm"), None)
            acc = tcm.accuracy if tcm else math.nan
            cov = tcm.coverage if tcm else math.nan
            print(
                f"{e.name:<10} object-frames {len(e.records):>5}  TCM {acc:6.1%}  coverage {cov:6.1%}"
            )
        print("\n".join(handover_text([ev])))
        print(f"  ({time.process_time() - t:.0f} s of CPU)", flush=True)


if __name__ == "__main__":
    main()
