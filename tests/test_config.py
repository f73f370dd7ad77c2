"""config.toml → dataclasses: the shipped file matches the defaults; errors name keys."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from tcm_companion.config import AppConfig, ConfigError, config_from_dict, load_config

ROOT = Path(__file__).resolve().parents[1]


def test_shipped_config_is_the_builtin_default() -> None:
    assert load_config(ROOT / "config.toml") == AppConfig()


def test_degrees_and_nested_tables() -> None:
    cfg = config_from_dict({"classifier": {"min_theta_deg": 20.0, "extra_intervals": [12, 40]}})
    assert cfg.pipeline.classifier.min_theta_rad == pytest.approx(math.radians(20.0))
    assert cfg.pipeline.classifier.extra_intervals == (12, 40)
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
            {"classifier": {"frame_interval": 2.5}},
            r"\[classifier\] frame_interval must be an integer",
        ),
        ({"pipeline": {"bsm_enabled": "yes"}}, r"bsm_enabled must be true or false"),
        ({"tracking": {"gate_deg": "wide"}}, r"gate_deg must be a number of degrees"),
        ({"camera": {}}, r"unknown table \[camera\]"),
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
