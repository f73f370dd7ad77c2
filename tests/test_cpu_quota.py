"""``bench --daemon --cpu-quota``: the emulated slow core (a cgroup CPU quota)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tcm_companion.bench.daemon import CpuQuota, CpuQuotaError
from tcm_companion.cli import main


def _v1_root(tmp_path: Path) -> Path:
    root = tmp_path / "cpu"
    root.mkdir()
    (root / "cpu.cfs_quota_us").write_text("-1\n")
    (root / "cpu.cfs_period_us").write_text("100000\n")
    return root


def test_the_quota_is_written_as_cgroup_v1_and_v2_spell_it(tmp_path: Path) -> None:
    v1 = CpuQuota(0.25, root=_v1_root(tmp_path))
    with v1:
        assert (v1.dir / "cpu.cfs_quota_us").read_text() == "25000"
        assert (v1.dir / "cpu.cfs_period_us").read_text() == "100000"
        assert "cpu.cfs_quota_us 25000 per cpu.cfs_period_us 100000" in v1.describe()
        (v1.dir / "cpu.stat").write_text("nr_periods 40\nnr_throttled 30\nthrottled_time 9000000\n")
        assert v1.throttling() == {"periods": 40, "throttled_periods": 30, "throttled_us": 9000}
        for f in v1.dir.iterdir():  # a real cgroup's files are the kernel's: rmdir works
            f.unlink()
    assert not v1.dir.exists()  # removed at the end

    root2 = tmp_path / "unified"
    root2.mkdir()
    (root2 / "cgroup.controllers").write_text("cpuset cpu io memory pids\n")
    v2 = CpuQuota(0.1, period_us=50_000, root=root2)
    with v2:
        assert (v2.dir / "cpu.max").read_text() == "5000 50000"
        (v2.dir / "cpu.max").unlink()


def test_no_cpu_controller_or_no_permission_is_one_clear_error(tmp_path: Path) -> None:
    root = tmp_path / "unified"
    root.mkdir()
    (root / "cgroup.controllers").write_text("memory pids\n")
    with pytest.raises(CpuQuotaError, match="no cpu controller"):
        CpuQuota(0.25, root=root).__enter__()
    with pytest.raises(CpuQuotaError, match="writable cgroup"):
        CpuQuota(0.25, root=tmp_path / "absent").__enter__()
    with pytest.raises(ValueError):
        CpuQuota(0.0)


def test_cpu_quota_option_is_checked_and_only_with_daemon(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["bench", "--daemon", "--cpu-quota", "1.5"])
    assert exc.value.code == 2
    assert (
        "--cpu-quota: must be a fraction of one core in (0, 1], got '1.5'"
        in capsys.readouterr().err
    )
    assert main(["bench", "--cpu-quota", "0.25"]) == 2
    assert "--cpu-quota goes with --daemon" in capsys.readouterr().err


def _writable_cgroup() -> bool:
    try:
        with CpuQuota(0.25):
            return True
    except CpuQuotaError:
        return False


@pytest.mark.slow  # a subprocess
@pytest.mark.skipif(not _writable_cgroup(), reason="no writable cgroup cpu controller here")
def test_a_process_in_the_quota_gets_a_quarter_of_a_core() -> None:
    """The real kernel limit: a busy loop for 1.5 s of wall time inside a 25 % quota
    gets about 0.4 s of CPU (well under the 1.5 s it would get unlimited)."""
    spin = "import time\nt = time.monotonic()\nwhile time.monotonic() - t < 1.5: pass\n"
    with CpuQuota(0.25) as q:
        t0 = time.monotonic()
        child = subprocess.Popen([sys.executable, "-c", spin], preexec_fn=q.join)
        _, status, usage = os.wait4(child.pid, 0)
        child.returncode = os.waitstatus_to_exitcode(status)
        wall_s = time.monotonic() - t0
        cpu_s = usage.ru_utime + usage.ru_stime
        throttled = q.throttling()
    assert child.returncode == 0
    assert wall_s >= 1.5
    assert cpu_s < 0.6 * wall_s, (cpu_s, wall_s)  # unlimited, it would be ~1.0 x wall
    assert throttled["throttled_periods"] >= 3, throttled
