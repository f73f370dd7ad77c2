"""``tcm-companion config check FILE``: validate a configuration and print the effective
settings."""

from __future__ import annotations

import argparse
from typing import Any

from .common import add_command, add_set_argument, config_from_args


def cmd_config_check(args: argparse.Namespace) -> int:
    from ..config import config_to_toml

    config = config_from_args(args)  # a ConfigError is reported by main: exit 2
    print(f"# {args.config}: OK. Effective configuration (CLI > environment > file > defaults):")
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
