"""SIGKILL, for real: a killed training process resumes to the same weights; a kill mid-write
never leaves a truncated checkpoint under its final name."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import torch
from conftest import python_env
from test_train import _params, _train, _weights

ROOT = Path(__file__).resolve().parents[1]

# The child trains like _train; after the checkpoint write named by PAUSE_AT it stops and waits
# to be killed (so the kill lands at a known point, not by timing luck).
CHILD = textwrap.dedent("""
    import os, sys, time
    from pathlib import Path
    import torch
    sys.path.insert(0, {tests!r})
    import msdepth.training.train as train_mod
    from test_train import _params
    pairs = [tuple(Path(p) for p in line.split()) for line in Path({pair_file!r}).read_text().splitlines()]
    pause_at, mode = int(os.environ["PAUSE_AT"]), os.environ["MODE"]
    real_save, calls = torch.save, [0]
    def save(obj, f, *a, **k):
        calls[0] += 1
        if mode == "mid_write" and calls[0] == pause_at:
            f.write(b"PK half a checkpoint"); f.flush()
            print("PAUSED", flush=True); time.sleep(600)
        if mode == "after_write" and calls[0] == pause_at + 1:  # checkpoint pause_at is renamed by now
            print("PAUSED", flush=True); time.sleep(600)
        real_save(obj, f, *a, **k)
    torch.save = save
    out = Path({out!r})
    outputs = train_mod.TrainOutputs(out / "model.pt", out / "ck.pt")
    train_mod.train_variant(_params(epochs=3), "ssim", pairs, outputs, train_mod.TrainOptions(progress=False))
    print("FINISHED", flush=True)
""")


def _run_child(tmp: Path, pairs, out: Path, mode: str, pause_at: int) -> str:
    pair_file = tmp / "pairs.txt"
    pair_file.write_text("".join(f"{a} {b}\n" for a, b in pairs))
    script = tmp / "child.py"
    script.write_text(CHILD.format(tests=str(ROOT / "tests"), pair_file=str(pair_file), out=str(out)))
    env = python_env(PAUSE_AT=str(pause_at), MODE=mode)
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, env=env)
    line = proc.stdout.readline().strip()
    if line == "PAUSED":
        proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=120)
    return line


def test_sigkill_after_a_checkpoint_resumes_to_the_uninterrupted_weights(pairs, tmp_path: Path) -> None:
    (tmp_path / "clean").mkdir()
    (tmp_path / "killed").mkdir()
    _train(_params(epochs=3), pairs, tmp_path / "clean")
    assert _run_child(tmp_path, pairs, tmp_path / "killed", "after_write", pause_at=2) == "PAUSED"
    assert torch.load(tmp_path / "killed" / "ck.pt", weights_only=True)["epoch"] == 2
    assert not (tmp_path / "killed" / "model.pt").exists()
    assert _run_child(tmp_path, pairs, tmp_path / "killed", "none", pause_at=0) == "FINISHED"
    a, b = _weights(tmp_path / "clean" / "model.pt"), _weights(tmp_path / "killed" / "model.pt")
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_sigkill_while_writing_a_checkpoint_leaves_the_previous_one(pairs, tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    assert _run_child(tmp_path, pairs, out, "mid_write", pause_at=2) == "PAUSED"
    state = torch.load(out / "ck.pt", weights_only=True)  # still epoch 1's, complete
    assert state["epoch"] == 1
    leftovers = [p for p in out.iterdir() if p.name != "ck.pt"]
    assert all(p.name.startswith(".ck.pt.") for p in leftovers)  # only the temp file, never the final name
