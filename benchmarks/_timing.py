"""Side-by-side timing for the benchmarks: warm-up excluded, candidates interleaved, medians.

Interleaving (A, B, C, A, B, C, ...) rather than timing each candidate in a block means that
a noisy neighbour or a CPU frequency change affects every candidate alike. Ratios are taken
per round (candidate / baseline, both timed in the same round) and summarised by their median
and interquartile range, so drift between rounds cancels and the spread that remains is shown.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from typing import Callable

import torch


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


@dataclass(frozen=True)
class Timings:
    """Seconds per call of each candidate, one entry per interleaved round."""

    rounds: dict[str, list[float]]

    def median(self, name: str) -> float:
        return statistics.median(self.rounds[name])

    def medians(self) -> dict[str, float]:
        return {name: self.median(name) for name in self.rounds}

    def ratio(self, name: str, baseline: str) -> tuple[float, float, float]:
        """Median, 25th and 75th percentile of the per-round ratio ``name / baseline``."""
        ratios = sorted(a / b for a, b in zip(self.rounds[name], self.rounds[baseline], strict=True))
        if len(ratios) < 2:
            return ratios[0], ratios[0], ratios[0]
        p25, _, p75 = statistics.quantiles(ratios, n=4, method="inclusive")
        return statistics.median(ratios), p25, p75


def compare(
    candidates: dict[str, Callable[[], object]], device: torch.device, repeats: int = 20, warmup: int = 3
) -> Timings:
    """Time every candidate ``repeats`` times, interleaved, after ``warmup`` untimed calls each."""
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
    return Timings(times)


def table(
    timings: Timings,
    baseline: str,
    unit_scale: float = 1e3,
    unit: str = "ms",
    anchor: str | None = None,
) -> str:
    """Markdown table: median time, and the per-round time ratio to ``baseline`` (median [IQR]);
    with ``anchor``, also the per-round ratio to that candidate (median), a reference beside the
    baseline (e.g. a classic method the candidates are measured against)."""
    extra = (f" time / {anchor} |", "---|") if anchor else ("", "")
    head = f"| candidate | median {unit} | time / {baseline} | IQR of the ratio |{extra[0]}"
    rows = [head, f"|---|---|---|---|{extra[1]}"]
    for name in timings.rounds:
        mid, low, high = timings.ratio(name, baseline)
        row = f"| {name} | {timings.median(name) * unit_scale:.2f} | {mid:.3f} | {low:.3f}-{high:.3f} |"
        if anchor:
            row += f" {timings.ratio(name, anchor)[0]:.1f} |"
        rows.append(row)
    return "\n".join(rows)


def device_from(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)
