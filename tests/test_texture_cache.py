"""The simulator's textures kept on disk between runs: the same bits, never a failure."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import pytest

from tcm_companion.sim.scene import texture_cache, world
from tcm_companion.sim.scene.texture_cache import CACHE_ENV, cache_dir, cached_arrays

#: A small ground (20 m at 0.1 m, a 1024-texel detail layer): the same code, quick.
SMALL = world.Ground(seed=7, extent_m=20.0, detail_px=1024)


def _fresh_textures(ground: world.Ground) -> world.GroundTextures:
    world.ground_textures.cache_clear()  # the in-process cache in front of the disk
    return world.ground_textures(ground)


@pytest.mark.slow  # over half a second of CPU
def test_ground_and_sky_textures_from_the_cache_are_the_built_ones(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(CACHE_ENV, "off")
    built = _fresh_textures(SMALL)
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    stored = _fresh_textures(SMALL)  # built again, and written
    assert [p.name.split("-")[0] for p in tmp_path.iterdir()] == ["ground"]
    loaded = _fresh_textures(SMALL)  # read back
    for t in (stored, loaded):
        for a, b in zip(
            (*t.macro_levels, t.detail_atlas, t.detail_offsets_px),
            (*built.macro_levels, built.detail_atlas, built.detail_offsets_px),
            strict=True,
        ):
            assert a.dtype == b.dtype and np.array_equal(a, b)
    sky = world.Sky(seed=3)
    world.sky_textures.cache_clear()
    first = world.sky_textures(sky)
    world.sky_textures.cache_clear()
    again = world.sky_textures(sky)
    assert np.array_equal(first.cloud, again.cloud) and np.array_equal(
        first.hill_el_rad, again.hill_el_rad
    )
    assert len([p for p in tmp_path.iterdir() if p.name.startswith("sky-")]) == 1
    world.ground_textures.cache_clear()
    world.sky_textures.cache_clear()


def test_other_settings_or_code_name_another_file(tmp_path: Path) -> None:
    src = tmp_path / "builder.py"
    src.write_text("v1")
    calls = []

    def build() -> dict[str, np.ndarray]:
        calls.append(1)
        return {"a": np.arange(3)}

    os.environ[CACHE_ENV] = str(tmp_path / "cache")
    try:
        cached_arrays("t", (1, 2), str(src), ("a",), build)
        cached_arrays("t", (1, 2), str(src), ("a",), build)
        assert len(calls) == 1
        cached_arrays("t", (1, 3), str(src), ("a",), build)  # other settings
        src.write_text("v2")  # the code that builds them changed
        cached_arrays("t", (1, 2), str(src), ("a",), build)
        assert len(calls) == 3
    finally:
        del os.environ[CACHE_ENV]


def test_a_damaged_file_is_rebuilt_and_an_unwritable_directory_skipped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    src = tmp_path / "builder.py"
    src.write_text("v1")
    cache = tmp_path / "cache"
    monkeypatch.setenv(CACHE_ENV, str(cache))

    def build() -> dict[str, np.ndarray]:
        return {"a": np.arange(5, dtype=np.uint8)}

    cached_arrays("t", 0, str(src), ("a",), build)
    (path,) = cache.iterdir()
    path.write_bytes(path.read_bytes()[:40])  # cut short
    with caplog.at_level(logging.WARNING, logger=texture_cache.__name__):
        got = cached_arrays("t", 0, str(src), ("a",), build)
    assert np.array_equal(got["a"], np.arange(5)) and "unreadable" in caplog.text
    assert np.array_equal(cached_arrays("t", 0, str(src), ("a",), build)["a"], np.arange(5))
    # A file holding other arrays (written by hand, say) is not taken either.
    np.savez(path, b=np.zeros(2))
    assert list(cached_arrays("t", 0, str(src), ("a",), build)) == ["a"]

    blocked = tmp_path / "not-a-dir"
    blocked.write_text("a file where the directory would be")
    monkeypatch.setenv(CACHE_ENV, str(blocked / "sub"))
    assert np.array_equal(cached_arrays("t", 0, str(src), ("a",), build)["a"], np.arange(5))


def test_where_the_cache_is(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv(CACHE_ENV, "off")
    assert cache_dir() is None
    monkeypatch.delenv(CACHE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_dir() == tmp_path / "tcm-companion"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_dir() == tmp_path / "home" / ".cache" / "tcm-companion"
