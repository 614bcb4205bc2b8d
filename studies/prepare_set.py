"""A study's own project folder: params.yaml with overrides, the rendered set, index, ROIs, cache.

What ``dvc repro cache rois`` leaves in the repository, made elsewhere and at other sizes, so a
study (``studies/learning.py``, run with that folder as its working directory) can screen e.g. a
larger render and input without touching the committed default run::

    python studies/prepare_set.py --out /tmp/big --set data.synthetic.height=250 \\
        --set data.synthetic.width=828 --set data.height=128 --set data.width=416
    cd /tmp/big && python <repo>/studies/learning.py --variants ssim --seeds 0 --out results
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from msdepth.config.params import Params, apply_overrides, params_from_dict, read_params_file
from msdepth.errors import MsdepthError, run_main
from msdepth.io import write_text
from msdepth.outputs import OutputPolicy, resolved
from msdepth.render import generate

ROOT = Path(__file__).resolve().parents[1]  # its params.yaml and stages/


def outputs(out: Path, params: Params) -> list[Path]:
    """Every file the study writes or replaces under ``out`` outside the data tree: params.yaml and
    the index, rois and cache stages' outputs (the extra sets' included, listed or not)."""
    from msdepth.data.eval_index import set_index_path, set_rois_path
    from msdepth.pipeline import paths

    files = [paths.TRAIN_PAIRS, paths.EVAL_FRAMES, paths.INDEX_REPORT, paths.ROIS, paths.ROI_SHEET]
    files += [paths.PAIR_CACHE, paths.CACHED_PAIRS, paths.CACHE_REPORT]
    for name in params.eval.extra_sets:
        rois = set_rois_path(paths.INDEX_DIR, name)
        files += [set_index_path(paths.INDEX_DIR, name), rois, rois.with_suffix(".png")]
    removed = sorted((out / paths.SET_INDEXES).glob("*.csv"))
    return list(dict.fromkeys([out / "params.yaml", *(out / f for f in files), *removed]))


def prepare(out: Path, assignments: list[str]) -> None:
    """Write ``out/params.yaml`` (the repository's, with ``assignments``), then render, index,
    find the ROIs and cache the training pairs there, as the pipeline's first stages do."""
    import os
    import runpy

    raw = apply_overrides(read_params_file(ROOT / "params.yaml"), assignments)
    params = params_from_dict(raw)  # checked before anything is written
    # Through the output policy (manifest out/.msdepth-prepare-set): a file at an output name that the
    # study did not write (e.g. --out naming a project) is refused in one line (OutputError) before
    # anything is written. The data tree is generate()'s to guard: it renders only into its own.
    OutputPolicy(out, "prepare-set").claim(outputs(out, params), ROOT / "params.yaml")
    write_text(out / "params.yaml", yaml.safe_dump(raw, sort_keys=False))
    os.chdir(out)  # the pipeline's paths are relative to the project folder
    generate(params.data.synthetic, Path(params.data.root), progress=True)
    for name in ("index", "rois", "cache"):  # the stage scripts' own functions, as dvc repro runs them
        runpy.run_path(str(ROOT / "stages" / f"{name}.py"))[name](params)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="the study's project folder")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    try:
        prepare(resolved(args.out), args.set)
    except (MsdepthError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/prepare_set.py", main))
