"""``config.toml`` → frozen dataclasses, with errors that name the file, table and key.

Each TOML table maps onto one dataclass of the core by field name (``[classifier]`` →
:class:`~tcm_companion.core.classify.ClassifierConfig`, …). Unknown keys are errors (a
typo must not silently fall back to a default), values are type-checked against the
field's annotation, and an angle field ``x_rad`` may be given in degrees as ``x_deg``.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .core.pipeline import PipelineConfig
from .mavlink.setup import MavlinkSettings


class ConfigError(ValueError):
    """A configuration value is missing, unknown or of the wrong type."""


@dataclass(frozen=True)
class ReplayConfig:
    # Telemetry received up to this long after a frame's capture time is available when
    # the frame is processed (the daemon waits as long for the attitude after the frame).
    telemetry_wait_us: int = 40_000


@dataclass(frozen=True)
class AppConfig:
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    mavlink: MavlinkSettings = field(default_factory=MavlinkSettings)


def _describe(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _coerce(value: Any, tp: Any, where: str) -> Any:
    """Check ``value`` against annotation ``tp``; convert lists to tuples, ints to floats."""
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        allowed = typing.get_args(tp)
        if value not in allowed:
            raise ConfigError(f"{where} must be one of {list(allowed)}, got {value!r}")
        return value
    if origin in (typing.Union, types.UnionType):
        errors = []
        for arm in typing.get_args(tp):
            if arm is type(None):
                continue
            try:
                return _coerce(value, arm, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{where}: bad value {value!r}")
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where} must be a list, got {value!r}")
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if len(args) != len(value):
            raise ConfigError(f"{where} must have {len(args)} items, got {len(value)}")
        return tuple(_coerce(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where} must be true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where} must be an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where} must be a number, got {value!r}")
        if not math.isfinite(float(value)):
            raise ConfigError(f"{where} must be finite, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where} must be a string, got {value!r}")
        return value
    return value


def build_dataclass(cls: type, table: Any, where: str) -> Any:
    """Instantiate dataclass ``cls`` from a TOML table, defaults for absent keys."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where} must be a table")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        name, val = key, value
        if key not in fields and key.endswith("_deg") and f"{key[:-4]}_rad" in fields:
            name = f"{key[:-4]}_rad"
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ConfigError(f"{where}.{key} must be a number of degrees, got {value!r}")
            val = math.radians(value)
        if name not in fields:
            known = ", ".join(sorted(fields))
            raise ConfigError(f"{where}: unknown key {key!r} (known keys: {known})")
        if name in kwargs:
            raise ConfigError(f"{where}: {name} given twice (as _rad and _deg)")
        tp = hints[name]
        if dataclasses.is_dataclass(tp):
            kwargs[name] = build_dataclass(tp, val, f"{where}.{key}")  # type: ignore[arg-type]
        else:
            kwargs[name] = _coerce(val, tp, f"{where}.{key}")
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _pipeline_table(doc: dict[str, Any]) -> dict[str, Any]:
    """The flat TOML layout ([pipeline] plus one table per stage) as one nested table."""
    table = dict(doc.get("pipeline", {}))
    stage_names = [
        f.name for f in dataclasses.fields(PipelineConfig) if f.name != "egomotion_source"
    ]
    for name in stage_names:
        if name in doc:
            if name in table:
                raise ConfigError(f"[{name}] given both as a table and inside [pipeline]")
            table[name] = doc[name]
    return table


def load_config(path: str | Path | None) -> AppConfig:
    """Read ``config.toml`` (``None``: built-in defaults)."""
    if path is None:
        return AppConfig()
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: {exc}") from None
    return config_from_dict(doc, str(p))


def config_from_dict(doc: dict[str, Any], where: str = "config") -> AppConfig:
    known = {"pipeline", "replay", "mavlink"} | {f.name for f in dataclasses.fields(PipelineConfig)}
    for key in doc:
        if key not in known:
            raise ConfigError(f"{where}: unknown table [{key}] (known: {', '.join(sorted(known))})")
    try:
        pipeline = build_dataclass(PipelineConfig, _pipeline_table(doc), f"{where}: [pipeline]")
        replay = build_dataclass(ReplayConfig, doc.get("replay", {}), f"{where}: [replay]")
        mavlink = build_dataclass(MavlinkSettings, doc.get("mavlink", {}), f"{where}: [mavlink]")
    except ConfigError as exc:
        msg = str(exc)
        # Report stage keys under their own table name, as the user wrote them.
        for name in (f.name for f in dataclasses.fields(PipelineConfig)):
            msg = msg.replace(f"[pipeline].{name}.", f"[{name}] ").replace(
                f"[pipeline].{name}:", f"[{name}]:"
            )
        raise ConfigError(msg) from None
    return AppConfig(pipeline=pipeline, replay=replay, mavlink=mavlink)
