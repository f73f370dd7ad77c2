"""Every numeric setting has a valid range (config.RANGES), checked at load whatever set
the value, and the error names the file (or variable, or flag), the table and only the
key at fault."""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
import tomllib
import types
import typing
from pathlib import Path
from typing import Any

import pytest

from tcm_companion.config import (
    RANGES,
    AppConfig,
    ConfigError,
    PerItem,
    Range,
    config_from_dict,
    config_to_toml,
    load_config,
)
from tcm_companion.core.camera import CameraModel, CameraModelError, camera_from_dict

ROOT = Path(__file__).resolve().parents[1]


def range_of(table: str, key: str) -> tuple[str, bool] | None:
    """The :data:`RANGES` key of ``key`` written in ``[table]``, and whether it was
    written in degrees for a field in radians."""
    if f"{table}.{key}" in RANGES:
        return f"{table}.{key}", False
    if key.endswith("_deg") and f"{table}.{key[:-4]}_rad" in RANGES:
        return f"{table}.{key[:-4]}_rad", True
    return None


def describe_range(key: str) -> str | None:
    """The valid range of setting ``"table.key"`` as config.toml states it
    (``"classifier.min_theta_deg"`` -> ``"[0, 90) deg"``); None for a key without one."""
    table, _, name = key.rpartition(".")
    found = range_of(table.removeprefix("pipeline."), name)
    if found is None:
        return None
    spec = RANGES[found[0]]
    return spec.text() if isinstance(spec, PerItem) else spec.text(deg=found[1])


def test_shipped_config_states_each_settings_range() -> None:
    """The comment of every numeric setting in config.toml (its line, and the indented
    comment lines under it) states the range that the loader checks (config.RANGES)."""
    table, checked, lines = "", [], (ROOT / "config.toml").read_text(encoding="utf-8").splitlines()
    for i, line in enumerate(lines):
        if m := re.match(r"\[([a-z_.]+)\]\s*$", line):
            table = m[1]
            continue
        m = re.match(r"([a-z_0-9]+)\s*=\s*(.*)$", line)
        if not m:
            continue
        key = f"{table}.{m[1]}"
        value = tomllib.loads(line)[m[1]]
        numeric = not isinstance(value, str | bool) and (
            not isinstance(value, list) or all(not isinstance(v, str | bool) for v in value)
        )
        expected = describe_range(key)
        if not numeric:
            assert expected is None, key
            continue
        assert expected is not None, f"{key}: no range in config.RANGES"
        comment = line.partition("#")[2]
        for more in lines[i + 1 :]:
            if not re.match(r"\s+#", more):
                break
            comment += " " + more.partition("#")[2].strip()
        assert expected in comment, f"config.toml {key}: the comment should state {expected}"
        checked.append(key)
    assert "classifier.tcm_threshold" in checked and "camera.front.cx" in checked


PINHOLE: dict[str, Any] = {
    "model": "pinhole",
    "width": 640,
    "height": 480,
    "fx": 320.0,
    "fy": 320.0,
    "cx": 320.0,
    "cy": 240.0,
    "dist": [0.0, 0.0, 0.0, 0.0, 0.0],
}
LENS_KEYS = {"fx", "fy", "cx", "cy", "dist"}


# -- every numeric field has a range -----------------------------------------------------
def _numeric(tp: Any) -> bool:
    if tp in (int, float):  # not bool
        return True
    if typing.get_origin(tp) is tuple:
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        return bool(args) and all(_numeric(a) for a in args)
    if typing.get_origin(tp) in (typing.Union, types.UnionType):  # float | None: optional
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return bool(args) and all(_numeric(a) for a in args)
    return False


def _concrete(cls: type) -> list[type]:
    """``cls`` and its subclasses that can be built (the camera models)."""
    found = [] if inspect.isabstract(cls) else [cls]
    sub: type
    for sub in cls.__subclasses__():
        found += _concrete(sub)
    return found


def _numeric_keys(cls: type, prefix: str) -> set[str]:
    """The numeric fields of dataclass ``cls`` as ``prefix.key`` (nested ones dotted),
    the camera model's under every concrete model."""
    hints = typing.get_type_hints(cls)
    keys: set[str] = set()
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        tp = hints[f.name]
        key = f"{prefix}.{f.name}" if prefix else f.name
        if isinstance(tp, type) and issubclass(tp, CameraModel):
            for model in _concrete(tp):  # [camera] holds the model's keys
                keys |= _numeric_keys(model, prefix)
        elif dataclasses.is_dataclass(tp):
            assert isinstance(tp, type)
            keys |= _numeric_keys(tp, key)
        elif _numeric(tp):
            keys.add(key)
        elif typing.get_origin(tp) is tuple and any(
            dataclasses.is_dataclass(a) for a in typing.get_args(tp)
        ):  # an array of tables, [[table.key]]
            (item,) = (a for a in typing.get_args(tp) if a is not Ellipsis)
            keys |= _numeric_keys(item, key)
    return keys


def reachable_numeric_keys() -> set[str]:
    """Every numeric setting reachable from AppConfig, keyed as config.toml writes it:
    the pipeline's stages are tables of their own, [camera] (and each [[cameras]]) holds
    the lens model's and the source's keys, [camera.front] and [camera.back] their own."""
    hints = typing.get_type_hints(AppConfig)
    keys: set[str] = set()
    for f in dataclasses.fields(AppConfig):
        tp = hints[f.name]
        if f.name == "pipeline":
            keys |= _numeric_keys(tp, "")
        elif f.name == "cameras":  # tuple[CameraConfig, ...]: each camera's keys
            (tp,) = {a for a in typing.get_args(tp) if a is not Ellipsis}
            camera_hints = typing.get_type_hints(tp)
            for cf in dataclasses.fields(tp):
                sub = camera_hints[cf.name]
                if isinstance(sub, type) and issubclass(sub, CameraModel):
                    for model in _concrete(sub):
                        keys |= _numeric_keys(model, "camera")
                elif dataclasses.is_dataclass(sub):
                    assert isinstance(sub, type)
                    keys |= _numeric_keys(sub, "camera")
                elif _numeric(sub):
                    keys.add(f"camera.{cf.name}")
        else:
            keys |= _numeric_keys(tp, f.name)
    return keys


def test_every_numeric_field_has_a_range_and_every_range_a_field() -> None:
    keys = reachable_numeric_keys()
    # The walk reaches every kind of table (not vacuous).
    assert {
        "classifier.tcm_threshold",
        "classifier.min_theta_rad",
        "camera.fx",
        "camera.cx",
        "camera.azimuth_min_deg",
        "camera.fps",
        "camera.front.fx",
        "camera.back.cy",
        "mavlink.endpoint.attitude_rate_hz",
        "mavlink.signing_link_id",
        "daemon.attitude_wait_max_us",
        "sim.telemetry_noise",
        "logging.jpeg_quality",
    } <= keys
    assert "replay.telemetry_wait_us" not in keys  # deprecated: [daemon] attitude_wait_max_us
    assert sorted(keys - set(RANGES)) == [], "numeric settings without a range in RANGES"
    assert sorted(set(RANGES) - keys) == [], "RANGES entries of no setting"


def test_every_default_is_in_range() -> None:
    """The effective configuration of the defaults (every field, as `config check`
    prints it) loads back: no default is outside its own range."""
    assert config_from_dict(tomllib.loads(config_to_toml(AppConfig()))) == AppConfig()


@pytest.mark.parametrize("key", sorted(k for k, v in RANGES.items() if isinstance(v, Range)))
def test_a_range_reads_back_from_its_text(key: str) -> None:
    spec = RANGES[key]
    assert isinstance(spec, Range)
    assert Range.parse(spec.text()) == spec


# -- the issue's examples ------------------------------------------------------------------
@pytest.mark.parametrize(
    ("doc", "message"),
    [
        (
            {"classifier": {"tcm_threshold": -0.5}},
            "[classifier] tcm_threshold = -0.5 is out of range: must be in [0, 2] (dimensionless)",
        ),
        (
            {"classifier": {"interval_s": 0}},
            "[classifier] interval_s = 0 is out of range: must be in (0, 10] s",
        ),
        (
            {"classifier": {"min_theta_rad": 10}},
            "[classifier] min_theta_rad = 10 is out of range: must be in [0, π/2) rad",
        ),
        (  # degrees are checked after conversion and reported in degrees
            {"classifier": {"min_theta_deg": 573}},
            "[classifier] min_theta_deg = 573 is out of range: must be in [0, 90) deg",
        ),
        (
            {"camera": {**PINHOLE, "fx": 1e-9}},
            "[camera] fx = 1e-09 is out of range: must be in [1, 100000] px",
        ),
        (
            {"camera": {**PINHOLE, "cx": -5000}},
            "[camera] cx = -5000 is out of range: must be in [0, width = 640] px",
        ),
        (
            {"camera": {"front": {"cy": 700.0}}},
            "[camera.front] cy = 700 is out of range: must be in [0, height = 640] px",
        ),
        (  # a cross-field bound checks the default too: the message names cx
            {"camera": {"back": {"width": 100}}},
            "[camera.back] cx = 320 (default) is out of range: must be in [0, width = 100] px",
        ),
        (
            {"mavlink": {"endpoint": {"attitude_rate_hz": 0.0}}},
            "[mavlink.endpoint] attitude_rate_hz = 0 is out of range: must be in (0, 500] Hz",
        ),
        (
            {"camera": {"exposure": -2}},
            "[camera] exposure = -2 is out of range: must be -1 or in (0, 100000] × 100 µs",
        ),
        (
            {"detection": {"seed_hue_deg": [-15.0, 120.0]}},
            "[detection] seed_hue_deg[1] = 120 is out of range: must be in [-90, 90] deg",
        ),
        (
            {"camera": {"sim_static_balls": [[0.0, 0.0, -1.0, 0.5], [0.0, 0.0, -1.0, 20.0]]}},
            "[camera] sim_static_balls[1][3] (radius_m) = 20 is out of range: must be in (0, 10] m",
        ),
    ],
)
def test_out_of_range_is_refused_naming_file_table_and_key(
    doc: dict[str, Any], message: str, tmp_path: Path
) -> None:
    import tomli_w

    path = tmp_path / "config.toml"
    path.write_text(tomli_w.dumps(doc))
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value) == f"{path}: {message}"


@pytest.mark.parametrize(
    ("bad", "others"),
    [
        ({"fx": 1e-9}, ["fy", "cx", "cy", "dist", "width", "height"]),
        ({"fy": 0.5}, ["fx", "cx", "cy", "dist", "width", "height"]),
        ({"cx": -5000.0}, ["fx", "fy", "cy", "dist", "height"]),
        ({"cy": 481.0}, ["fx", "fy", "cx", "dist", "width"]),
        ({"dist": [0.0, 0.0, 0.0, 0.0, 1e3]}, ["fx", "fy", "cx", "cy", "width", "height"]),
    ],
)
def test_messages_name_only_the_bad_key(bad: dict[str, Any], others: list[str]) -> None:
    with pytest.raises(ConfigError) as err:
        config_from_dict({"camera": {**PINHOLE, **bad}}, "c.toml")
    msg = str(err.value)
    (key,) = bad
    assert msg.startswith(f"c.toml: [camera] {key}")
    for other in others:
        assert not re.search(rf"\b{other}\b", msg), msg


@pytest.mark.parametrize(
    ("change", "key", "other"),
    [
        ({"fx": -1.0}, "fx", "fy"),
        ({"fy": 0.0}, "fy", "fx"),
    ],
)
def test_the_lens_model_names_only_the_bad_focal_length(
    change: dict[str, float], key: str, other: str
) -> None:
    """camera_from_dict (scenario files, logs) said "fx and fy must be positive"."""
    with pytest.raises(CameraModelError) as err:
        camera_from_dict({**PINHOLE, **change}, where="scenario.toml: camera")
    msg = str(err.value)
    assert msg.startswith(f"scenario.toml: camera.{key} = {change[key]} is out of range")
    assert other not in msg


@pytest.mark.parametrize(
    "doc",
    [
        {"camera": {"model": "pinhole", "width": 640}},
        {"camera": {**PINHOLE, "fx": 0.0}},
        {"camera": {**PINHOLE, "dist": [0.0]}},
        {"camera": {"azimuth_min_deg": 10.0, "azimuth_max_deg": 0.0}},
        {"camera": {"azimuth_min_deg": -200.0, "azimuth_max_deg": 200.0}},
        {"camera": {"elevation_min_deg": 10.0, "elevation_max_deg": 0.0}},
        {"camera": {"source": "file"}},
        {"camera": {"source": "dual_fisheye", "back": {"device": "0"}}},
        {"camera": {"front": {"device": ""}}},
        {"camera": {"name": ""}},
        {"camera": {"fps": 0}},
        {"classifier": {"hold_s": -1.0}},
        {"ttc": {"min_span_s": 1.0}},
        {"sim": {"scenario": "NOPE"}},
    ],
)
def test_the_file_is_named_once(doc: dict[str, Any], tmp_path: Path) -> None:
    import tomli_w

    path = tmp_path / "camera.toml"  # a name that contains "camera."
    path.write_text(tomli_w.dumps(doc))
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ") and msg.count(str(path)) == 1, msg
    assert msg.count("camera.toml") == 1, msg


def test_the_dual_fisheye_pair_is_reported_under_its_own_table() -> None:
    with pytest.raises(ConfigError, match=r"^c\.toml: \[camera\.back\] device must differ"):
        config_from_dict({"camera": {"source": "dual_fisheye", "back": {"device": "0"}}}, "c.toml")


# -- every source of a value gets the same check --------------------------------------------
@pytest.mark.parametrize("how", ["file", "environment", "--set"])
def test_every_source_is_checked_and_named(how: str, tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text("[classifier]\ntcm_threshold = 0.1\n")
    environ, sets = {}, []
    if how == "file":
        path.write_text("[classifier]\ntcm_threshold = -0.5\n")
    elif how == "environment":
        environ = {"TCM_COMPANION__CLASSIFIER__TCM_THRESHOLD": "-0.5"}
    else:
        sets = ["classifier.tcm_threshold=-0.5"]
    with pytest.raises(ConfigError) as err:
        load_config(path, environ=environ, sets=sets)
    head = f"{path}: [classifier] tcm_threshold = -0.5 is out of range: must be in [0, 2]"
    assert str(err.value).startswith(head)
    assert str(err.value).endswith(
        {
            "file": "(dimensionless)",
            "environment": "(set by environment TCM_COMPANION__CLASSIFIER__TCM_THRESHOLD)",
            "--set": "(set by --set classifier.tcm_threshold)",
        }[how]
    )


def test_an_override_in_radians_replaces_the_files_degrees() -> None:
    """config.toml writes min_theta_deg; --set min_theta_rad replaces it (it was refused as
    "given twice"), and is range-checked like any value."""
    cfg = load_config(ROOT / "config.toml", sets=["classifier.min_theta_rad=0.5"])
    assert cfg.pipeline.classifier.min_theta_rad == 0.5
    with pytest.raises(ConfigError, match=r"\[classifier\] min_theta_rad = 10 is out of range"):
        load_config(ROOT / "config.toml", sets=["classifier.min_theta_rad=10"])
    cfg = load_config(
        ROOT / "config.toml", environ={"TCM_COMPANION__CLASSIFIER__MIN_THETA_DEG": "20"}
    )
    assert cfg.pipeline.classifier.min_theta_rad == pytest.approx(math.radians(20.0))


# -- each bound ------------------------------------------------------------------------------
#: Arrays of tables: a bound is tried in a one-table array.
TABLE_LISTS = {"detection.targets"}


def _defaults() -> dict[str, Any]:
    """Every default, tables as config.toml writes them (the pipeline's stages on top)."""
    doc = tomllib.loads(config_to_toml(AppConfig()))
    return {**doc, **{k: v for k, v in doc["pipeline"].items() if isinstance(v, dict)}}


def _default(key: str) -> Any:
    """The default of ``key`` (the lens keys: of a 640x480 pinhole; a colour target's: the
    flat [detection] keys'), None when there is none."""
    parts = key.split(".")
    if parts[0] == "camera" and len(parts) == 2 and parts[1] in LENS_KEYS:
        return PINHOLE[parts[1]]
    table = parts[:-1]
    if ".".join(table) in TABLE_LISTS:
        table = table[:-1]
    node: Any = _defaults()
    for p in [*table, parts[-1]]:
        node = node.get(p) if isinstance(node, dict) else None
    return node


def _doc(key: str, position: int | None, value: float) -> dict[str, Any]:
    """A document setting ``key`` (one ``position`` of a list) to ``value``, other keys
    at their defaults; the lens keys on a 640x480 pinhole."""
    parts = key.split(".")
    doc: dict[str, Any] = {}
    if parts[0] == "camera" and len(parts) == 2 and parts[1] in LENS_KEYS:
        doc["camera"] = dict(PINHOLE)
    node = doc
    for i, p in enumerate(parts[:-1]):
        if ".".join(parts[: i + 1]) in TABLE_LISTS:
            node[p] = [{}]
            node = node[p][0]
        else:
            node = node.setdefault(p, {})
    name, default = parts[-1], _default(key)
    if position is None:
        node[name] = int(value) if isinstance(default, int) else value
    elif key == "camera.sim_static_balls":
        ball = [0.0, 0.0, -1.0, 0.5]
        ball[position] = value
        node[name] = [ball]
    else:
        spec = RANGES.get(key)
        if not default and isinstance(spec, PerItem):  # empty by default (a colour's lab)
            default = [0.0] * len(spec.items)
        items = list(default) if default else [value]
        items[position] = int(value) if isinstance(items[position], int) else value
        node[name] = items
    return doc


def _hi_of(key: str, spec: Range) -> float | None:
    if not spec.hi_key:
        return spec.hi
    table = key.rpartition(".")[0]
    if table == "camera":  # the lens keys are tried on PINHOLE
        return float(PINHOLE[spec.hi_key])
    return float(_default(f"{table}.{spec.hi_key}"))


def _leaf(key: str, position: int | None) -> Any:
    if key == "camera.sim_static_balls":
        return 0.0
    value = _default(key)
    if isinstance(value, list):
        return value[position or 0] if value else 0.0
    return value


def _bound_cases() -> list[Any]:
    cases = []
    for key, spec in sorted(RANGES.items()):
        items = (
            [(j, r) for j, (_, r) in enumerate(spec.items)]
            if isinstance(spec, PerItem)
            else [(0 if isinstance(_default(key), list) else None, spec)]  # a list: its first
        )
        for position, r in items:
            hi = _hi_of(key, r)
            for side, bound, is_open in (("lo", r.lo, r.lo_open), ("hi", hi, r.hi_open)):
                if bound is not None:
                    cases.append(
                        pytest.param(key, position, side, bound, is_open, id=f"{key}-{side}")
                    )
    return cases


@pytest.mark.parametrize(("key", "position", "side", "bound", "is_open"), _bound_cases())
def test_each_bound(key: str, position: int | None, side: str, bound: float, is_open: bool) -> None:
    """A closed bound is accepted and a value just past it refused; an open bound is
    refused and a value just inside it accepted. (A value at a bound may still be refused
    by a relation between fields, e.g. min_span_s below window_s: not a range error.)"""
    written = key.split(".")[-1]
    is_int = isinstance(_leaf(key, position), int)
    step = 1.0 if is_int else max(1e-6, abs(bound) * 1e-6)
    outward = -1.0 if side == "lo" else 1.0

    def refused(value: float) -> None:
        with pytest.raises(ConfigError, match=_out_of_range(written)):
            config_from_dict(_doc(key, position, value), "c.toml")

    if is_open:
        refused(bound)
        _accepted_by_the_range(key, position, bound - outward * step)
    else:
        _accepted_by_the_range(key, position, bound)
        refused(bound + outward * step)


def _out_of_range(written: str) -> str:
    """The message refusing ``written`` (``"[camera] sim_static_balls[0][3] (radius_m) = 20
    is out of range"``); ``written`` at the start of the key, never inside a bound."""
    return rf"\] {written}(\[\d+\])* (\(\w+\) )?= \S+ is out of range"


def _accepted_by_the_range(key: str, position: int | None, value: float) -> None:
    """``value`` passes ``key``'s range; another check may refuse it (a relation between
    fields, or another key's range bound by this one, as cy's by height)."""
    written = key.split(".")[-1]
    try:
        config_from_dict(_doc(key, position, value), "c.toml")
    except ConfigError as exc:
        assert not re.search(_out_of_range(written), str(exc)), str(exc)


@pytest.mark.parametrize(
    ("doc", "ok"),
    [
        ({"classifier": {"tcm_threshold": 0.0}}, True),
        ({"classifier": {"tcm_threshold": 2.0}}, True),
        ({"classifier": {"tcm_threshold": 2.001}}, False),
        ({"classifier": {"interval_s": 10.0}}, True),
        ({"classifier": {"interval_s": 1e-3}}, True),
        ({"classifier": {"min_theta_deg": 0.0}}, True),
        ({"classifier": {"min_theta_deg": 89.9}}, True),
        ({"classifier": {"min_theta_deg": 90.0}}, False),
        ({"classifier": {"min_theta_rad": math.pi / 2}}, False),
        ({"tracking": {"gate_deg": 180.0}}, True),
        ({"tracking": {"gate_deg": 180.001}}, False),
        ({"camera": {**PINHOLE, "fx": 1.0}}, True),
        ({"camera": {**PINHOLE, "fx": 0.999}}, False),
        ({"camera": {**PINHOLE, "cx": 0.0, "cy": 0.0}}, True),
        ({"camera": {**PINHOLE, "cx": 640.0, "cy": 480.0}}, True),
        ({"camera": {**PINHOLE, "cx": 640.5}}, False),
        ({"camera": {"exposure": -1.0}}, True),
        ({"camera": {"exposure": 100_000.0}}, True),
        ({"mavlink": {"endpoint": {"attitude_rate_hz": 500.0}}}, True),
        ({"mavlink": {"endpoint": {"component_id": 255}}}, True),
        ({"mavlink": {"endpoint": {"component_id": 256}}}, False),
    ],
)
def test_the_issues_keys_at_their_bounds(doc: dict[str, Any], ok: bool) -> None:
    if ok:
        config_from_dict(doc)
    else:
        with pytest.raises(ConfigError, match="is out of range"):
            config_from_dict(doc)


def test_describe_range_states_the_unit_the_key_is_written_in() -> None:
    assert describe_range("classifier.tcm_threshold") == "[0, 2]"
    assert describe_range("classifier.min_theta_rad") == "[0, π/2) rad"
    assert describe_range("classifier.min_theta_deg") == "[0, 90) deg"
    assert describe_range("pipeline.classifier.interval_s") == "(0, 10] s"
    assert describe_range("camera.front.cx") == "[0, width] px"
    assert describe_range("camera.exposure") == "-1 or (0, 100000] × 100 µs"
    assert describe_range("mavlink.url") is None
