"""Where the daemon's CPU goes, per thread: the daemon names its threads for the OS, and
``bench --daemon`` reads each thread's CPU from ``/proc``."""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

import pytest

from tcm_companion.bench.daemon import _thread_cpu, thread_shares
from tcm_companion.service.daemon import name_os_threads

linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs /proc")


def _comm(tid: int) -> str:
    return Path(f"/proc/self/task/{tid}/comm").read_text().strip()


@linux_only
def test_threads_get_their_python_names_as_os_names() -> None:
    """A thread's OS name is the process's until the daemon names it; names longer than
    15 bytes are cut (the kernel's limit), and the main thread keeps the process's."""
    started, done = threading.Event(), threading.Event()

    def work() -> None:
        started.set()
        done.wait(5.0)

    threads = [
        threading.Thread(target=work, name="flightlog", daemon=True),
        threading.Thread(target=work, name="camera-0-frames-and-more", daemon=True),
    ]
    for t in threads:
        started.clear()
        t.start()
        started.wait(5.0)
    main_before = _comm(threading.main_thread().native_id or 0)
    try:
        tids = [t.native_id for t in threads]
        assert all(tid is not None for tid in tids)
        assert [_comm(tid) for tid in tids if tid] != ["flightlog", "camera-0-frames"]
        name_os_threads()
        assert [_comm(tid) for tid in tids if tid] == ["flightlog", "camera-0-frames"]
        assert _comm(threading.main_thread().native_id or 0) == main_before
    finally:
        done.set()
        for t in threads:
            t.join(5.0)


@linux_only
def test_thread_cpu_sees_a_busy_named_thread() -> None:
    """``_thread_cpu`` of this process: the main thread as ``main``, a named thread by its
    name, and the CPU a busy thread burnt between two readings."""
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            sum(range(1000))

    t = threading.Thread(target=spin, name="spinner", daemon=True)
    t.start()
    try:
        name_os_threads()
        before = _thread_cpu(os.getpid())
        t0 = time.monotonic()
        # Until the spinner has burnt 50 ms (5 clock ticks), however busy the machine: a
        # fixed 0.3 s gave it under 10% of a core on a loaded two-core runner.
        spun = 0.0
        while spun < 0.05 and time.monotonic() - t0 < 30.0:
            time.sleep(0.05)
            after = _thread_cpu(os.getpid())
            spun = sum(c for tid, (n, c) in after.items() if n == "spinner") - sum(
                c for tid, (n, c) in before.items() if n == "spinner"
            )
        wall = time.monotonic() - t0
    finally:
        stop.set()
        t.join(5.0)
    assert after[os.getpid()][0] == "main"
    shares = thread_shares(before, after, wall)
    assert "spinner" in shares and shares["spinner"] >= 0.05 / wall * 100.0 - 1e-9
    assert shares["spinner"] >= shares["main"]  # the main thread slept


def test_thread_shares_sums_by_name_and_counts_new_threads_from_zero() -> None:
    before = {1: ("main", 10.0), 2: ("camera-0", 1.0), 3: ("camera-1", 2.0), 4: ("old", 5.0)}
    after = {1: ("main", 12.0), 2: ("camera-0", 1.5), 3: ("camera-1", 2.5), 5: ("flightlog", 0.2)}
    shares = thread_shares(before, after, wall_s=10.0)
    assert shares == pytest.approx(
        {"main": 20.0, "flightlog": 2.0, "camera-0": 5.0, "camera-1": 5.0}
    )
    assert next(iter(shares)) == "main"  # the busiest first
    assert thread_shares(before, after, wall_s=0.0) == {}
    # Two threads of one name add up.
    same = {2: ("camera", 1.5), 3: ("camera", 2.5)}
    assert thread_shares(before, same, 1.0) == pytest.approx({"camera": 100.0})
