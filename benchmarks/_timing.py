"""Side-by-side timing for the benchmarks: warm-up excluded, candidates interleaved, medians.

Interleaving (A, B, C, A, B, C, ...) rather than timing each candidate in a block means that
a noisy neighbour or a CPU frequency change affects every candidate alike, so the printed
*ratios* are meaningful even when absolute times drift.
"""

from __future__ import annotations

import statistics
import time
from typing import Callable

import torch


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def compare(
    candidates: dict[str, Callable[[], object]], device: torch.device, repeats: int = 20, warmup: int = 3
) -> dict[str, float]:
    """Median seconds per call of each candidate, measured interleaved."""
    for fn in candidates.values():
        for _ in range(warmup):
            fn()
    sync(device)
    times: dict[str, list[float]] = {name: [] for name in candidates}
    for _ in range(repeats):
        for name, fn in candidates.items():
            sync(device)
            start = time.perf_counter()
            fn()
            sync(device)
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(t) for name, t in times.items()}


def table(medians: dict[str, float], baseline: str, unit_scale: float = 1e3, unit: str = "ms") -> str:
    """Markdown table: median time and speed relative to ``baseline`` (>1 = faster than it)."""
    rows = [f"| candidate | median {unit} | time / {baseline} |", "|---|---|---|"]
    for name, t in medians.items():
        rows.append(f"| {name} | {t * unit_scale:.2f} | {t / medians[baseline]:.3f} |")
    return "\n".join(rows)


def device_from(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)
