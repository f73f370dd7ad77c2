"""Parameters, signing key and timestamp across restarts."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from tcm_companion.core.pipeline import PipelineConfig
from tcm_companion.io.persist import ParamStore, SigningKeyError, TimestampStore, load_signing_key
from tcm_companion.mavlink.params import ParamTable, config_with_params


def test_params_round_trip_and_apply(tmp_path: Path) -> None:
    store = ParamStore(tmp_path / "params.json")
    assert store.load() == {}
    table = ParamTable()
    assert table.set("TCM_THRESH", 0.12) == pytest.approx(0.12)
    assert table.set("TCM_INTERVAL_S", 1.2) == pytest.approx(1.2)
    assert table.set("TCM_INTERVAL_S", 25) is None and table.set("NOPE", 1) is None
    assert table.set("TCM_INTERVAL", 25) is None  # the old frame count: unknown now
    store.save(table.values)
    again = ParamTable(ParamStore(tmp_path / "params.json").load())
    assert again.values == table.values
    cfg = config_with_params(PipelineConfig(), again.values)
    assert cfg.classifier.tcm_threshold == pytest.approx(0.12) and cfg.classifier.interval_s == 1.2


def test_corrupt_param_file_is_set_aside(tmp_path: Path) -> None:
    path = tmp_path / "params.json"
    path.write_text("{not json")
    store = ParamStore(path)
    assert store.load() == {}
    assert (tmp_path / "params.json.corrupt").exists() and "using defaults" in store.warnings[0]


def test_out_of_range_stored_values_are_ignored(tmp_path: Path) -> None:
    table = ParamTable({"TCM_THRESH": 99.0, "TCM_HOLD_S": 0.2, "TCM_HOLD": 3})
    assert table.values["TCM_THRESH"] == pytest.approx(0.09) and table.values["TCM_HOLD_S"] == 0.2
    # A frame count stored under the old name is ignored, not read as 3 s.
    assert table.ignored_initial == ["TCM_THRESH", "TCM_HOLD"]


def test_signing_key_forms_and_permissions(tmp_path: Path) -> None:
    key = tmp_path / "key"
    key.write_text("00" * 32 + "\n")
    key.chmod(0o600)
    assert load_signing_key(key) == bytes(32)
    key.write_bytes(bytes(range(32)))
    assert load_signing_key(key) == bytes(range(32))
    key.write_text("correct horse battery staple\n")
    assert load_signing_key(key) == hashlib.sha256(b"correct horse battery staple").digest()
    key.chmod(0o644)
    with pytest.raises(
        SigningKeyError, match=r"accessible to other users \(mode 0644\); run: chmod 600"
    ):
        load_signing_key(key)
    with pytest.raises(SigningKeyError, match="does not exist"):
        load_signing_key(tmp_path / "missing")


def test_timestamp_store(tmp_path: Path) -> None:
    ts = TimestampStore(tmp_path / "ts")
    assert ts.load() == 0
    ts.save(123456789)
    assert TimestampStore(tmp_path / "ts").load() == 123456789


def test_make_endpoint_signing_and_params(tmp_path: Path) -> None:
    from tcm_companion.service.endpoint_setup import MavlinkConfig, make_endpoint, persist

    key = tmp_path / "key"
    key.write_text("ab" * 32)
    key.chmod(0o644)
    settings = MavlinkConfig(
        signing_key_file=str(key),
        signing_timestamp_file=str(tmp_path / "ts"),
        params_file=str(tmp_path / "params.json"),
    )
    with pytest.raises(SigningKeyError, match="chmod 600"):
        make_endpoint(settings, 0)
    key.chmod(0o600)
    (tmp_path / "params.json").write_text('{"TCM_THRESH": 0.15, "TCM_INTERVAL_S": 999}')
    ep, warnings = make_endpoint(settings, 0)
    assert ep.codec.signing is not None and ep.params.values["TCM_THRESH"] == pytest.approx(0.15)
    assert warnings and "TCM_INTERVAL_S" in warnings[0]
    ep.codec.mav.signing.timestamp = 4242
    persist(settings, ep)
    again, _ = make_endpoint(settings, 0)
    assert again.codec.signing_timestamp == 4242


def test_each_parameter_has_the_range_of_the_setting_it_stands_for() -> None:
    """A value config.toml admits is one its MAVLink parameter admits (before: a
    configured interval of 3 s or a seed hue of -70 deg was replaced by the parameter's
    default, with a warning)."""
    from tcm_companion.config import RANGES, PerItem, Range
    from tcm_companion.mavlink.params import CONFIG_KEYS, PARAMS

    specs = {p.name: p for p in PARAMS}
    for name, key in CONFIG_KEYS.items():
        table, _, field = key.removeprefix("[").partition("] ")
        field = field.split("[")[0]
        spec = RANGES.get(f"{table}.{field}")
        if spec is None:  # an enumeration (egomotion_source): its index range
            continue
        assert isinstance(spec, Range) and not isinstance(spec, PerItem), key
        assert (specs[name].minimum, specs[name].maximum) == (spec.lo, spec.hi), name


def test_a_configured_value_the_old_parameter_range_refused_is_used(tmp_path: Path) -> None:
    from tcm_companion.core.classify import ClassifierConfig
    from tcm_companion.core.pipeline import PipelineConfig
    from tcm_companion.mavlink.params import config_with_params
    from tcm_companion.service.endpoint_setup import MavlinkConfig, make_endpoint

    pipeline = PipelineConfig(classifier=ClassifierConfig(interval_s=3.0, hold_s=2.5))
    settings = MavlinkConfig(params_file=str(tmp_path / "params.json"))
    ep, warnings = make_endpoint(settings, 0, pipeline)
    assert warnings == []
    used = config_with_params(pipeline, ep.params.values)
    assert (used.classifier.interval_s, used.classifier.hold_s) == (3.0, 2.5)


def test_a_second_corrupt_param_file_does_not_replace_the_first_set_aside(tmp_path: Path) -> None:
    """Each damaged file is kept: the second goes to ``.corrupt.1`` (it replaced the
    first ``.corrupt``, whatever it held, before)."""
    path = tmp_path / "params.json"
    for text in ("{first", "{second", "{third"):
        path.write_text(text)
        assert ParamStore(path).load() == {}
        assert not path.exists()
    kept = {p.name: p.read_text() for p in tmp_path.iterdir()}
    assert kept == {
        "params.json.corrupt": "{first",
        "params.json.corrupt.1": "{second",
        "params.json.corrupt.2": "{third",
    }
