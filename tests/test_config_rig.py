"""A rig of several cameras in the configuration: ``[[cameras]]`` (issue 26)."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path
from typing import Any

import pytest

from tcm_companion.config import (
    MAX_CAMERAS,
    AppConfig,
    CameraConfig,
    ConfigError,
    config_from_dict,
    config_to_toml,
    load_config,
)

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


def rig_doc(*names: str, **extra: Any) -> dict[str, Any]:
    """``[[cameras]]`` of pinholes named ``names``, yawed 90° apart."""
    return {
        "cameras": [
            {"name": n, **PINHOLE, "mount_rpy_deg": [0.0, 0.0, 90.0 * i], **extra}
            for i, n in enumerate(names)
        ]
    }


def test_cameras_are_read_in_order_and_camera_is_the_first() -> None:
    cfg = config_from_dict(rig_doc("front", "right", "rear"))
    assert [c.name for c in cfg.cameras] == ["front", "right", "rear"]
    assert cfg.camera is cfg.cameras[0]
    assert [c.model.model_name for c in cfg.cameras] == ["pinhole"] * 3
    yaws = [c.model.R_body_from_cam for c in cfg.cameras]
    assert not (yaws[0] == yaws[1]).all()  # each camera its own mount


def test_a_lone_camera_table_is_a_rig_of_one() -> None:
    cfg = config_from_dict({"camera": {"name": "nose", **PINHOLE}})
    assert len(cfg.cameras) == 1 and cfg.camera.name == "nose"
    assert AppConfig().cameras == (CameraConfig(),)


def test_camera_is_read_only() -> None:
    cfg = AppConfig()
    with pytest.raises(AttributeError):
        cfg.camera = CameraConfig()  # type: ignore[misc]
    with pytest.raises(TypeError):
        dataclasses.replace(cfg, camera=CameraConfig())  # type: ignore[call-arg]


def test_with_camera_replaces_one_camera() -> None:
    cfg = config_from_dict(rig_doc("front", "back"))
    changed = cfg.with_camera(dataclasses.replace(cfg.cameras[1], name="aft"), 1)
    assert [c.name for c in changed.cameras] == ["front", "aft"]
    with pytest.raises(ValueError, match="'front' given twice"):
        cfg.with_camera(dataclasses.replace(cfg.cameras[1], name="front"), 1)


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        (
            {"cameras": [{**PINHOLE}, {"name": "b", **PINHOLE}]},
            r"^c\.toml: \[cameras\[0\]\] name is required",
        ),
        (
            rig_doc("front", "back", "front"),
            r"^c\.toml: \[\[cameras\]\] name = 'front' given twice \(cameras 0 and 2\)",
        ),
        (
            {"camera": {}, **rig_doc("a", "b")},
            r"^c\.toml: both \[camera\] and \[\[cameras\]\] given",
        ),
        (
            rig_doc(*(f"c{i}" for i in range(MAX_CAMERAS + 1))),
            rf"^c\.toml: \[\[cameras\]\]: 1 to {MAX_CAMERAS} cameras, got {MAX_CAMERAS + 1}",
        ),
        ({"cameras": []}, r"1 to 16 cameras, got 0"),
        ({"cameras": [1, 2]}, r"cameras must be an array of tables"),
        (
            {"cameras": [{"name": "a", **PINHOLE}, {"name": "b", **PINHOLE, "fx": 1e-9}]},
            r"^c\.toml: \[cameras\.b\] fx = 1e-09 is out of range: must be in \[1, 100000\] px",
        ),
        (
            {"cameras": [{"name": "a", **PINHOLE, "fps": 0}, {"name": "b", **PINHOLE}]},
            r"^c\.toml: \[cameras\.a\] fps = 0 is out of range",
        ),
        (
            {"cameras": [{"name": "a", **PINHOLE}, {"name": "b", "zoom": 2}]},
            r"^c\.toml: \[cameras\.b\]: unknown key 'zoom'",
        ),
        (
            {"cameras": [{"name": "a", **PINHOLE}, {"name": "b", **PINHOLE, "cx": 9000}]},
            r"^c\.toml: \[cameras\.b\] cx = 9000 is out of range: must be in \[0, width = 640\]",
        ),
        (
            {"cameras": [{"name": 3, **PINHOLE}, {"name": "b", **PINHOLE}]},
            r"^c\.toml: \[cameras\[0\]\] name must be a non-empty string, got 3",
        ),
    ],
)
def test_rig_errors_name_the_camera_and_key(doc: dict[str, Any], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        config_from_dict(doc, "c.toml")


def test_every_cameras_errors_are_reported_together() -> None:
    doc = {"cameras": [{"name": "a", **PINHOLE, "fx": 0.0}, {"name": "b", **PINHOLE, "fy": 0}]}
    with pytest.raises(ConfigError) as info:
        config_from_dict(doc, "c.toml")
    lines = str(info.value).splitlines()
    assert len(lines) == 2 and "[cameras.a] fx" in lines[0] and "[cameras.b] fy" in lines[1]


@pytest.mark.parametrize("n", [1, 2, 4])
def test_config_to_toml_writes_a_rig_as_cameras_and_one_as_camera(n: int) -> None:
    cfg = config_from_dict(rig_doc(*(f"c{i}" for i in range(n))))
    text = config_to_toml(cfg)
    doc = tomllib.loads(text)
    if n == 1:
        assert "camera" in doc and "cameras" not in doc and "[[cameras]]" not in text
    else:
        assert "camera" not in doc and text.count("[[cameras]]") == n
    assert config_from_dict(doc) == cfg


def _write(tmp_path: Path, doc_text: str) -> Path:
    path = tmp_path / "rig.toml"
    path.write_text(doc_text)
    return path


RIG_TOML = """
[[cameras]]
name = "Front"
fps = 20.0

[[cameras]]
name = "back"
fps = 30.0
"""


def test_set_reaches_one_camera_of_the_rig_by_name(tmp_path: Path) -> None:
    path = _write(tmp_path, RIG_TOML)
    cfg = load_config(path, sets=["cameras.back.fps=10", "cameras.Front.fx=300"])
    assert [c.source.fps for c in cfg.cameras] == [20.0, 10.0]
    # the environment's names are upper case: matched whatever the case
    cfg = load_config(path, environ={"TCM_COMPANION__CAMERAS__FRONT__FPS": "5"})
    assert [c.source.fps for c in cfg.cameras] == [5.0, 30.0]


def test_a_bad_override_of_a_rig_camera_names_what_set_it(tmp_path: Path) -> None:
    path = _write(tmp_path, RIG_TOML)
    with pytest.raises(ConfigError, match=r"\[cameras\.back\] fps = 0 .*\(set by --set cameras"):
        load_config(path, sets=["cameras.back.fps=0"])
    with pytest.raises(ConfigError, match=r"\(set by environment TCM_COMPANION__CAMERAS__FRONT"):
        load_config(path, environ={"TCM_COMPANION__CAMERAS__FRONT__FPS": "-1"})


@pytest.mark.parametrize(
    ("sets", "match"),
    [
        (["cameras.left.fps=10"], r"no camera named 'left' in \[\[cameras\]\] \(Front, back\)"),
        (["camera.fps=10"], r"a rig of \[\[cameras\]\] \(Front, back\).*cameras\.NAME\.fps"),
        (["cameras.back=1"], r"expected cameras\.NAME\.KEY"),
    ],
)
def test_overrides_that_miss_the_rig_are_refused(
    tmp_path: Path, sets: list[str], match: str
) -> None:
    with pytest.raises(ConfigError, match=match):
        load_config(_write(tmp_path, RIG_TOML), sets=sets)


def test_cameras_override_of_a_one_camera_config_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"this configuration has none \(one camera: set"):
        load_config(None, sets=["cameras.front.fps=10"])
    assert load_config(None, sets=["camera.fps=10"]).camera.source.fps == 10.0


def test_box_tracking_camera_counts_the_rigs_cameras() -> None:
    daemon = {"box_tracking": True, "box_tracking_camera": 1}
    detection = {"backend": "boxes"}
    cfg = config_from_dict({"daemon": daemon, "detection": detection, **rig_doc("a", "b")})
    assert cfg.daemon.box_tracking_camera == 1
    with pytest.raises(ConfigError, match=r"box_tracking_camera = 1 is not a camera"):
        config_from_dict({"daemon": daemon, "detection": detection})
