"""Data parallel on CPU: 2 ranks under torchrun (gloo) end with identical weights, equal to one
process with the same global batch; the sampler reproduces a shuffling DataLoader exactly."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import torch
from conftest import python_env
from test_train import _params, _train, _weights
from torch.utils.data import DataLoader

from msdepth.training.distributed import Context, GlobalBatchSampler

ROOT = Path(__file__).resolve().parents[1]


def test_one_process_sees_the_batches_a_shuffling_dataloader_draws() -> None:
    data = list(range(23))
    old = DataLoader(
        data, batch_size=4, shuffle=True, drop_last=True, generator=torch.Generator().manual_seed(5)
    )
    gen = torch.Generator().manual_seed(5)
    new = DataLoader(data, batch_size=4, sampler=GlobalBatchSampler(23, 4, Context(), gen), generator=gen)
    assert [b.tolist() for b in old] == [b.tolist() for b in new]


def test_ranks_split_each_global_batch() -> None:
    def batches(rank: int) -> list[list[int]]:
        gen = torch.Generator().manual_seed(1)
        sampler = GlobalBatchSampler(10, 2, Context(rank, 2, rank), gen)
        return [list(b) for b in DataLoader(list(range(10)), batch_size=2, sampler=sampler, generator=gen)]

    one = DataLoader(
        list(range(10)),
        batch_size=4,
        sampler=GlobalBatchSampler(10, 4, Context(), g := torch.Generator().manual_seed(1)),
        generator=g,
    )
    for global_batch, r0, r1 in zip(one, batches(0), batches(1), strict=True):
        assert global_batch.tolist() == [int(i) for i in r0] + [int(i) for i in r1]


CHILD = textwrap.dedent("""
    import sys
    from pathlib import Path
    sys.path.insert(0, {tests!r})
    from msdepth.training.train import TrainOptions, TrainOutputs, train_variant
    from test_train import _params
    pairs = [tuple(Path(p) for p in line.split()) for line in Path({pair_file!r}).read_text().splitlines()]
    out = Path({out!r})
    params = _params("learned", batch_size=2, nproc=2, launcher="torchrun", dist_timeout_s=60)
    outputs = TrainOutputs(out / "model.pt", out / "ck.pt")
    train_variant(params, "msssim", pairs, outputs, TrainOptions(progress=False))
""")


def test_two_ranks_match_one_process_with_the_same_global_batch(pairs, tmp_path: Path) -> None:
    (tmp_path / "single").mkdir()
    (tmp_path / "ddp").mkdir()
    _train(_params("learned", batch_size=4), pairs, tmp_path / "single", variant="msssim")
    pair_file = tmp_path / "pairs.txt"
    pair_file.write_text("".join(f"{a} {b}\n" for a, b in pairs))
    script = tmp_path / "child.py"
    script.write_text(
        CHILD.format(tests=str(ROOT / "tests"), pair_file=str(pair_file), out=str(tmp_path / "ddp"))
    )
    env = python_env(OMP_NUM_THREADS="1")
    proc = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2", str(script)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    # Rank 0 wrote the model after checking that both ranks' replicas (network and learned
    # MS-SSIM level weights) are bit-identical.
    single, ddp = _weights(tmp_path / "single" / "model.pt"), _weights(tmp_path / "ddp" / "model.pt")
    # all-reduce sums the two ranks' gradients in another order than one process sums its batch: on
    # a 2-core AMD EPYC one weight of 4,608 ends 1.3e-5 apart after the run (rounding, not a defect)
    for name in single:
        torch.testing.assert_close(ddp[name], single[name], rtol=1e-4, atol=5e-5)
    level = [
        torch.load(tmp_path / run / "model.pt", weights_only=True)["criterion"]["level_weights.logits"]
        for run in ("single", "ddp")
    ]
    assert level[0].abs().sum() > 0  # the weights did train
    torch.testing.assert_close(level[1], level[0], rtol=1e-4, atol=1e-6)


CRASH = textwrap.dedent("""
    import os, sys
    from pathlib import Path
    sys.path.insert(0, {tests!r})
    import msdepth.training.train as train_mod
    from test_train import _params
    if os.environ["RANK"] == "1":
        real = train_mod.MonodepthLoss.forward
        calls = [0]
        def dying(self, *a):
            calls[0] += 1
            if calls[0] == 2:
                raise RuntimeError("rank 1 lost its GPU")
            return real(self, *a)
        train_mod.MonodepthLoss.forward = dying
    pairs = [tuple(Path(p) for p in line.split()) for line in Path({pair_file!r}).read_text().splitlines()]
    out = Path({out!r})
    train_mod.train_variant(_params(batch_size=2, nproc=2, dist_timeout_s=30), "ssim", pairs,
                            train_mod.TrainOutputs(out / "model.pt", out / "ck.pt"),
                            train_mod.TrainOptions(progress=False))
""")


def test_a_crashed_rank_stops_the_job_instead_of_hanging(pairs, tmp_path: Path) -> None:
    pair_file = tmp_path / "pairs.txt"
    pair_file.write_text("".join(f"{a} {b}\n" for a, b in pairs))
    script = tmp_path / "crash.py"
    script.write_text(CRASH.format(tests=str(ROOT / "tests"), pair_file=str(pair_file), out=str(tmp_path)))
    env = python_env(OMP_NUM_THREADS="1")
    proc = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2", str(script)],
        capture_output=True,
        text=True,
        env=env,
        timeout=240,  # far below a hang; the job must end itself
    )
    assert proc.returncode != 0
    assert "rank 1 lost its GPU" in proc.stderr
    assert not (tmp_path / "model.pt").exists()
