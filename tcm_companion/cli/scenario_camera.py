"""``run`` with ``[camera] source = "scenario"``: the recorded frames are the camera, so
the camera model is the one the scenario declares (its ``scenario.toml`` ``[camera]``),
with the configuration's own lens keys replaced (and a conflict named when this run sets
one itself)."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..config import AppConfig

log = logging.getLogger("tcm_companion")


def lens_overrides(sets: list[str], environ: Any) -> dict[str, str]:
    """The ``[camera]`` lens keys this run sets with ``--set`` or the environment, and
    how (``{"width": "--set camera.width"}``)."""
    from ..config import ENV_PREFIX, LENS_KEYS

    out = {}
    for name in environ:
        parts = name.removeprefix(ENV_PREFIX).lower().split("__")
        if name.startswith(ENV_PREFIX) and len(parts) == 2 and parts[0] == "camera":
            if parts[1] in LENS_KEYS:
                out[parts[1]] = f"environment {name}"
    for item in sets:
        table, _, key = item.partition("=")[0].strip().partition(".")
        if table == "camera" and key in LENS_KEYS:
            out[key] = f"--set camera.{key}"
    return out


def camera_from_scenario(config: AppConfig, overrides: dict[str, str]) -> AppConfig:
    """``config`` with the camera model ``[camera] path``'s scenario declares (its
    ``scenario.toml`` ``[camera]``): with ``source = "scenario"`` the recorded frames are
    the camera. The configuration's own lens keys (the drone's camera) are replaced, with
    a warning naming those that differ; a differing key this run sets itself
    (``overrides``: ``--set``, environment) is a conflict, a ValueError naming it."""
    from ..io.scenario import ScenarioError, load_scenario

    path = config.camera.source.path
    if not Path(path).is_dir():
        return config  # the source says "no such directory"
    try:
        declared = load_scenario(path, check_frames=False).camera
    except (ScenarioError, OSError) as exc:
        raise ValueError(f"camera.path: {exc} (camera.source = 'scenario')") from None
    mine, theirs = config.camera.model.to_dict(), declared.to_dict()
    differ = [k for k in {**mine, **theirs} if mine.get(k) != theirs.get(k)]
    what = f"{declared.model_name} {declared.width}x{declared.height}"
    conflicts = [k for k in differ if k in overrides]
    if conflicts:

        def show(d: dict[str, Any], k: str) -> str:
            return repr(d[k]) if k in d else "(none)"

        raise ValueError(
            f"camera.source = 'scenario': scenario {path} declares a {what} camera (its"
            " scenario.toml [camera]), and this run sets "
            + ", ".join(
                f"camera.{k} = {show(mine, k)} ({overrides[k]}; the scenario's: {show(theirs, k)})"
                for k in conflicts
            )
            + ": drop the override to take the scenario's camera"
        )
    if differ:
        from ..config import CameraConfig

        # The built-in default (or the repository's config.toml, which writes it out) is
        # not a camera someone described: replacing it is worth a note, not a warning.
        described = config.camera.model != CameraConfig().model
        log.log(
            logging.WARNING if described else logging.INFO,
            "camera model: scenario %s declares a %s camera; the configuration's [camera]"
            " %s are replaced by the scenario's",
            path,
            what,
            ", ".join(differ),
        )
    else:
        log.info("camera model: scenario %s declares a %s camera", path, what)
    return config.with_camera(dataclasses.replace(config.camera, model=declared))
