"""``tcm-companion config check FILE``: validate a configuration and print the effective
settings, after the rig it describes (each camera and what of the horizon it sees)."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

from .common import add_command, add_set_argument, config_from_args

if TYPE_CHECKING:
    from ..config import AppConfig


def rig_text(config: AppConfig) -> list[str]:
    """The rig as ``config check`` prints it (TOML comments): each camera's name, lens,
    size, mount and field of view at the horizon, where cameras overlap at the horizon
    and what of it no camera sees (:func:`~tcm_companion.core.rig_geometry.horizon_coverage`)."""
    from ..core.rig_geometry import horizon_coverage

    cams = config.cameras
    cov = horizon_coverage([c.model for c in cams])
    n = len(cams)
    lines = [f"# Rig: {n} camera{'s' if n > 1 else ''} (id name: lens, mount, horizon)"]
    for i, c in enumerate(cams):
        m = c.model
        rpy = "/".join(f"{a:g}°" for a in m.mount_rpy_deg)
        seen = ", ".join(a.text(width=False) for a in cov.camera_arcs(i))
        lines.append(
            f"#   {i} {c.name}: {m.model_name} {m.width}x{m.height}, mount roll/pitch/yaw"
            f" {rpy}, horizontal FOV at the horizon {cov.fov_deg(i):g}°"
            + (f" ({seen})" if seen else "")
        )
    overlaps = cov.overlaps()
    if n > 1:
        lines.append("# Overlaps at the horizon (body azimuth, clockwise from the nose):")
        lines += [
            f"#   {cams[i].name} + {cams[j].name}: {', '.join(a.text() for a in arcs)}"
            for i, j, arcs in overlaps
        ] or ["#   none"]
    gaps = cov.gaps()
    unseen = f"{', '.join(a.text() for a in gaps)}: {cov.unseen_deg:g}° in all" if gaps else "none"
    lines.append(f"# Unseen at the horizon: {unseen}")
    return lines


def cmd_config_check(args: argparse.Namespace) -> int:
    from ..config import config_to_toml, rig_source_problems

    config = config_from_args(args)  # a ConfigError is reported by main: exit 2
    print(f"# {args.config}: OK. Effective configuration (CLI > environment > file > defaults):")
    for line in rig_text(config):
        print(line)
    # Loadable, but not a rig `run` can open (a simulated rig is sitl's).
    for problem in rig_source_problems(config, args.config):
        print(f"warning: run would refuse it: {problem}", file=sys.stderr)
    print(config_to_toml(config))
    return 0


def add_parsers(sub: Any) -> None:
    """Register ``config check`` on the main parser's subparsers."""
    p = add_command(sub, "config", "Configuration tools: config check FILE.")
    csub = p.add_subparsers(dest="config_command", required=True, metavar="COMMAND", help="check")
    c = add_command(
        csub,
        "check",
        help="validate a config file and print the effective settings",
        description="Validate a config file with the environment (TCM_COMPANION__TABLE__KEY) and --set"
        " applied, and print the effective configuration as TOML. Errors name the file, table"
        " and key, and the variable or flag that set a bad value (exit 2).",
    )
    c.add_argument("config", metavar="FILE", help="the config.toml to check")
    add_set_argument(c)
    c.set_defaults(func=cmd_config_check)
