"""Tracking by bearing: gating, stable ids, coasting, history."""

from __future__ import annotations

import math

import numpy as np

from tcm_companion.core.frames import bearing_from_azel
from tcm_companion.core.timebase import frames_to_cover
from tcm_companion.core.tracking import Observation, Tracker, TrackerConfig


def obs(
    frame: int,
    az_deg: float,
    el_deg: float = 0.0,
    alpha_deg: float = 3.0,
    t_us: int | None = None,
    label: str = "",
) -> Observation:
    b = bearing_from_azel(np.radians(az_deg), np.radians(el_deg))
    t = frame * 40_000 if t_us is None else t_us
    return Observation(frame, t, b, b, b, math.radians(alpha_deg), (0.0, 0.0), label=label)


def test_two_objects_keep_their_ids() -> None:
    tr = Tracker()
    ids = None
    for f in range(30):
        tracks = tr.update([obs(f, 10 + 0.5 * f), obs(f, 60 - 0.3 * f)], f * 40_000)
        now = {
            round(
                math.degrees(math.atan2(t.last.bearing_ned[1], t.last.bearing_ned[0]))
            ): t.track_id
            for t in tracks
        }
        if ids is None:
            ids = sorted(t.track_id for t in tracks)
        assert sorted(t.track_id for t in tracks) == ids
        assert len(now) == 2
    assert all(len(t.history) == 30 for t in tr.tracks)


def test_detections_order_does_not_matter() -> None:
    tr = Tracker()
    tr.update([obs(0, 10), obs(0, 40)], 0)
    first = {t.track_id: t.last.bearing_ned[1] for t in tr.tracks}
    tr.update([obs(1, 40.2), obs(1, 10.2)], 40_000)
    for t in tr.tracks:
        assert abs(t.last.bearing_ned[1] - first[t.track_id]) < 0.01


def test_missed_detection_coasts_then_reassociates() -> None:
    tr = Tracker()
    for f in range(5):
        tr.update([obs(f, 10 + f)], f * 40_000)
    tid = tr.tracks[0].track_id
    tracks = tr.update([], 5 * 40_000)
    assert tracks[0].coasting and tracks[0].track_id == tid
    tracks = tr.update([obs(6, 16)], 6 * 40_000)
    assert [t.track_id for t in tracks] == [tid] and not tracks[0].coasting
    assert tracks[0].at_frame(5) is None and tracks[0].at_frame(6) is not None


def test_far_jump_or_size_jump_starts_a_new_track() -> None:
    tr = Tracker()
    tr.update([obs(0, 10)], 0)
    tracks = tr.update([obs(1, 40)], 40_000)
    assert len(tracks) == 2
    tr = Tracker()
    tr.update([obs(0, 10, alpha_deg=3.0)], 0)
    tracks = tr.update([obs(1, 10.1, alpha_deg=9.0)], 40_000)
    assert len(tracks) == 2


def test_track_dropped_after_max_misses_and_ids_not_reused() -> None:
    tr = Tracker(TrackerConfig(max_misses=2))
    tr.update([obs(0, 10)], 0)
    for f in range(1, 4):
        tr.update([], f * 40_000)
    assert tr.tracks == []
    tracks = tr.update([obs(4, 10)], 4 * 40_000)
    assert tracks[0].track_id == 2


def test_history_is_bounded_in_time_and_in_count() -> None:
    tr = Tracker(TrackerConfig(history_s=0.4))
    for f in range(25):
        tr.update([obs(f, 10)], f * 40_000)
    t = tr.tracks[0]
    # 0.4 s of capture time at 25 Hz: the newest and the ten before it.
    assert len(t.history) == 11 and t.at_frame(13) is None and t.at_frame(14) is not None
    assert t.age_s(t.last.t_us) == 24 * 0.040  # the first observation is remembered
    # At a much higher rate the count bound holds (sized for timebase.MAX_FRAME_RATE_HZ).
    tr = Tracker(TrackerConfig(history_s=0.4))
    for f in range(500):
        tr.update([obs(f, 10, t_us=f * 1_000)], f * 1_000)  # 1000 fps
    assert len(tr.tracks[0].history) == frames_to_cover(0.4) < 500


def test_nearest_in_time_picks_by_capture_time() -> None:
    tr = Tracker()
    # 10 fps with one frame missing (t = 0.3 s) and some capture jitter.
    times_us = [0, 100_000, 200_000, 401_000, 500_000, 600_000]
    for f, t_us in enumerate(times_us):
        tr.update([obs(f, 10 + 0.1 * f, t_us=t_us)], t_us)
    t = tr.tracks[0]
    assert t.nearest_in_time(400_000, 80_000).t_us == 401_000
    assert t.nearest_in_time(310_000, 80_000) is None  # nothing within the tolerance
    assert t.nearest_in_time(310_000, 200_000).t_us == 401_000  # 91 ms vs 110 ms
    # Equally near either side: the earlier one (the longer pair), also when the later
    # one is nearer by less than the jitter allowance.
    assert t.nearest_in_time(150_000, 80_000).t_us == 100_000
    assert t.nearest_in_time(301_000, 200_000).t_us == 401_000  # 100 ms vs 101 ms
    assert t.nearest_in_time(301_000, 200_000, prefer_earlier_us=2_000).t_us == 200_000
    # Never an observation captured after not_after_us.
    assert t.nearest_in_time(600_000, 120_000, not_after_us=599_999).t_us == 500_000


def test_a_detection_of_another_label_does_not_continue_a_track() -> None:
    """A yellow object's track is not taken over by a white detection next to where the
    yellow one was (its own detection missed this frame): the white one starts a track
    of its own and the yellow track coasts. Empty labels join anything; without
    keep_labels the white detection continues the yellow track, as before."""
    for keep in (True, False):
        tr = Tracker() if keep else Tracker(TrackerConfig(keep_labels=False))  # on by default
        for f in range(5):
            tr.update([obs(f, 10 + 0.2 * f, label="yellow")], f * 40_000)
        yellow = tr.tracks[0].track_id
        tracks = tr.update([obs(5, 11.2, label="white")], 5 * 40_000)
        by_id = {t.track_id: t for t in tracks}
        if keep:
            assert len(tracks) == 2 and by_id[yellow].coasting
            assert [t.label for t in tracks if t.track_id != yellow] == ["white"]
        else:
            assert list(by_id) == [yellow] and not by_id[yellow].coasting
        # With its own detection back, the yellow track goes on (it wins the pair).
        tracks = tr.update([obs(6, 11.4, label="yellow"), obs(6, 11.5, label="white")], 6 * 40_000)
        assert yellow in {t.track_id for t in tracks if not t.coasting}
    # A detector without labels, or an unlabelled detection: associated by bearing alone.
    tr = Tracker()
    for f in range(3):
        tr.update([obs(f, 10 + 0.2 * f, label="yellow")], f * 40_000)
    tracks = tr.update([obs(3, 10.6, label="")], 3 * 40_000)
    assert len(tracks) == 1 and not tracks[0].coasting
