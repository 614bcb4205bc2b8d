"""What every stage shares: :func:`run_stage`, run names and the pipeline's paths, each defined here only.

The stages themselves are the scripts ``stages/<name>.py`` that dvc.yaml runs: each parses its
arguments with :func:`run_stage` and calls the logic in the package. No module of the package
imports a stage script. This module imports only the config and the errors (no numpy, no
torch) at its top, and :mod:`msdepth.io` in :func:`run_stage`: every stage imports it, so whatever
it imports is every stage's dependency.
"""

from __future__ import annotations

import argparse
import hashlib
import inspect
import logging
import os
import sys
import time
import typing
from pathlib import Path
from typing import Annotated, Callable

from msdepth.config.params import Params, load_params
from msdepth.errors import ConfigError, MsdepthError, unexpected_error
from msdepth.readers import read_text_file

log = logging.getLogger("msdepth")

# The pipeline's files that its stages pass to each other, defined here only: dvc.yaml's lines
# that name them end in `# = NAME` (or `# = model_path(RUN)`), and `python -m msdepth.pipeline.dvcyaml`
# writes their paths from these definitions.
CHECKED = Path("data/params_checked.txt")
# <x>.txt: what stages/<x>.py's code does (the fingerprints stage's; msdepth.pipeline.fingerprints)
FINGERPRINTS = Path("data/fingerprints")
INDEX_DIR = Path("data/index")
TRAIN_PAIRS = INDEX_DIR / "train_pairs.txt"
EVAL_FRAMES = INDEX_DIR / "eval_frames.csv"
SET_INDEXES = INDEX_DIR / "sets"  # <set>.csv per eval.extra_sets (msdepth.data.eval_index.set_index_path)
INDEX_REPORT = INDEX_DIR / "report.json"
ROIS = INDEX_DIR / "rois.csv"
ROI_SHEET = INDEX_DIR / "rois.png"
SET_ROIS = INDEX_DIR / "set_rois"  # <set>.csv and <set>.png per eval.extra_sets (msdepth.data.rois)
PAIR_CACHE = Path("data/cache/train_pairs.npy")
CACHED_PAIRS = Path("data/cache/train_pairs.txt")
CACHE_REPORT = Path("data/cache/report.json")
# model.pretrained's path and content hash (the pretrained stage's record, a dep of train).
PRETRAINED = Path("data/pretrained.json")
SUITE_NAMES = ("full", "roi", "gradients")
MODELS = Path("models")
CHECKPOINTS = Path("checkpoints")
OUTPUTS = Path("outputs")
METRICS = Path("metrics")  # <suite>/<run>.json|csv: see suite_path
HEADLINE = METRICS / "headline"  # the DVC metrics: <suite>/<run>.json, see headline_path
TRAIN_SUMMARIES = METRICS / "train"  # <run>.json: the train stage's summaries (pose ATE of mono runs)
COST_CURVES = METRICS / "cost_curves"  # <variant>.json: the cost_curves stage's, drawn by figures
# The photometry stage's outputs (metrics/photometry/).
PHOTOMETRY_SUMMARY = METRICS / "photometry" / "summary.json"
PHOTOMETRY_TABLE = METRICS / "photometry" / "table.md"
PHOTOMETRY_FRAMES = METRICS / "photometry" / "frames.csv"
COMPARE_JSON = METRICS / "compare.json"
COMPARE_MD = METRICS / "compare.md"
# <variant>.json: per variant its mean over seeds, the compare stage's DVC metrics (see mean_path)
MEANS = HEADLINE / "mean"
PLOTS = Path("plots")
TRAIN_PLOTS = PLOTS / "train"  # <run>/: each run's dvclive curves
FIGURES_DIR = PLOTS / "figures"
TRAIN_LOGS = Path("logs/train")  # <run>.json: training timings (untracked: they vary between machines)
RESULTS = Path("docs/results.md")
# The shared real KITTI frames through the pipeline's set stages (a study apart: a user's clone has no
# real frames); the README shows its rows beside the committed run's, never pooled with them. Not a
# DVC dependency (no stage reads below studies/; a project copy may lack it; the README is no stage's
# output): tests/test_report.py keeps the committed README current with it.
REAL_SETS_COMPARE = Path("studies/results/real_sets/compare.json")
README = Path("README.md")  # not a DVC output: the report stage rewrites only its generated block
# The folders that only the stages write: a stage removes the temp files that a stage killed
# mid-write (kill -9) left there before it runs. The data roots are not walked (a KITTI tree is
# 175 GB); the renderer and the downloader remove their own temps there.
STAGE_OUTPUT_ROOTS = (INDEX_DIR, PAIR_CACHE.parent, MODELS, CHECKPOINTS, OUTPUTS, METRICS, PLOTS)

# The validate_params stage's CHECKED: the same bytes whatever the params, so the stages after it
# re-run only for the params keys (and code) they list themselves, never because this file changed.
CHECKED_TEXT = (
    "params.yaml passed msdepth.config.load_params (types, ranges, no unknown keys).\n"
    "This file's content never changes: the stages that depend on it re-run for their own params.\n"
)


def write_checked(path: Path = CHECKED) -> None:
    """Write :data:`CHECKED_TEXT` to ``path`` unless it holds it already (then it is left alone)."""
    if not path.is_file() or read_text_file(path, "stage mark") != CHECKED_TEXT:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(CHECKED_TEXT)


# The command-line arguments of the per-run stages (see _stage_parser).
VariantArg = Annotated[str, "a loss variant listed in params.yaml's variants (e.g. ssim, msssim)"]
SeedArg = Annotated[str, "a training seed listed in train.seeds"]


def run_name(variant: str, seed: int) -> str:
    """One training run: ``<variant>/seed<seed>``, also its path below models/, outputs/, metrics/<suite>/."""
    return f"{variant}/seed{seed}"


OPTIMUM = "optimum"  # the optimum's runs: optimum/<variant>/w<weight>, below outputs/ and metrics/<suite>/


def optimum_run(variant: str, weight: str) -> str:
    """The optimum's run of one variant and smoothness weight, named like a trained run's
    ``<variant>/seed<seed>``: ``optimum/<variant>/w<weight>`` (``weight`` as dvc.yaml writes it)."""
    return f"{OPTIMUM}/{variant}/w{weight}"


MATCH = "match"  # SGM on a variant's own cost volume: run optimum/match/<variant>
SGBM = "sgbm"  # OpenCV's SGBM (the matchers' rows beside the optimum's; msdepth.optimum.frames)
SGBM_RUN = f"{OPTIMUM}/{SGBM}"
MatcherArg = Annotated[str, f"a variant listed in params.yaml's variants (SGM on its own cost) or {SGBM}"]


def match_run(matcher: str) -> str:
    """A matcher's run, no refinement, below the optimum's: :data:`SGBM_RUN` for ``sgbm``, else
    ``optimum/match/<variant>`` (SGM on that variant's own cost volume)."""
    return SGBM_RUN if matcher == SGBM else f"{OPTIMUM}/{MATCH}/{matcher}"


def checked_run(params: Params, variant: str, seed: str) -> str:
    """The run of a stage's ``VARIANT SEED`` arguments, a ConfigError if either is not configured."""
    return run_name(params.variant(variant), params.seed(seed))


def variant_runs(params: Params) -> dict[str, list[str]]:
    """``{variant: [its run of every seed in train.seeds]}``."""
    return {v: [run_name(v, s) for s in params.train.seeds] for v in params.variants}


SetArg = Annotated[str, "an evaluation set listed in eval.extra_sets (e.g. eigen)"]
SETS_METRICS = METRICS / "sets"  # <set>/full/<run>.json: see set_metrics_dir
SETS_HEADLINE = HEADLINE / "sets"  # <set>/full/<run>.json: see set_headline_dir


def checked_set(params: Params, name: str) -> str:
    """``name`` if it is in ``eval.extra_sets``, else a ConfigError naming them."""
    if name not in params.eval.extra_sets:
        raise ConfigError(f"evaluation set {name!r} is not in eval.extra_sets {list(params.eval.extra_sets)}")
    return name


def model_path(run: str) -> Path:
    """A run's trained model (the train stage's output)."""
    return MODELS / run / "model.pt"


def checkpoint_path(run: str) -> Path:
    """A run's per-epoch checkpoint: resume state, not a DVC output."""
    return CHECKPOINTS / run / "checkpoint.pt"


def run_dir(run: str, root: Path = OUTPUTS) -> Path:
    """A run's folder of predictions below ``root`` (:data:`OUTPUTS`; another tree's in tests)."""
    return Path(root) / run


def disparities_path(run: str, root: Path = OUTPUTS) -> Path:
    """A run's disparities of the evaluation frames (the infer stage's output)."""
    return run_dir(run, root) / "disparities.npy"


def depth_path(run: str, root: Path = OUTPUTS) -> Path:
    """A run's metric depth maps at GT resolution (the depth stage's output)."""
    return run_dir(run, root) / "depth.npz"


def suite_dir(suite: str, root: Path = METRICS) -> Path:
    """The folder of one suite's files below a metrics tree (:data:`METRICS`, or an extra set's)."""
    return Path(root) / suite


def suite_path(suite: str, run: str, suffix: str = ".json", root: Path = METRICS) -> Path:
    """A run's file of one suite: its summary (``.json``) or per-unit table (``.csv``)."""
    return suite_dir(suite, root) / f"{run}{suffix}"


def headline_path(suite: str, run: str, root: Path = HEADLINE) -> Path:
    """A run's headline numbers of one suite, the DVC metric (below :data:`HEADLINE`, or an extra set's)."""
    return Path(root) / suite / f"{run}.json"


def mean_path(variant: str, root: Path = MEANS) -> Path:
    """A variant's mean over its seeds, one flat row of ``dvc metrics show`` (the compare stage's)."""
    return Path(root) / f"{variant}.json"


def set_metrics_dir(name: str) -> Path:
    """The metrics tree of extra evaluation set ``name`` (its suite: ``full``)."""
    return SETS_METRICS / name


def set_headline_dir(name: str) -> Path:
    """The headline tree of extra evaluation set ``name``."""
    return SETS_HEADLINE / name


def train_summary_path(run: str) -> Path:
    """A run's training summary (steps, final losses; a monocular run's pose ATE)."""
    return TRAIN_SUMMARIES / f"{run}.json"


def train_plots_dir(run: str, root: Path = TRAIN_PLOTS) -> Path:
    """A run's dvclive folder of per-epoch losses."""
    return Path(root) / run


def train_timing_path(run: str) -> Path:
    """A run's training timings (seconds, examples/s), kept out of the tracked summary."""
    return TRAIN_LOGS / f"{run}.json"


def cost_curves_path(variant: str, root: Path = COST_CURVES) -> Path:
    """A variant's cost-curve summary (the cost_curves stage's)."""
    return Path(root) / f"{variant}.json"


def source_files(package: Path, modules: typing.Sequence[str]) -> list[Path]:
    """The files of ``modules`` (paths below ``package``, the ``msdepth`` folder), each package
    expanded to its sorted .py files."""
    files: list[Path] = []
    for name in modules:
        path = package / name
        files.extend(sorted(path.rglob("*.py")) if path.is_dir() else [path])
    return files


def source_digest(package: Path, modules: typing.Sequence[str]) -> str:
    """Hash (hex, 16 digits) of the source of ``modules`` (:func:`source_files`), each file under its
    path below ``package``: part of every resume key (a training checkpoint's fingerprint, an optimum
    set stage's scratch key), so that state written by other code is never resumed."""
    digest = hashlib.sha256()
    for path in source_files(package, modules):
        digest.update(path.relative_to(package).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def _stage_parser(fn: Callable[..., None]) -> argparse.ArgumentParser:
    """The command line of stage function ``fn(params, ...)``, built from its signature.

    Positional parameters after ``params`` become positional arguments (``VARIANT``); keyword-only
    booleans become flags (``dry_run`` -> ``--dry-run``). Help texts come from
    ``Annotated[str, "help"]`` annotations, the description from the docstring.
    """
    hints = typing.get_type_hints(fn, include_extras=True)
    parser = argparse.ArgumentParser(
        prog=f"stages/{Path(inspect.getfile(fn)).name}",
        description=inspect.getdoc(fn),
        epilog="Reads params.yaml in the working directory; run by `dvc repro` (see dvc.yaml).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    for name, param in list(inspect.signature(fn).parameters.items())[1:]:
        extras = typing.get_args(hints.get(name))
        help_text = extras[1] if len(extras) > 1 else None
        if param.kind is inspect.Parameter.KEYWORD_ONLY:
            parser.add_argument(f"--{name.replace('_', '-')}", action="store_true", dest=name, help=help_text)
        else:
            parser.add_argument(name, metavar=name.upper(), help=help_text)
    return parser


def run_stage(fn: Callable[..., None], *args: str, params_path: str | os.PathLike = "params.yaml") -> int:
    """Parse a stage's arguments, load params, run the stage, report errors as one line.

    Before the stage runs, the temp files that a stage killed mid-write left under
    :data:`STAGE_OUTPUT_ROOTS` are removed (only names of :func:`msdepth.io.atomic_path`'s form).

    Returns the exit code: 0 (also for ``--help``, which runs nothing), 1 for the project's errors
    and for any other exception (one line naming the stage, its traceback in a log file:
    :func:`msdepth.errors.unexpected_error`), 2 for a usage error.
    """
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", stream=sys.stderr)
    try:
        parsed = vars(_stage_parser(fn).parse_args(args))
    except SystemExit as exc:  # --help (0) or a usage error (2), already printed by argparse
        return int(exc.code or 0)
    parameters = list(inspect.signature(fn).parameters.values())[1:]
    positional = [parsed.pop(p.name) for p in parameters if p.kind is not inspect.Parameter.KEYWORD_ONLY]
    if "LOCAL_RANK" not in os.environ:  # torchrun's ranks start after their launcher did this
        from msdepth.io import remove_stale_temps

        for root in STAGE_OUTPUT_ROOTS:
            remove_stale_temps(root)
    started = time.perf_counter()
    try:
        fn(load_params(params_path), *positional, **parsed)
    except MsdepthError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # a bug: one line naming the stage, the traceback in a log file
        print(unexpected_error(f"stage {fn.__name__}", exc, args), file=sys.stderr)
        return 1
    log.info(
        "%s%s done in %.1f s",
        fn.__name__,
        f" {' '.join(args)}" if args else "",
        time.perf_counter() - started,
    )
    return 0
