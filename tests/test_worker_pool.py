"""Worker processes end with their stage (issue 68): a parent killed by SIGKILL, which runs no
cleanup, takes :func:`msdepth.optimum.workers.worker_pool`'s spawned workers with it within seconds,
as it does ``optimum.jobs``' frame workers (msdepth.optimum.sets.frame_disparities)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# A stage's stand-in: two busy workers from the project's pool, their ids printed, then a wait for
# the kill. {patch} runs in the workers too (spawn imports the main file in each, as __mp_main__).
PARENT = """
import time
from msdepth.optimum import workers
{patch}
if __name__ == "__main__":
    pool = workers.worker_pool(2)
    short = [pool.submit(time.sleep, 0.5) for _ in range(2)]
    long = [pool.submit(time.sleep, 120) for _ in range(2)]
    for future in short:
        future.result()
    print(" ".join(str(p) for p in pool._processes), flush=True)
    time.sleep(120)
"""
NO_SIGNAL = "workers._set_parent_death_signal = lambda: None  # as where Linux's signal is missing"


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc for the workers' state")
@pytest.mark.parametrize("signal_too", [True, False], ids=["death-signal", "watchdog-only"])
def test_workers_end_within_seconds_of_a_sigkilled_parent(signal_too: bool, tmp_path: Path) -> None:
    """kill -9 of the parent: both workers are gone within 5 s, by the parent-death signal, or by the
    watchdog thread alone where there is no such signal."""
    script = tmp_path / "parent.py"
    script.write_text(PARENT.format(patch="" if signal_too else NO_SIGNAL))
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, env=env)
    try:
        line = parent.stdout.readline()
        pids = [int(p) for p in line.split()]
        assert len(pids) == 2 and all(_alive(p) for p in pids), line
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(10)
        deadline = time.monotonic() + 5
        while any(_alive(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_alive(p) for p in pids), [p for p in pids if _alive(p)]
    finally:
        parent.kill()
        for pid in [int(p) for p in (locals().get("line") or "").split()]:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
