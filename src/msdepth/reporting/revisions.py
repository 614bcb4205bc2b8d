"""Committed results at git revisions, paired: what the studies that compare two or more
revisions of the repository read (studies/optimum_kernels.py, studies/glass_before_after.py).

A revision is anything ``git show`` takes (a commit, a branch, an experiment's ref); its
``metrics/`` and ``params.yaml`` are read from git in the current folder, not from the workspace.
"""

from __future__ import annotations

import io
import json
import subprocess

import pandas as pd

from msdepth.config.params_yaml import parse as parse_yaml
from msdepth.errors import DataError
from msdepth.reporting.comparison import UNIT_KEYS, difference_cell, unit_clusters
from msdepth.reporting.stats import paired_table, seed_bootstrap

CAP = 80  # m: the cap of every table the studies print


def show(ref: str, path: str) -> str:
    """The text of ``path`` at git revision ``ref`` of the repository in the current folder."""
    out = subprocess.run(["git", "show", f"{ref}:{path}"], capture_output=True, text=True)
    if out.returncode:
        raise DataError(f"{ref}:{path}: {out.stderr.strip()}")
    return out.stdout


def optimum_run_at(ref: str, variant: str, weight: str) -> dict:
    """One optimum run at ``ref``: its per-frame and per-ROI tables and the masks' abs_rel at :data:`CAP`."""
    stem = f"optimum/{variant}/w{weight}"
    full = pd.read_csv(io.StringIO(show(ref, f"metrics/full/{stem}.csv")))
    roi = pd.read_csv(io.StringIO(show(ref, f"metrics/roi/{stem}.csv")))
    masks = json.loads(show(ref, f"metrics/roi/{stem}.json"))["masks"][f"cap{CAP}"]
    return {"full": full[full["cap"] == CAP], "roi": roi[roi["cap"] == CAP], "masks": masks}


def optimum_settings_at(ref: str) -> dict:
    """The optimum's weights and the MS-SSIM settings in ``ref``'s params.yaml."""
    params = parse_yaml(show(ref, "params.yaml"))  # the params reader's parser
    weights = sorted({params["optimum"]["smoothness_weight"], *params["optimum"]["smoothness_sweep"]})
    return {
        "kernel": params["msssim"]["kernel_size"],
        "levels": params["msssim"]["levels"],
        "weights": weights,
    }


def paired_cell(run: pd.DataFrame, ref: pd.DataFrame, keys: list[str], what: str) -> str:
    """``mean(run - ref)`` of abs_rel over the units paired on ``keys``, with its 95 % interval
    (:func:`msdepth.reporting.comparison.difference_cell`); ``–`` where ``run`` has no unit. ROIs
    (``keys`` the ROI suite's) are drawn with their frame, as the pipeline's comparison draws them
    (:func:`msdepth.reporting.comparison.unit_clusters`)."""
    if run.empty:
        return "–"
    values, reference = paired_table(run, ref, keys, "abs_rel", what)
    clusters = unit_clusters("roi", run) if keys == UNIT_KEYS["roi"] else None  # in run's row order
    return difference_cell(seed_bootstrap(values[None], reference[None], clusters=clusters).as_dict())
