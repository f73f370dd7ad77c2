"""The scenario reader on the independent examples, and its errors on broken copies."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from tcm_companion.io.scenario import ScenarioError, load_scenario

from .helpers import EXAMPLE_NAMES, example_path


@pytest.mark.parametrize("name", EXAMPLE_NAMES)
def test_examples_load(name: str) -> None:
    s = load_scenario(example_path(name))
    assert s.n_frames in (30, 100)
    assert s.warnings == []
    assert np.all(np.diff(s.frame_times_us) > 0)
    assert len(s.attitude_samples()) > 25 * s.n_frames / 25
    assert len(s.position_samples()) > 0
    assert s.truth is not None and s.truth.object_ids == [1]
    _, t_us, img = next(s.iter_frames())
    assert img.shape == (s.camera.height, s.camera.width, 3) and t_us == s.frame_times_us[0]


@pytest.fixture()
def broken(tmp_path: Path) -> Path:
    dst = tmp_path / "s"
    shutil.copytree(example_path("EX-PINHOLE"), dst)
    for p in [dst, *dst.rglob("*")]:
        p.chmod(0o755 if p.is_dir() else 0o644)
    return dst


def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def test_frames_csv_not_increasing(broken: Path) -> None:
    lines = (broken / "frames.csv").read_text().splitlines()
    lines[3] = lines[3].split(",")[0] + "," + lines[2].split(",")[1]
    (broken / "frames.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(ScenarioError, match=r"frames\.csv: line 4: t_us .* does not increase"):
        load_scenario(broken)


def test_frames_csv_bad_header_and_bad_int(broken: Path) -> None:
    edit(broken / "frames.csv", "frame,t_us", "frame,time")
    with pytest.raises(ScenarioError, match=r"frames\.csv: line 1: header"):
        load_scenario(broken)
    edit(broken / "frames.csv", "frame,time", "frame,t_us")
    edit(broken / "frames.csv", "\n5,", "\nfive,")
    with pytest.raises(ScenarioError, match=r"frames\.csv: line 7: frame must be an integer"):
        load_scenario(broken)


def test_missing_frame_file(broken: Path) -> None:
    (broken / "frames" / "000007.png").unlink()
    with pytest.raises(ScenarioError, match=r"line 9: frame 7 has no file .*000007\.png"):
        load_scenario(broken)


def test_camera_key_errors(broken: Path) -> None:
    edit(broken / "scenario.toml", "fx = 320.0\n", "")
    with pytest.raises(ScenarioError, match=r"scenario\.toml: camera\.fx is required"):
        load_scenario(broken)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "fx = 320.0\n",
            "fx = 1e-9\n",
            r"camera\.fx = 1e-09 is out of range: must be in \[1, 100000\] px",
        ),
        (
            "cx = 320.0\n",
            "cx = -5000.0\n",
            r"camera\.cx = -5000\.0 is out of range: .*\[0, width\] px \(width = 640\)",
        ),
    ],
)
def test_camera_values_out_of_range(broken: Path, old: str, new: str, message: str) -> None:
    """The scenario's camera is held to the ranges config.toml's is (issue 13: fx = 1e-9
    and cx = -5000 replayed silently)."""
    edit(broken / "scenario.toml", old, new)
    with pytest.raises(ScenarioError, match=r"scenario\.toml: " + message) as err:
        load_scenario(broken)
    assert "fy" not in str(err.value) and "cy" not in str(err.value)  # only the bad key


def test_toml_syntax_error_names_line(broken: Path) -> None:
    edit(broken / "scenario.toml", 'model = "pinhole"', "model = pinhole")
    with pytest.raises(ScenarioError, match=r"scenario\.toml: .*line 7"):
        load_scenario(broken)


def test_wrong_format_and_image_size(broken: Path) -> None:
    edit(broken / "scenario.toml", "width = 640", "width = 320")
    with pytest.raises(ScenarioError, match=r"000000\.png: image is 640x480 but .* says 320x480"):
        load_scenario(broken)
    edit(broken / "scenario.toml", "tcm-scenario/1", "tcm-scenario/2")
    with pytest.raises(ScenarioError, match="format must be"):
        load_scenario(broken)


def test_truth_errors(broken: Path) -> None:
    lines = (broken / "truth.csv").read_text().splitlines()
    fields = lines[5].split(",")
    fields[2] = "2"
    lines[5] = ",".join(fields)
    (broken / "truth.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(ScenarioError, match=r"truth\.csv: line 6: moving must be 0 or 1"):
        load_scenario(broken)


def test_missing_or_unusable_tlog(broken: Path) -> None:
    (broken / "telemetry.tlog").write_bytes(b"\x00" * 8 + bytes(range(256)) * 4)
    with pytest.raises(
        ScenarioError,
        match=r"telemetry\.tlog: no usable MAVLink record in 1032 bytes \(record 0 at byte 0: "
        r"byte 0x00 is not a MAVLink magic byte",
    ):
        load_scenario(broken)
    (broken / "telemetry.tlog").unlink()
    with pytest.raises(ScenarioError, match=r"telemetry\.tlog: missing"):
        load_scenario(broken)


def _record_bounds(data: bytes) -> list[tuple[int, int]]:
    """(start, end) of each record of a well-formed .tlog."""
    from tcm_companion.io.tlog import iter_tlog

    starts = [r.offset for r in iter_tlog(data)]
    return list(zip(starts, [*starts[1:], len(data)]))


@pytest.mark.parametrize("damage", ["cut", "junk", "middle", "first-record"])
def test_a_damaged_tlog_keeps_what_is_intact_and_says_what_is_not(
    broken: Path, damage: str
) -> None:
    """A .tlog cut short, with junk appended, or with a corrupt stretch in the middle is
    read the same way: the intact records kept, the rest in ``warnings`` (file, bytes,
    where) and in ``tlog_stats`` (issue 13: junk appended refused the whole scenario)."""
    path = broken / "telemetry.tlog"
    data = path.read_bytes()
    full = load_scenario(broken)
    spans = _record_bounds(data)
    k = len(spans) // 2
    start, end = spans[k]
    if damage == "cut":
        bad, lost, where = data[: start + 11], len(spans) - k, f"at byte {start}"
    elif damage == "junk":
        bad, lost, where = data + b"\x00junk" * 100, 0, f"500 bytes skipped at byte {len(data)}"
    elif damage == "middle":
        n = min(30, end - start - 8)  # its frame, not the next record
        bad = data[: start + 8] + b"\x42" * n + data[start + 8 + n :]
        lost, where = 1, f"skipped at byte {start}, resynchronised at byte {end}"
    else:
        bad = b"\x42" * 9 + data[9:]
        lost, where = 1, f"{spans[0][1]} bytes skipped at byte 0, resynchronised"
    path.write_bytes(bad)
    s = load_scenario(broken)
    stats = s.tlog_stats
    assert stats.decoded == full.tlog_stats.decoded - lost
    assert stats.gaps and stats.bytes_skipped > 0
    (warning,) = s.warnings
    assert warning.startswith(f"{path}: {stats.decoded} records kept, received ")
    assert where in warning
    if damage == "cut":
        assert "truncated last record: 11 bytes" in warning
    assert len(s.telemetry) < len(full.telemetry) or damage == "junk"


def test_video_scenario(broken: Path, tmp_path: Path) -> None:
    import cv2

    s = load_scenario(broken)
    writer = cv2.VideoWriter(
        str(broken / "video.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 25, (640, 480)
    )
    for _, _, img in s.iter_frames():
        writer.write(img)
    writer.release()
    edit(broken / "scenario.toml", 'frames_dir = "frames"', 'video = "video.avi"')
    shutil.rmtree(broken / "frames")
    v = load_scenario(broken)
    frames = list(v.iter_frames())
    assert len(frames) == 30 and frames[0][2].shape == (480, 640, 3)


def test_targets_and_detections_are_read(broken: Path) -> None:
    assert load_scenario(broken).targets == [] and load_scenario(broken).detections is None
    with open(broken / "scenario.toml", "a") as fh:
        fh.write(
            '\n[[target]]\nobject_id = 1\nshape = "box"\n'
            "colour_rgb = [40, 70, 190]\nsize_m = [1.8, 0.8, 1.5]\n"
        )
    (broken / "detections.csv").write_text(
        "frame,x_min,y_min,x_max,y_max,score,label\n0,10.5,20,40,60,0.9,car\n2,11,21,41,61,0.8,\n"
    )
    s = load_scenario(broken)
    assert [(t.object_id, t.shape, t.colour_rgb, t.size_m) for t in s.targets] == [
        (1, "box", (40, 70, 190), (1.8, 0.8, 1.5))
    ]
    assert s.detections is not None
    assert [(d.frame, d.x_min, d.score, d.label) for d in s.detections] == [
        (0, 10.5, 0.9, "car"),
        (2, 11.0, 0.8, ""),
    ]


@pytest.mark.parametrize(
    "row, message",
    [
        ("5,40,20,10,60,0.9,car", r"line 3: x_max \(10\) must exceed x_min \(40\)"),  # pinhole
        ("1,10,20,40,60,1.5,car", r"line 3: score must be in \[0, 1\]"),
        ("99,10,20,40,60,0.5,car", r"line 3: frame 99 is not in frames.csv"),
        ("0,10,20,40,600,0.5,car", r"line 3: box .* leaves the 640x480 image"),
    ],
)
def test_malformed_detections_name_the_line(broken: Path, row: str, message: str) -> None:
    (broken / "detections.csv").write_text(
        f"frame,x_min,y_min,x_max,y_max,score,label\n0,1,2,3,4,0.5,x\n{row}\n"
    )
    with pytest.raises(ScenarioError, match=r"detections\.csv: " + message):
        load_scenario(broken)


# -- truth: the one matching rule and the true time to contact ------------------------------
def test_truth_matching_is_greedy_nearest_within_the_gate() -> None:
    import math

    from tcm_companion.io.scoring import MATCH_GATE_RAD, match_truth

    rel = np.array([10.0, 0.0, 0.0])  # 10 m north; radius 0.5 m: α = asin(0.05)
    alpha = math.asin(0.05)
    gate = MATCH_GATE_RAD + 2 * alpha

    def bearing(az: float) -> np.ndarray:
        return np.array([math.cos(az), math.sin(az), 0.0])

    cands = [bearing(gate * 0.9), bearing(gate * 0.5), bearing(gate * 1.1)]
    used: set[int] = set()
    m = match_truth(rel, 0.5, cands, used)
    assert (m.index, used) == (1, {1}) and m.matched
    assert m.bearing_error_rad == pytest.approx(gate * 0.5)
    assert m.alpha_true_rad == pytest.approx(alpha)
    # A second truth object at the same place takes the next nearest free one ...
    assert match_truth(rel, 0.5, cands, used).index == 0 and used == {0, 1}
    # ... and a third none: the last candidate is outside the gate.
    m = match_truth(rel, 0.5, cands, used)
    assert not m.matched and m.index == -1 and used == {0, 1}
    assert m.bearing_error_rad == pytest.approx(gate * 1.1)
    assert match_truth(rel, 0.5, cands, set(), gate_rad=MATCH_GATE_RAD * 2).index == 1
    assert not match_truth(rel, 0.5, [], set()).matched


def test_truth_time_to_contact_is_range_over_closing_speed() -> None:
    from tcm_companion.io.truth import Truth

    n = 6
    times = 1_700_000_000_000_000 + 40_000 * np.arange(n)  # Unix µs: 25 Hz
    frame = np.r_[np.arange(n), np.arange(n)]
    # object 1 closes at 2 m/s from 10 m; object 2 recedes
    d1 = 10.0 - 2.0 * 0.04 * np.arange(n)
    d2 = 10.0 + 2.0 * 0.04 * np.arange(n)
    obj = np.zeros((2 * n, 3))
    obj[:, 0] = np.r_[d1, d2]
    truth = Truth(
        frame=frame,
        object_id=np.r_[np.ones(n, int), 2 * np.ones(n, int)],
        moving=np.ones(2 * n, bool),
        obj_ned_m=obj,
        obj_radius_m=np.full(2 * n, 0.5),
        veh_ned_m=np.zeros((2 * n, 3)),
    )
    ttc = truth.ttc_s(times)
    np.testing.assert_allclose(ttc[:n], d1 / 2.0, rtol=1e-9)
    assert np.isnan(ttc[n:]).all()
    assert list(truth.rows_for_object(2)) == list(range(n, 2 * n))


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_frames_are_read_ahead_in_order_and_the_reader_thread_ends(tmp_path: Path) -> None:
    """The next PNG is decoded on a thread while the caller works on this one: the images
    and their order are those of reading each one when asked, a bad frame is still
    reported at its own index, and stopping early leaves no reader thread behind."""
    import threading

    import cv2

    sc = load_scenario(example_path("EX-PINHOLE"))
    expected = [cv2.imread(str(sc.frame_path(i)), cv2.IMREAD_COLOR) for i in range(sc.n_frames)]
    got = list(sc.iter_frames())
    assert [i for i, _, _ in got] == list(range(sc.n_frames))
    assert all(np.array_equal(img, e) for (_, _, img), e in zip(got, expected, strict=True))

    dst = tmp_path / "sc"
    shutil.copytree(example_path("EX-PINHOLE"), dst)
    (dst / "frames" / "000003.png").write_bytes(b"")
    damaged = load_scenario(dst, check_frames=False)
    seen: list[int] = []
    frames = damaged.iter_frames_tolerant(lambda i, why: seen.append(i))
    for i, _, img in frames:
        assert (img is None) == (i == 3)
        assert seen == ([3] if i >= 3 else [])  # reported when its turn comes, not before
        if i == 5:
            break
    frames.close()
    assert not [t for t in threading.enumerate() if t.name.startswith("tcm-frame-reader")]
