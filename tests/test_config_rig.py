"""A rig of several cameras in the configuration: ``[[cameras]]`` (issue 26)."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import tomllib
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import tomli_w

from tcm_companion import cli
from tcm_companion.config import (
    MAX_CAMERAS,
    AppConfig,
    CameraConfig,
    ConfigError,
    config_from_dict,
    config_to_toml,
    load_config,
    rig_source_problems,
)
from tcm_companion.core.camera import Equirectangular, Fisheye, Pinhole
from tcm_companion.core.rig_geometry import Arc, HorizonCoverage, horizon_coverage
from tcm_companion.sim.scene.cameras import rig_cameras

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


# -- where the rig looks: core/rig_geometry.py --------------------------------------------
def _coverage(rig: str) -> tuple[list[str], HorizonCoverage]:
    cams = rig_cameras(rig)
    return [n for n, _ in cams], horizon_coverage([m for _, m in cams])


def test_quad_sees_all_round_with_four_10_degree_overlaps() -> None:
    names, cov = _coverage("quad")
    assert [cov.fov_deg(i) for i in range(4)] == [100.0] * 4
    assert [a.text() for a in cov.camera_arcs(2)] == ["130°..-130° (100°)"]  # the rear, wrapped
    assert cov.gaps() == [] and cov.unseen_deg == 0.0
    pairs = {(names[i], names[j]): arcs for i, j, arcs in cov.overlaps()}
    assert set(pairs) == {
        ("front", "right"),
        ("right", "rear"),
        ("rear", "left"),
        ("front", "left"),
    }
    assert pairs["front", "right"] == [Arc(40.0, 10.0)]
    assert pairs["front", "left"] == [Arc(-50.0, 10.0)]
    assert all(sum(a.width_deg for a in arcs) == 10.0 for arcs in pairs.values())


def test_front_back_leaves_the_sides_unseen() -> None:
    _, cov = _coverage("front-back")
    assert cov.overlaps() == []
    assert [a.text() for a in cov.gaps()] == ["-130°..-50° (80°)", "50°..130° (80°)"]
    assert cov.unseen_deg == 160.0


def test_the_panorama_sees_all_round_alone() -> None:
    _, cov = _coverage("panorama")
    assert cov.fov_deg(0) == 360.0 and cov.gaps() == [] and cov.overlaps() == []
    assert [a.text() for a in cov.camera_arcs(0)] == ["all round (360°)"]


def test_a_pinhole_does_not_see_behind_itself_and_a_fisheye_sees_its_180_degrees() -> None:
    front = Pinhole(320, 240, (0.0, 0.0, 0.0), fx=160.0, fy=160.0, cx=160.0, cy=120.0)
    cov = horizon_coverage([front], step_deg=0.5)
    assert cov.fov_deg(0) == 90.0  # 2·atan(160/160), and nothing of the back half
    fish = Fisheye(640, 640, (0.0, 0.0, 90.0), fx=200.0, fy=200.0, cx=320.0, cy=320.0)
    cov = horizon_coverage([fish])
    # θd = θ·200 px reaches the 320-px edge at θ = 1.6 rad (91.7°): the side half and a bit
    assert cov.fov_deg(0) == pytest.approx(2 * math.degrees(1.6), abs=2.0)
    assert cov.camera_arcs(0)[0].start_deg == pytest.approx(90.0 - math.degrees(1.6), abs=1.0)


def test_a_step_that_does_not_divide_the_circle_is_refused() -> None:
    with pytest.raises(ValueError, match="step_deg must divide 360"):
        horizon_coverage([Equirectangular(360, 220)], step_deg=7.0)


def test_config_check_prints_the_rig(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "quad.toml"
    path.write_text(_rig_toml("quad", source='source = "device"', device=True))
    args = cli.build_parser().parse_args(["config", "check", str(path)])
    assert args.func(args) == 0
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert lines[1] == "# Rig: 4 cameras (id name: lens, mount, horizon)"
    assert lines[3] == (
        "#   1 right: pinhole 320x240, mount roll/pitch/yaw 0°/0°/90°, horizontal FOV at the"
        " horizon 100° (40°..140°)"
    )
    assert "#   front + right: 40°..50° (10°)" in lines
    assert "#   front + left: -50°..-40° (10°)" in lines
    assert lines[11] == "# Unseen at the horizon: none"
    assert not err
    assert load_config(path) == config_from_dict(tomllib.loads(out))  # still TOML


def test_config_check_warns_of_a_rig_run_would_refuse(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    path = tmp_path / "fb.toml"
    path.write_text(_rig_toml("front-back", source=""))  # the default source: "sim"
    args = cli.build_parser().parse_args(["config", "check", str(path)])
    assert args.func(args) == 0
    out, err = capsys.readouterr()
    assert "# Unseen at the horizon: -130°..-50° (80°), 50°..130° (80°): 160° in all" in out
    assert err.splitlines()[0] == (
        f'warning: run would refuse it: {path}: [cameras.front] source = "sim" renders the'
        " one camera of the simulated flight; fly a simulated rig with `tcm-companion sitl"
        " --rig NAME` (one camera: [camera])"
    )


def _rig_toml(rig: str, source: str, device: bool = False, **extra: str) -> str:
    out = []
    for i, (name, m) in enumerate(rig_cameras(rig)):
        table = {"name": name, **m.to_dict()}
        lines = [f"{k} = {json.dumps(v)}" for k, v in table.items()]
        if source:
            lines.append(source)
        if device:
            lines.append(f'device = "/dev/video{i}"')
        lines += [f"{k} = {v}" for k, v in extra.items()]
        out.append("[[cameras]]\n" + "\n".join(lines))
    return "\n\n".join(out) + "\n"


@pytest.mark.parametrize(
    ("cameras", "match"),
    [
        ([{"source": "device"}, {}], r'\[cameras\.b\] source = "sim" renders the one camera'),
        ([{"source": "device"}, {"source": "dual_fisheye"}], r'\[cameras\.b\] source = "dual_f'),
        (
            [{"source": "device", "device": "2"}, {"source": "device", "device": "2"}],
            r"\[cameras\.b\] device = '2' is camera a's too",
        ),
        (
            [{"source": "sim_autopilot"}, {"source": "sim_autopilot"}],
            r"\[cameras\.b\] sim_url = 'tcp:127\.0\.0\.1:5763' is camera a's too",
        ),
    ],
)
def test_sources_a_rig_cannot_run_are_named(cameras: list[dict[str, Any]], match: str) -> None:
    doc = {"cameras": [{"name": n, **c} for n, c in zip("ab", cameras, strict=True)]}
    if any(c.get("source") == "dual_fisheye" for c in cameras):
        doc["cameras"][1]["back"] = {"device": "1"}
    problems = rig_source_problems(config_from_dict(doc), "c.toml")
    assert len(problems) == 1 and re.search(match, str(problems[0])), problems
    one = {"camera": {"name": "a", **cameras[0]}}
    assert rig_source_problems(config_from_dict(one)) == []


# -- run: every camera of the rig -----------------------------------------------------------
def _textured(directory: Path, width: int, height: int, n: int, seed: int) -> Path:
    rng = np.random.default_rng(seed)
    directory.mkdir()
    for k in range(n):
        img = rng.integers(0, 255, (height, width, 3), dtype=np.uint8)
        cv2.imwrite(str(directory / f"{k:06d}.png"), img)
    return directory


@pytest.mark.slow  # the real daemon for 2 s
@pytest.mark.xdist_group("sitl")
def test_run_delivers_frames_from_every_camera_of_the_rig(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = rig_cameras("front-back", resolution=(160, 120))
    cams = []
    for i, ((name, model), fps) in enumerate(zip(rig, (10, 5), strict=True)):
        frames = _textured(tmp_path / name, model.width, model.height, 4, seed=i)
        table = {"name": name, **model.to_dict(), "source": "frames", "path": str(frames)}
        cams.append({**table, "loop": True, "fps": float(fps)})
    config = tmp_path / "rig.toml"
    config.write_text(tomli_w.dumps({"cameras": cams}))
    summary = tmp_path / "summary.json"
    argv = ["run", "--config", str(config), "--duration", "2", "--no-status"]
    argv += ["--summary-json", str(summary), "--log-level", "ERROR"]
    for k, v in {
        "logging.enabled": "false",
        "daemon.state_dir": str(tmp_path / "state"),
        "mavlink.url": "udpout:127.0.0.1:9",  # discard: nobody answers
    }.items():
        argv += ["--set", f"{k}={v}"]
    args = cli.build_parser().parse_args(argv)
    assert args.func(args) == 0
    out = capsys.readouterr().out
    doc = json.loads(summary.read_text())
    by_name = {c["name"]: c for c in doc["cameras"]}
    assert list(by_name) == ["front", "rear"]
    # each camera at its own rate: 10 and 5 fps for 2 s
    assert 14 <= by_name["front"]["delivered"] <= 22, by_name
    assert 6 <= by_name["rear"]["delivered"] <= 12, by_name
    assert all(c["processed"] >= 1 for c in doc["cameras"]), by_name
    assert doc["processed"] == sum(c["processed"] for c in doc["cameras"])
    assert re.search(r"; cameras front \d+/\d+, rear \d+/\d+", out), out


def test_run_refuses_a_rig_it_cannot_open(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "rig.toml"
    config.write_text(_rig_toml("front-back", source='source = "scenario"\npath = "x"'))
    args = cli.build_parser().parse_args(["run", "--config", str(config), "--duration", "1"])
    assert args.func(args) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and err[1].startswith(
        f'error: {config}: [cameras.rear] source = "scenario" plays a one-camera scenario'
    )


def test_the_rig_example_of_config_toml_loads() -> None:
    """config.toml's commented [[cameras]] example, uncommented in place of [camera]."""
    text = (Path(__file__).resolve().parents[1] / "config.toml").read_text(encoding="utf-8")
    lines = text.splitlines()
    start = lines.index("# [[cameras]]")
    example = []
    for line in lines[start:]:
        if not line.startswith("#"):
            break
        example.append(line.removeprefix("#").removeprefix(" "))
    cfg = config_from_dict(tomllib.loads("\n".join(example)))
    assert [c.name for c in cfg.cameras] == ["front", "rear"]
    cov = horizon_coverage([c.model for c in cfg.cameras])
    assert [round(cov.fov_deg(i)) for i in (0, 1)] == [100, 100] and cov.unseen_deg == 160.0
    assert rig_source_problems(cfg) == []
