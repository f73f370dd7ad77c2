"""``config.toml`` → frozen dataclasses, with errors that name the file, table and key.

Each TOML table maps onto one dataclass of the core by field name (``[classifier]`` →
:class:`~tcm_companion.core.classify.ClassifierConfig`, …). Unknown keys are errors (a
typo must not silently fall back to a default), values are type-checked against the
field's annotation, and an angle field ``x_rad`` may be given in degrees as ``x_deg``.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .core.camera import _KEYS, CameraModel, CameraModelError, Equirectangular, camera_from_dict
from .core.pipeline import PipelineConfig
from .flightlog.writer import LoggingConfig
from .io.cameras.settings import CameraSettings
from .service.companion import DaemonConfig
from .service.endpoint_setup import MavlinkSettings


class ConfigError(ValueError):
    """A configuration value is missing, unknown or of the wrong type."""


@dataclass(frozen=True)
class ReplayConfig:
    # Telemetry received up to this long after a frame's capture time is available when
    # the frame is processed (the daemon waits as long for the attitude after the frame).
    telemetry_wait_us: int = 40_000


@dataclass(frozen=True)
class SimConfig:
    """``[sim]``: the simulated vehicle flown by the mock autopilot when the camera source
    is ``"sim"`` (``tcm-companion run`` with the repository's config, and ``sitl``)."""

    scenario: str = "T90"  # TS, T45, T90, RAISED, INPLANE, COLLISION, HEADON, TWO
    seed: int = 0  # turbulence of the flight, telemetry noise, sensor noise
    telemetry_noise: float = 1.0  # scale of the mock's attitude/position noise (0: exact)
    ekf_origin_delay_us: int = 3_000_000  # LOCAL_POSITION_NED starts this long after boot
    brake_on_collision: bool = True  # the mock brakes on a collision-course alarm

    def __post_init__(self) -> None:
        from .sim.scene.names import SCENARIO_NAMES

        if self.scenario.upper() not in SCENARIO_NAMES:
            raise ValueError(
                f"scenario must be one of {', '.join(SCENARIO_NAMES)}, got {self.scenario!r}"
            )
        if self.telemetry_noise < 0 or self.ekf_origin_delay_us < 0:
            raise ValueError("telemetry_noise and ekf_origin_delay_us must be >= 0")


def _default_camera_model() -> CameraModel:
    return Equirectangular(360, 220)


@dataclass(frozen=True)
class CameraConfig:
    """``[camera]``: the lens model the pipeline uses (the keys of a scenario's ``[camera]``:
    ``model``, ``width``, ``height``, ``mount_rpy_deg`` and the model's intrinsics) and
    where its frames come from (:class:`~tcm_companion.io.cameras.settings.CameraSettings`:
    ``source``, ``device``, ``path`` …), in one table."""

    model: CameraModel = field(default_factory=_default_camera_model)
    source: CameraSettings = field(default_factory=CameraSettings)
    name: str = "camera0"


_MODEL_KEYS = {"model", "width", "height", "mount_rpy_deg"} | {
    k for ks in _KEYS.values() for k in ks
}


def camera_config_from_table(table: Any, where: str) -> CameraConfig:
    """Split ``[camera]`` into the lens model and the source settings; check both."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where} must be a table")
    model_keys = {k: v for k, v in table.items() if k in _MODEL_KEYS}
    source_keys = {k: v for k, v in table.items() if k not in _MODEL_KEYS and k != "name"}
    name = table.get("name", "camera0")
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{where}.name must be a non-empty string, got {name!r}")
    if model_keys:
        defaults = {"model": "equirectangular", "width": 360, "height": 220}
        try:
            model = camera_from_dict({**defaults, **model_keys}, where=where)
        except CameraModelError as exc:
            raise ConfigError(str(exc)) from None
    else:
        model = _default_camera_model()
    try:
        source = build_dataclass(CameraSettings, source_keys, where)
    except ConfigError as exc:
        # CameraSettings names its fields "camera.x"; say where they were written.
        raise ConfigError(str(exc).replace(f"{where}: camera.", f"{where}.")) from None
    if source.source == "dual_fisheye" and model.model_name != "equirectangular":
        raise ConfigError(
            f'{where}.model must be "equirectangular" for source = "dual_fisheye" '
            "(the two fisheyes are stitched into a panorama)"
        )
    return CameraConfig(model=model, source=source, name=name)


@dataclass(frozen=True)
class AppConfig:
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    mavlink: MavlinkSettings = field(default_factory=MavlinkSettings)
    daemon: DaemonConfig = field(default_factory=DaemonConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    logging: LoggingConfig = field(default_factory=LoggingConfig)


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


#: Environment variables ``TCM_COMPANION__TABLE__KEY=value`` override the file
#: (e.g. ``TCM_COMPANION__MAVLINK__URL=serial:/dev/ttyAMA0:921600``); CLI ``--set
#: table.key=value`` overrides both. Values are read as TOML (``0.1``, ``true``,
#: ``[1, 2]``, ``"text"``), and as plain text when they are not valid TOML.
ENV_PREFIX = "TCM_COMPANION__"


def _toml_value(text: str) -> Any:
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _set_dotted(doc: dict[str, Any], path: list[str], value: Any, origin: str) -> None:
    node = doc
    for part in path[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"{origin}: {'.'.join(path)}: {part} is not a table")
        node = child
    node[path[-1]] = value


def apply_overrides(
    doc: dict[str, Any],
    environ: typing.Mapping[str, str] | None = None,
    sets: typing.Sequence[str] = (),
) -> dict[str, str]:
    """Apply environment then ``--set`` overrides to ``doc`` in place.

    Returns ``{dotted key: where it was set}`` so that errors can name the variable or
    flag that set a bad value.
    """
    origins: dict[str, str] = {}
    for name, raw in sorted((environ or {}).items()):
        if not name.startswith(ENV_PREFIX):
            continue
        path = [p.lower() for p in name[len(ENV_PREFIX) :].split("__") if p]
        if len(path) < 2:
            raise ConfigError(f"environment {name}: expected {ENV_PREFIX}TABLE__KEY")
        _set_dotted(doc, path, _toml_value(raw), f"environment {name}")
        origins[".".join(path)] = f"environment {name}"
    for item in sets:
        key, eq, raw = item.partition("=")
        path = [p for p in key.strip().split(".") if p]
        if not eq or len(path) < 2:
            raise ConfigError(f"--set {item!r}: expected TABLE.KEY=VALUE")
        _set_dotted(doc, path, _toml_value(raw.strip()), f"--set {item}")
        origins[".".join(path)] = f"--set {key.strip()}"
    return origins


def load_config(
    path: str | Path | None,
    *,
    environ: typing.Mapping[str, str] | None = None,
    sets: typing.Sequence[str] = (),
) -> AppConfig:
    """Read ``config.toml`` (``None``: built-in defaults), then apply overrides.

    Precedence: ``sets`` (CLI) > ``environ`` (``TCM_COMPANION__…``) > file > defaults.
    """
    doc: dict[str, Any] = {}
    where = "config"
    if path is not None:
        p = Path(path)
        where = str(p)
        try:
            with open(p, "rb") as fh:
                doc = tomllib.load(fh)
        except FileNotFoundError:
            raise ConfigError(f"{p}: no such file") from None
        except IsADirectoryError:
            raise ConfigError(f"{p}: is a directory, not a TOML file") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{p}: {exc}") from None
        except UnicodeDecodeError:
            from .io.scenario import not_utf8

            raise ConfigError(f"{p}: {not_utf8(p)}") from None
    origins = apply_overrides(doc, environ, sets)
    try:
        return config_from_dict(doc, where)
    except ConfigError as exc:
        msg = str(exc)
        for key, origin in origins.items():
            table, _, name = key.rpartition(".")
            if f"[{table}]" in msg and re.search(rf"\b{re.escape(name)}\b", msg):
                msg += f" (set by {origin})"
        raise ConfigError(msg) from None


_TABLES = ("pipeline", "replay", "mavlink", "daemon", "sim", "camera", "logging")


def config_from_dict(doc: dict[str, Any], where: str = "config") -> AppConfig:
    known = set(_TABLES) | {f.name for f in dataclasses.fields(PipelineConfig)}
    for key in doc:
        if key not in known:
            raise ConfigError(f"{where}: unknown table [{key}] (known: {', '.join(sorted(known))})")
    try:
        pipeline = build_dataclass(PipelineConfig, _pipeline_table(doc), f"{where}: [pipeline]")
        tables = {
            name: build_dataclass(cls, doc.get(name, {}), f"{where}: [{name}]")
            for name, cls in (
                ("replay", ReplayConfig),
                ("mavlink", MavlinkSettings),
                ("daemon", DaemonConfig),
                ("sim", SimConfig),
                ("logging", LoggingConfig),
            )
        }
        camera = camera_config_from_table(doc.get("camera", {}), f"{where}: [camera]")
    except ConfigError as exc:
        msg = str(exc)
        # Report stage keys under their own table name, as the user wrote them.
        for name in (f.name for f in dataclasses.fields(PipelineConfig)):
            msg = msg.replace(f"[pipeline].{name}.", f"[{name}] ").replace(
                f"[pipeline].{name}:", f"[{name}]:"
            )
        raise ConfigError(msg) from None
    return AppConfig(pipeline=pipeline, camera=camera, **tables)


def _plain(value: Any) -> Any:
    """Dataclasses, tuples and camera models as TOML-writable values."""
    if hasattr(value, "to_dict") and callable(value.to_dict):
        return _plain(value.to_dict())
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value) if f.init}
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    return value


def config_to_toml(config: AppConfig) -> str:
    """The configuration in force, as TOML (the camera's model and source in one table)."""
    import tomli_w

    doc = _plain(config)
    cam = doc.pop("camera")
    camera = {"name": cam["name"], **cam["model"], **cam["source"]}
    doc["camera"] = camera
    return tomli_w.dumps(doc)
