"""Data-parallel training under ``torchrun``: process group, sharded batches, rank checks.

One process (the default) and N processes run the same code path. Under ``torchrun``
(``WORLD_SIZE`` > 1) every rank takes a contiguous slice of each *global* batch, so N ranks with
batch B see exactly the batches a single process with batch N·B sees, and DDP's gradient average
equals the single-process gradient (no batch norm in the model).
"""

from __future__ import annotations

import datetime
import gc
import logging
import os
import subprocess
import sys
from dataclasses import dataclass
from typing import Iterator, Sequence

import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import Sampler

from msdepth.errors import MsdepthError

log = logging.getLogger("msdepth")


@dataclass(frozen=True)
class Context:
    """This process's place in the job (rank 0 of 1 when not distributed)."""

    rank: int = 0
    world: int = 1
    local_rank: int = 0

    @property
    def main(self) -> bool:
        """Only the main rank writes checkpoints, logs, models and metrics."""
        return self.rank == 0


def must_relaunch(launcher: str) -> bool:
    """Whether this process must re-run its script under ``torchrun`` (``train.launcher``): it is not
    one of torchrun's ranks, which start with ``LOCAL_RANK`` set."""
    return launcher == "torchrun" and "LOCAL_RANK" not in os.environ


def relaunch(script: str, args: Sequence[str], nproc: int, what: str) -> None:
    """Run ``script args`` under ``torchrun`` with ``nproc`` processes on this node and wait for them;
    an MsdepthError naming ``what`` if any fails (their errors are above it)."""
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        f"--nproc_per_node={nproc}",
        script,
        *args,
    ]
    log.info("%s: %s", what, " ".join(cmd))
    if subprocess.run(cmd).returncode != 0:
        raise MsdepthError(f"{what}: torchrun with {nproc} processes failed (see the ranks' errors above)")


def is_main_process() -> bool:
    """Whether this process is rank 0 of a ``torchrun`` job, or runs alone (before :func:`setup` too)."""
    return int(os.environ.get("RANK", "0")) == 0


def setup(device: torch.device, timeout_s: float) -> tuple[Context, torch.device]:
    """Join the ``torchrun`` process group if there is one; returns the context and this rank's device.

    ``timeout_s`` bounds every collective: a rank that died or hangs makes the others fail with
    an error after that long instead of waiting forever.
    """
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Context(), device
    rank, local_rank = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", "0"))
    if device.type == "cuda":
        device = torch.device("cuda", local_rank)
        torch.cuda.set_device(device)
    if not dist.is_initialized():
        backend = "nccl" if device.type == "cuda" else "gloo"
        dist.init_process_group(backend, timeout=datetime.timedelta(seconds=timeout_s))
    return Context(rank, world, local_rank), device


def teardown() -> None:
    """Leave the process group (if this process joined one), once every rank is done with it.

    The barrier keeps a rank from tearing its connections down while another still works (rank
    0 saves the model last). ``gc.collect()`` then frees what still holds the group (a dropped
    DDP wrapper's reducer sits in reference cycles), so gloo's threads stop while the interpreter
    is alive: left to interpreter exit, their teardown can abort a process whose work is done
    (seen once in CI: SIGABRT, "terminate called without an active exception", after training).
    """
    if dist.is_initialized():
        dist.barrier()
        gc.collect()
        dist.destroy_process_group()
        gc.collect()


class GlobalBatchSampler(Sampler[int]):
    """This rank's share of each global batch of one epoch's shuffle.

    The shuffle is ``torch.randperm(n, generator)``, the permutation a shuffling DataLoader with
    that generator draws, so one process gives exactly the batches it always did. Global batch
    ``b`` is ``perm[b·G:(b+1)·G]`` (G = batch · world) and rank ``r`` takes its r-th slice.
    Incomplete last batches are dropped (unless the data set is smaller than one global batch).
    """

    def __init__(self, n: int, batch: int, ctx: Context, generator: torch.Generator) -> None:
        self.n, self.batch, self.ctx, self.generator = n, batch, ctx, generator
        self.global_batch = batch * ctx.world
        if n < self.global_batch and ctx.world > 1:
            raise MsdepthError(f"{n} training pairs cannot fill one global batch of {self.global_batch}")

    def __len__(self) -> int:
        full = self.n // self.global_batch
        return full * self.batch if full else self.n

    def __iter__(self) -> Iterator[int]:
        perm = torch.randperm(self.n, generator=self.generator).tolist()
        full = self.n // self.global_batch
        if not full:  # a data set smaller than one batch: one short batch (single process only)
            yield from perm
            return
        for b in range(full):
            start = b * self.global_batch + self.ctx.rank * self.batch
            yield from perm[start : start + self.batch]


def average_gradients(module: nn.Module, ctx: Context) -> None:
    """Average the gradients of a module that DDP does not wrap (e.g. learned loss weights)."""
    if ctx.world <= 1:
        return
    for p in module.parameters():
        if p.grad is not None:
            dist.all_reduce(p.grad, op=dist.ReduceOp.SUM)
            p.grad /= ctx.world


def mean_over_ranks(values: dict[str, float], ctx: Context) -> dict[str, float]:
    """Average per-rank numbers (epoch loss means) over the ranks."""
    if ctx.world <= 1:
        return values
    t = torch.tensor(list(values.values()), dtype=torch.float64)
    dist.all_reduce(t, op=dist.ReduceOp.SUM)
    return dict(zip(values, (t / ctx.world).tolist(), strict=True))


def check_replicas(modules: list[nn.Module], ctx: Context) -> None:
    """Raise if the ranks' parameters differ: they must stay bit-identical under DDP."""
    if ctx.world <= 1:
        return
    # On the parameters' device: NCCL only reduces GPU tensors.
    flat = torch.cat([p.detach().double().flatten() for m in modules for p in m.parameters()])
    reference = flat.clone()
    dist.broadcast(reference, src=0)
    diff = (flat - reference).abs().max().reshape(1)
    dist.all_reduce(diff, op=dist.ReduceOp.MAX)
    if diff.item() != 0.0:
        raise MsdepthError(
            f"rank {ctx.rank}: model replicas differ across ranks (max |diff| {diff.item():.3g})"
        )
