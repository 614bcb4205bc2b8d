"""Every stage's wiring in one namespace, for tests and interactive use: ``pipeline.index(params)``.

The stages themselves live in :mod:`msdepth.stages` (one module per stage) and the scripts under
``stages/`` import only their own, so that each stage depends on the code it runs and no more.
No stage may import this module (tests/test_dvc_deps.py checks it): it imports them all.
"""

from __future__ import annotations

from .stages.baselines import BASELINES, baselines
from .stages.baselines_set import baselines_set
from .stages.cache import cache
from .stages.common import (
    CACHE_REPORT,
    CACHED_PAIRS,
    INDEX_DIR,
    PAIR_CACHE,
    checked_run,
    checkpoint_path,
    model_path,
    run_dir,
    run_name,
    run_stage,
    variant_runs,
)
from .stages.compare import compare, mean_headline
from .stages.depth import depth
from .stages.eval_set import eval_set
from .stages.evaluate import SUITES, evaluate, headline
from .stages.figures import figures
from .stages.index import index
from .stages.infer import infer, torch_threads
from .stages.prepare_data import prepare_data
from .stages.rois import rois
from .stages.train import train
from .stages.validate_params import validate_params

__all__ = [
    "BASELINES",
    "CACHED_PAIRS",
    "CACHE_REPORT",
    "INDEX_DIR",
    "PAIR_CACHE",
    "SUITES",
    "baselines",
    "baselines_set",
    "cache",
    "checked_run",
    "checkpoint_path",
    "compare",
    "depth",
    "eval_set",
    "evaluate",
    "figures",
    "headline",
    "index",
    "infer",
    "mean_headline",
    "model_path",
    "prepare_data",
    "rois",
    "run_dir",
    "run_name",
    "run_stage",
    "torch_threads",
    "train",
    "validate_params",
    "variant_runs",
]
