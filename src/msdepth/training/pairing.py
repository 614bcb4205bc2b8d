"""What makes two runs a pair: the same initial weights and the same first batch.

Both loss variants train with the same seeds, and a seed fixes the network's initial weights
(``torch.manual_seed`` before it is built) and the data order and augmentation (generators
seeded from the seed and the epoch). Seed ``s`` of SSIM and seed ``s`` of MS-SSIM then differ only
in the loss, and the comparison may treat them as a pair (:mod:`msdepth.stats`). The
training summary records the evidence (:func:`pairing_record`); the comparison pairs two runs only
where their records agree (:func:`pairing_status`).
"""

from __future__ import annotations

import hashlib
import re
from typing import Any, Iterable, Mapping, Sequence

import torch

PAIRING_KEYS = ("initial_weights_sha256", "first_batch_sha256")


def tensors_sha256(tensors: Iterable[tuple[str, torch.Tensor]]) -> str:
    """sha256 (hex, 16 digits) of named tensors: each name, dtype, shape and bytes, in order.

    Example:
        >>> a = tensors_sha256([("w", torch.zeros(2))])
        >>> a == tensors_sha256([("w", torch.zeros(2))]), a == tensors_sha256([("w", torch.ones(2))])
        (True, False)
    """
    digest = hashlib.sha256()
    for name, t in tensors:
        t = t.detach().to("cpu").contiguous()
        digest.update(f"{name}\0{t.dtype}\0{tuple(t.shape)}\0".encode())
        digest.update(t.numpy().tobytes() if t.dtype != torch.bfloat16 else t.float().numpy().tobytes())
    return digest.hexdigest()[:16]


def _named(batch: Any, prefix: str = "") -> list[tuple[str, torch.Tensor]]:
    """The tensors of a batch (a tensor, or lists / tuples / dicts of them), named by their place."""
    if isinstance(batch, torch.Tensor):
        return [(prefix, batch)]
    if isinstance(batch, dict):
        return [x for k in sorted(batch, key=str) for x in _named(batch[k], f"{prefix}.{k}")]
    if isinstance(batch, (list, tuple)):
        return [x for i, item in enumerate(batch) for x in _named(item, f"{prefix}[{i}]")]
    return []


def pairing_record(model: torch.nn.Module, first_batch: Any) -> dict[str, str]:
    """The run's pairing evidence: hashes of the network's initial weights and of the first
    training batch (its order and augmentation included).

    Example:
        >>> torch.manual_seed(0)  # doctest: +ELLIPSIS
        <torch._C.Generator object at ...>
        >>> record = pairing_record(torch.nn.Linear(2, 1), [torch.ones(1, 2)])
        >>> sorted(record) == sorted(PAIRING_KEYS)
        True
    """
    return {
        "initial_weights_sha256": tensors_sha256(sorted(model.state_dict().items())),
        "first_batch_sha256": tensors_sha256(_named(first_batch)),
    }


SEED_RUN = re.compile(r"/(seed\d+)$")  # a variant's run, "<variant>/seed<S>"


def pairing_status(
    groups: Mapping[str, Sequence[str]], reference: str, summaries: Mapping[str, Mapping]
) -> dict[str, str | None]:
    """Per group other than ``reference``: None when its runs pair seed by seed with the
    reference's (the same seeds, and every pair's training summaries record the same initial
    weights and first batch: :mod:`msdepth.training.pairing`), else why they do not."""

    def records(runs: Sequence[str]) -> dict[str, dict | None] | None:
        keys = [SEED_RUN.search(r) for r in runs]
        if not all(keys):
            return None
        return {k.group(1): (summaries.get(r) or {}).get("pairing") for k, r in zip(keys, runs, strict=True)}

    ref = records(groups[reference])
    out: dict[str, str | None] = {}
    for name, runs in groups.items():
        if name == reference:
            continue
        own = records(runs)
        if own is None or ref is None:
            out[name] = "a baseline is one deterministic run, not a seed of a variant"
        elif sorted(own) != sorted(ref):
            out[name] = "the two variants were trained with different seeds"
        else:
            out[name] = _record_mismatch(own, ref)
    return out


def _record_mismatch(own: Mapping[str, dict | None], ref: Mapping[str, dict | None]) -> str | None:
    """The first seed whose two pairing records disagree, in words; None when all agree."""
    for key in sorted(own):
        a, b = own[key], ref[key]
        if not a or not b:
            return f"{key}: a training summary keeps no pairing record (trained by an older version)"
        if a.get("initial_weights_sha256") != b.get("initial_weights_sha256"):
            return f"{key}: the initial weights differ"
        if a.get("first_batch_sha256") != b.get("first_batch_sha256"):
            return f"{key}: the first training batches differ"
    return None
