"""config.toml → dataclasses: the shipped file matches the defaults; errors name keys."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from tcm_companion.config import (
    AppConfig,
    ConfigError,
    config_from_dict,
    config_to_toml,
    load_config,
)

ROOT = Path(__file__).resolve().parents[1]


def test_shipped_config_is_the_builtin_default() -> None:
    assert load_config(ROOT / "config.toml") == AppConfig()


def test_degrees_and_nested_tables() -> None:
    cfg = config_from_dict(
        {"classifier": {"min_theta_deg": 20.0, "extra_intervals_s": [0.48, 1.6]}}
    )
    assert cfg.pipeline.classifier.min_theta_rad == pytest.approx(math.radians(20.0))
    assert cfg.pipeline.classifier.extra_intervals_s == (0.48, 1.6)
    assert cfg.pipeline.classifier.intervals_s == (1.6, 1.0, 0.48)
    cfg = config_from_dict(
        {"pipeline": {"egomotion_source": "vision"}, "detection": {"seed_hue_deg": [-10, 10]}}
    )
    assert cfg.pipeline.egomotion_source == "vision"
    assert cfg.pipeline.detection.seed_hue_deg == (-10.0, 10.0)


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        ({"classifier": {"treshold": 0.1}}, r"\[classifier\]: unknown key 'treshold'"),
        ({"classifier": {"method": "magic"}}, r"\[classifier\] method must be one of"),
        (
            {"classifier": {"interval_s": "long"}},
            r"\[classifier\] interval_s must be a number",
        ),
        (
            {"classifier": {"interval_s": 0}},
            r"\[classifier\] interval_s = 0 is out of range: must be in \(0, 10\] s$",
        ),
        ({"classifier": {"hold_s": -0.1}}, r"\[classifier\] hold_s = -0.1 is out of range"),
        # The frame counts of earlier versions are refused, not misread.
        ({"classifier": {"frame_interval": 25}}, r"\[classifier\]: unknown key 'frame_interval'"),
        ({"ttc": {"window_frames": 12}}, r"\[ttc\]: unknown key 'window_frames'"),
        ({"tracking": {"history_s": 0.0}}, r"\[tracking\] history_s = 0 is out of range"),
        ({"pipeline": {"bsm_enabled": "yes"}}, r"bsm_enabled must be true or false"),
        ({"tracking": {"gate_deg": "wide"}}, r"gate_deg must be a number of degrees"),
        ({"cameras": {}}, r"cameras must be an array of tables \(\[\[cameras\]\]"),
        ({"camras": {}}, r"unknown table \[camras\]"),
        ({"camera": {"source": "webcam"}}, r"\[camera\] source must be one of"),
        ({"camera": {"model": "pinhole", "width": 640}}, r"\[camera\] fx is required"),
        ({"camera": {"width": -3}}, r"\[camera\] width = -3 is out of range"),
        ({"camera": {"width": 640.5}}, r"\[camera\] width must be a positive integer"),
        ({"camera": {"source": "file"}}, r"\[camera\] path must be given"),
        ({"camera": {"exposre": 3}}, r"\[camera\]: unknown key 'exposre'"),
        (
            {
                "camera": {
                    "model": "fisheye",
                    **{"fx": 200.0, "fy": 200.0, "cx": 320.0, "cy": 320.0},
                    **{"width": 640, "height": 640, "dist": [0.0, 0.0, 0.0, 0.0]},
                    "source": "dual_fisheye",
                }
            },
            r"must be \"equirectangular\"",
        ),
        ({"daemon": {"attitude_timeout_us": 0}}, r"\[daemon\] attitude_timeout_us = 0 is out"),
        (
            {"daemon": {"attitude_lead_max_us": 50_000}},
            r"\[daemon\]: attitude_wait_max_us must be >= attitude_lead_max_us",
        ),
        ({"sim": {"scenario": "T100"}}, r"\[sim\]: scenario must be one of"),
        ({"detection": {"seed_hue_deg": [1.0]}}, r"seed_hue_deg must have 2 items"),
    ],
)
def test_errors_name_the_key(doc: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        config_from_dict(doc)


def test_file_errors(tmp_path: Path) -> None:
    bad = tmp_path / "c.toml"
    bad.write_text("[classifier]\ntcm_threshold = \n")
    with pytest.raises(ConfigError, match=r"c\.toml: .*line 2"):
        load_config(bad)
    with pytest.raises(ConfigError, match="no such file"):
        load_config(tmp_path / "missing.toml")


def test_precedence_cli_over_environment_over_file(tmp_path: Path) -> None:
    f = tmp_path / "c.toml"
    f.write_text('[mavlink]\nurl = "udpout:10.0.0.1:14550"\n[classifier]\ntcm_threshold = 0.1\n')
    env = {
        "TCM_COMPANION__MAVLINK__URL": "serial:/dev/ttyAMA0:921600",
        "TCM_COMPANION__CLASSIFIER__TCM_THRESHOLD": "0.12",
        "UNRELATED": "x",
    }
    cfg = load_config(f)
    assert cfg.mavlink.url == "udpout:10.0.0.1:14550"
    cfg = load_config(f, environ=env)
    assert cfg.mavlink.url == "serial:/dev/ttyAMA0:921600"
    assert cfg.pipeline.classifier.tcm_threshold == 0.12
    cfg = load_config(f, environ=env, sets=["classifier.tcm_threshold=0.2", "camera.source=device"])
    assert cfg.pipeline.classifier.tcm_threshold == 0.2
    assert cfg.mavlink.url == "serial:/dev/ttyAMA0:921600"
    assert cfg.camera.source.source == "device"
    # Defaults stay for what nobody set.
    assert cfg.pipeline.classifier.interval_s == AppConfig().pipeline.classifier.interval_s


def test_override_errors_name_the_variable_or_flag(tmp_path: Path) -> None:
    with pytest.raises(
        ConfigError, match=r"set by environment TCM_COMPANION__DAEMON__CAMERA_TIMEOUT_US"
    ):
        load_config(None, environ={"TCM_COMPANION__DAEMON__CAMERA_TIMEOUT_US": "-5"})
    with pytest.raises(ConfigError, match=r"set by --set sim.scenario"):
        load_config(None, sets=["sim.scenario=NOPE"])
    with pytest.raises(ConfigError, match=r"expected TABLE.KEY=VALUE"):
        load_config(None, sets=["threshold"])
    with pytest.raises(ConfigError, match=r"TCM_COMPANION__X: expected"):
        load_config(None, environ={"TCM_COMPANION__X": "1"})


def test_camera_table_holds_the_model_and_the_source() -> None:
    cfg = config_from_dict(
        {
            "camera": {
                "model": "pinhole",
                "width": 640,
                "height": 480,
                "fx": 320.0,
                "fy": 320.0,
                "cx": 320.0,
                "cy": 240.0,
                "dist": [0.0, 0.0, 0.0, 0.0, 0.0],
                "mount_rpy_deg": [0.0, -10.0, 90.0],
                "source": "device",
                "device": "/dev/video2",
                "fourcc": "MJPG",
            }
        }
    )
    assert cfg.camera.model.model_name == "pinhole" and cfg.camera.model.width == 640
    assert cfg.camera.source.device == "/dev/video2" and cfg.camera.source.fourcc == "MJPG"


@pytest.mark.slow  # a subprocess
def test_config_check_prints_an_effective_config_that_loads_back(tmp_path: Path) -> None:
    import subprocess
    import sys

    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "tcm_companion",
            "config",
            "check",
            str(ROOT / "config.toml"),
            "--set",
            "classifier.tcm_threshold=0.11",
        ],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "OK" in out.splitlines()[0]
    body = "\n".join(out.splitlines()[1:])
    again = tmp_path / "effective.toml"
    again.write_text(body)
    cfg = load_config(again)
    assert cfg.pipeline.classifier.tcm_threshold == 0.11
    assert dataclasses_replace_threshold(cfg) == AppConfig()
    bad = subprocess.run(
        [sys.executable, "-m", "tcm_companion", "config", "check", str(ROOT / "nope.toml")],
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2 and "nope.toml: no such file" in bad.stderr


def dataclasses_replace_threshold(cfg: AppConfig) -> AppConfig:
    import dataclasses

    cls = dataclasses.replace(cfg.pipeline.classifier, tcm_threshold=0.09)
    return dataclasses.replace(cfg, pipeline=dataclasses.replace(cfg.pipeline, classifier=cls))


def test_deprecated_replay_wait_is_accepted_with_a_warning_and_ignored(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """[replay] telemetry_wait_us moved to [daemon] attitude_wait_max_us (one setting for
    the daemon and replay): an older file still loads, the old key is named in a warning
    with its replacement, and it changes nothing."""
    old = tmp_path / "old.toml"
    old.write_text(
        "[replay]\ntelemetry_wait_us = 25000\n\n[daemon]\nattitude_wait_max_us = 30000\n"
    )
    with caplog.at_level("WARNING", logger="tcm_companion.config"):
        cfg = load_config(old)
    assert cfg.daemon.attitude_wait_max_us == 30_000
    assert cfg == load_config(None, sets=["daemon.attitude_wait_max_us=30000"])
    (msg,) = [r.getMessage() for r in caplog.records]
    assert "[replay] telemetry_wait_us is deprecated" in msg
    assert "[daemon] attitude_wait_max_us" in msg and str(old) in msg
    # An empty [replay] is fine (nothing to warn about); other keys in it are not.
    caplog.clear()
    assert config_from_dict({"replay": {}}) == AppConfig() and not caplog.records
    with pytest.raises(ConfigError, match=r"unknown table \[replay\]"):
        config_from_dict({"replay": {"telemetry_wait_us": 1, "typo": 2}})
    # Replay waits as the daemon does.
    from tcm_companion.replay.scenario import telemetry_wait_us

    assert telemetry_wait_us(cfg) == 30_000
    assert "replay" not in config_to_toml(cfg)
