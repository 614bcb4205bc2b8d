"""Each loss at its own best smoothness weight, chosen on frames it is not scored on (two folds).

The two appearance terms have different scales, so one smoothness weight regularises them
differently, and the order of the losses can flip with it (docs/optimum.md's sweep). A fair
comparison lets each loss have its best weight of ``optimum.smoothness_sweep``; choosing it on the
frames it is then scored on would favour whichever loss varies more. So the frames (sorted by name)
are split into two folds by position (even, odd); each fold's frames are scored at the weight that
had the lowest mean error on the other fold. Every frame is scored once, and no frame chose its own
weight.
"""

from __future__ import annotations

from typing import Mapping

import pandas as pd

FOLDS = 2


def fold_of(frames: list[str]) -> dict[str, int]:
    """Each frame's fold: its position among the sorted names, modulo :data:`FOLDS`.

    Example:
        >>> fold_of(["000002_10", "000000_10", "000001_10"])
        {'000000_10': 0, '000001_10': 1, '000002_10': 0}
    """
    return {frame: i % FOLDS for i, frame in enumerate(sorted(frames))}


def choose_weights(
    per_weight: Mapping[float, pd.DataFrame], frame: str = "frame", metric: str = "abs_rel"
) -> tuple[dict[str, float], dict[int, float]]:
    """Which weight scores each frame: ``({frame: weight}, {fold: the weight chosen on the other folds})``.

    ``per_weight``: per smoothness weight, one row per frame (column ``frame``) with its error
    (``metric``; lower is better), every weight holding the same frames. Ties go to the smaller weight.

    Example:
        >>> import pandas as pd
        >>> rows = lambda *e: pd.DataFrame({"frame": ["a", "b", "c", "d"], "abs_rel": e})
        >>> frames, chosen = choose_weights({3.0: rows(1, 9, 1, 9), 10.0: rows(2, 2, 2, 2)})
        >>> chosen  # fold 0 (a, c) is scored at the weight fold 1 (b, d) prefers, and back
        {0: 10.0, 1: 3.0}
        >>> frames
        {'a': 10.0, 'b': 3.0, 'c': 10.0, 'd': 3.0}
    """
    if not per_weight:
        raise ValueError("choose_weights: no weight to choose from")
    sets = {w: frozenset(t[frame]) for w, t in per_weight.items()}
    names = next(iter(sets.values()))
    if any(s != names for s in sets.values()) or len(names) < FOLDS:
        raise ValueError(f"choose_weights: every weight needs the same >= {FOLDS} frames, got {len(names)}")
    folds = fold_of(list(names))
    chosen = {}
    for fold in range(FOLDS):
        means = {
            w: float(t.loc[t[frame].map(folds) != fold, metric].mean()) for w, t in sorted(per_weight.items())
        }
        chosen[fold] = min(means, key=lambda w: (means[w], w))
    return {name: chosen[folds[name]] for name in sorted(names)}, chosen


def select_rows(
    per_weight: Mapping[float, pd.DataFrame], weights: Mapping[str, float], frame: str = "frame"
) -> pd.DataFrame:
    """The rows of each frame (column ``frame``) from the table of its weight (``weights``), in the
    order of the first weight's table: a frame's ROI rows, say, from the weight that scores it.

    Example:
        >>> import pandas as pd
        >>> t = {w: pd.DataFrame({"image": ["a", "a", "b"], "e": [w, w, w]}) for w in (3.0, 10.0)}
        >>> select_rows(t, {"a": 10.0, "b": 3.0}, frame="image")["e"].tolist()
        [10.0, 10.0, 3.0]
    """
    first = next(iter(per_weight.values()))
    parts = [table[table[frame].map(weights) == weight] for weight, table in per_weight.items()]
    picked = pd.concat(parts).reindex(first.index) if parts else first.iloc[0:0]
    return picked.dropna(how="all").reset_index(drop=True)
