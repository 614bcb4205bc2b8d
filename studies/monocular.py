"""Monodepth2's monocular (M) and mono+stereo (MS) training beside stereo, with SSIM and MS-SSIM.

Issue 30's closing study. From a checkout whose workspace holds the stereo results of its params
(``dvc repro`` or ``dvc pull`` done, ``params.yaml`` and ``dvc.lock`` unchanged), it snapshots the
stereo runs, then per monocular mode runs every variant and seed of ``params.yaml`` as

    dvc exp run -n mono-study-<mode> -S train.mode=<mode> -S data.synthetic.sequence_length=<L> [-S ...]

snapshots it under ``--out``/runs/<mode>/ (a mode already there is not run again), puts the
workspace back to the stereo results, and writes ``--out``/table.md (per mode and variant, mean ±
sd over seeds of full-frame abs_rel, median-scaled for M and MS, ROI abs_rel per class, image
dependence, pose ATE, training time), table.json (the same per seed) and disparities.png::

    python studies/monocular.py                                   # the study (hours: see table.md)
    python studies/monocular.py --modes mono --set train.epochs=1 # any -S of every experiment

The pipeline's compare stage reads neither table: its verdict holds only what ``dvc repro`` computes.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from msdepth.analysis.comparison import variant_settings
from msdepth.analysis.runs import image_dependence
from msdepth.analysis.verdict import FULL_FRAME, settings_label
from msdepth.config.params import params_from_dict, read_params_file
from msdepth.errors import OutputError, run_main
from msdepth.evaluation.results import load_suite_metrics, load_unit_tables
from msdepth.io import write_text
from msdepth.outputs import OutputPolicy
from msdepth.reporting.comparison import markdown_table
from msdepth.reporting.figures import write_figure

ROOT = Path(__file__).resolve().parents[1]
SETTINGS_LINE = "Variant settings: "  # table.md's line naming what its runs were trained with

MODES = ("mono", "mono_stereo")
CLASSES = ("car", "windshield", "glass", "sign")
SNAPSHOT = ("metrics/full", "metrics/roi", "metrics/train", "metrics/compare.md")
# What an experiment rewrites in the workspace that git holds: checked clean first, restored after.
# (The report stage rewrites README.md's results block and docs/results.md.)
# What the study writes at the top of --out (its manifest: .msdepth-monocular); runs/ holds snapshots.
OUTPUTS = ("table.md", "table.json", "disparities.png")
RESTORED = ("params.yaml", "dvc.lock", "metrics", "plots", "README.md", "docs/results.md")


def sh(cmd: list[str], cwd: Path) -> str:
    """Run ``cmd`` in ``cwd``; its stdout, or exit with its error."""
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(f"error: {' '.join(cmd)} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}")
    return proc.stdout


def runs_of(params: dict) -> list[str]:
    """Every variant's run of every seed (the pipeline's ``<variant>/seed<seed>``)."""
    return [f"{v}/seed{s}" for v in params["variants"] for s in params["train"]["seeds"]]


def snapshot(repo: Path, dest: Path, runs: list[str]) -> None:
    """Copy the workspace's metrics, each run's evaluation disparities and training timing to ``dest``."""
    # A fresh folder of our own next to dest (never a fixed name, which could be a user's folder).
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", suffix=".partial", dir=dest.parent))
    try:
        copy_snapshot(repo, tmp, runs)
        tmp.rename(dest)  # a complete snapshot or none
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def copy_snapshot(repo: Path, tmp: Path, runs: list[str]) -> None:
    """Copy what :func:`snapshot` keeps from ``repo`` into the empty folder ``tmp``."""
    for rel in SNAPSHOT:
        src = repo / rel
        if src.is_dir():
            shutil.copytree(src, tmp / rel)
        elif src.is_file():
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(src, tmp / rel)
    for run in runs:
        for rel in (f"outputs/{run}/disparities.npy", f"logs/train/{run}.json"):
            if (repo / rel).is_file():
                (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy(repo / rel, tmp / rel)
    shutil.copy(repo / "params.yaml", tmp / "params.yaml")


def run_mode(repo: Path, mode: str, length: int, sets: list[str], dest: Path, runs: list[str]) -> None:
    """One experiment of ``mode``, snapshotted to ``dest``, then the workspace's stereo results back."""
    overrides = ["-S", f"train.mode={mode}", "-S", f"data.synthetic.sequence_length={length}"]
    for assignment in sets:
        overrides += ["-S", assignment]
    print(f"dvc exp run {mode} ...", flush=True)
    before = files_under(repo, RESTORED[2:])
    try:
        sh(
            [sys.executable, "-m", "dvc", "exp", "run", "--quiet", "-n", f"mono-study-{mode}", *overrides],
            repo,
        )
        snapshot(repo, dest, runs)
    finally:
        sh(["git", "checkout", "--", *RESTORED], repo)
        for path in files_under(repo, RESTORED[2:]) - before:  # e.g. dvclive's automask.tsv of M runs
            path.unlink()
        sh([sys.executable, "-m", "dvc", "checkout", "--quiet"], repo)


def files_under(repo: Path, folders: tuple[str, ...]) -> set[Path]:
    """Every file below ``folders`` of ``repo``."""
    return {p for f in folders for p in (repo / f).rglob("*") if p.is_file()}


def _mean_sd(values: list[float]) -> str:
    values = [v for v in values if v is not None and np.isfinite(v)]
    if not values:
        return "–"
    sd = f" ± {np.std(values, ddof=1):.4f}" if len(values) > 1 else ""
    return f"{np.mean(values):.4f}{sd}"


def mode_rows(snap: Path, mode: str, params: dict, cap: float) -> list[list[str]]:
    """One table row per variant of the snapshot ``snap`` (the last: its mean training seconds)."""
    runs = runs_of(params)
    groups = {v: [r for r in runs if r.startswith(f"{v}/")] for v in params["variants"]}
    key = f"cap{cap:g}"
    suites = load_suite_metrics(snap / "metrics", [*runs, "prior"], ("full", "roi"))
    tables = load_unit_tables(snap / "metrics", [*runs, "prior"], ("full",))
    dependence = image_dependence(suites, tables, {**groups, "prior": ["prior"]}, "prior", cap)
    rows = []
    for variant, members in groups.items():
        full = [suites["full"][r][key] for r in members]
        roi = [suites["roi"][r][key]["by_class"] for r in members]
        train = [_json(snap / "metrics" / "train" / f"{r}.json") for r in members]
        timing = [_json(snap / "logs" / "train" / f"{r}.json").get("seconds") for r in members]
        seconds = float(np.mean([t for t in timing if t])) if any(timing) else float("nan")
        rows.append(
            [
                mode,
                variant,
                _mean_sd([m["abs_rel"] for m in full]),
                *[_mean_sd([c.get(cls, {}).get("abs_rel") for c in roi]) for cls in CLASSES],
                _mean_sd([dependence[r]["variation_ratio"] for r in members]),
                _mean_sd([dependence[r]["prior_correlation"] for r in members]),
                _mean_sd([m.get("median_scaling", {}).get("ratio_median") for m in full]),
                _mean_sd([t.get("pose", {}).get("ate_mean") for t in train]),
                f"{seconds:.0f}",
            ]
        )
    return rows


def scaled_stereo_rows(repo: Path, params: dict, cap: float) -> list[list[str]]:
    """Per variant, the stereo runs of ``repo``'s workspace median-scaled per image as the monocular
    runs are, so the modes compare on shape alone (:func:`table`'s columns, ``–`` for pose)."""
    import os

    from msdepth.config.params import load_params
    from msdepth.data import kitti
    from msdepth.data.eval_index import read_eval_index
    from msdepth.evaluation.suites import (
        evaluate_full,
        evaluate_roi,
        load_frames,
        median_scaled_maps,
        read_depth_maps,
    )
    from msdepth.pipeline.paths import EVAL_FRAMES, ROIS, depth_path

    here, key, rows = Path.cwd(), f"cap{cap:g}", []
    os.chdir(repo)  # the index names its files relative to the project
    try:
        cfg = load_params("params.yaml").eval
        frames, boxes = load_frames(read_eval_index(EVAL_FRAMES)), kitti.read_rois(ROIS)
        for variant in params["variants"]:
            full, roi = [], []
            for run in [r for r in runs_of(params) if r.startswith(f"{variant}/")]:
                pred = read_depth_maps(depth_path(run))
                full.append(evaluate_full(pred, frames, cfg, median_scaling=True)[0][key])
                roi.append(evaluate_roi(median_scaled_maps(pred, frames, cfg)[0], frames, boxes, cfg)[0][key])
            by_class = [r["by_class"] for r in roi]
            rows.append(
                ["stereo, median-scaled", variant, _mean_sd([m["abs_rel"] for m in full])]
                + [_mean_sd([c.get(cls, {}).get("abs_rel") for c in by_class]) for cls in CLASSES]
                + ["–", "–", _mean_sd([m["median_scaling"]["ratio_median"] for m in full]), "–", "–"]
            )
    finally:
        os.chdir(here)
    return rows


def seed_values(snap: Path, params: dict, cap: float) -> dict[str, dict[str, list[float]]]:
    """table.json's values: per variant of ``snap``, each seed's full-frame and per-class ROI abs_rel."""
    runs, key = runs_of(params), f"cap{cap:g}"
    suites = load_suite_metrics(snap / "metrics", runs, ("full", "roi"))
    out: dict[str, dict[str, list[float]]] = {}
    for variant in params["variants"]:
        members = [r for r in runs if r.startswith(f"{variant}/")]
        values = {FULL_FRAME: [suites["full"][r][key]["abs_rel"] for r in members]}
        for cls in CLASSES:
            found = [suites["roi"][r][key]["by_class"].get(cls, {}).get("abs_rel") for r in members]
            if all(v is not None and np.isfinite(v) for v in found):
                values[cls] = found
        out[variant] = values
    return out


def _json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.is_file() else {}


def study_settings(params: dict) -> str:
    """The variants' settings the study's runs were trained with (the verdict's label)."""
    typed = params_from_dict(params)
    return settings_label(variant_settings(typed), typed.variants)


def table(out: Path, modes: list[str], params: dict, cap: float, repo: Path | None = None) -> str:
    """table.md's text from the snapshots under ``out``; with ``repo`` (its workspace holding the
    stereo runs), their median-scaled rows too (:func:`scaled_stereo_rows`)."""
    header = ["mode", "variant", "abs_rel", *[f"ROI {c}" for c in CLASSES], "variation", "corr. prior"]
    header += ["scale ratio", "pose ATE (m)", "train s/run"]
    rows = []
    for mode in ["stereo", *modes]:
        rows += mode_rows(out / "runs" / mode, mode, params, cap)
        if mode == "stereo" and repo is not None:
            rows += scaled_stereo_rows(repo, params, cap)
    lines = markdown_table(header, rows).split("\n")
    prior = _json(out / "runs" / "stereo" / "metrics" / "full" / "prior.json").get(f"cap{cap:g}", {})
    seeds = params["train"]["seeds"]
    return "\n".join(
        [
            f"# Monocular (M), mono+stereo (MS) and stereo training, cap {cap:g} m",
            "",
            f"Mean ± sd over seeds {seeds}. abs_rel: full frame, median-scaled per image for mono and "
            "mono_stereo (scale ratio: the median of the per-image ratios median GT / median prediction). "
            "ROI: abs_rel per class. Variation: how much the prediction changes between images as a "
            "fraction of the GT's (the per-pixel prior's is 0; below 0.25 a run is image-blind); corr. "
            "prior: of the run's per-image abs_rel with the prior's. Pose ATE: Monodepth2's over "
            "5-frame snippets of the training sequences. Stereo, median-scaled: the stereo runs "
            "scored as the monocular ones are (per-image GT scale), to compare the modes on shape. "
            "Train s/run: logs/train/<run>.json, as each run happened; the load of the machine "
            "may differ between runs, so compare modes' speed with `benchmarks/mode_step.py`, which "
            "measures them side by side. "
            "Per-pixel prior's abs_rel: "
            f"{prior.get('abs_rel', float('nan')):.4f}.",
            "",
            f"{SETTINGS_LINE}`{study_settings(params)}`",
            "",
            *lines,
            "",
        ]
    )


def figure(out: Path, repo: Path, modes: list[str], params: dict, frames: int = 3) -> None:
    """disparities.png: per evaluation frame, the image and seed 0's disparity of each mode and variant."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from msdepth.data.kitti import read_image

    index = pd.read_csv(repo / "data" / "index" / "eval_frames.csv")
    seed = params["train"]["seeds"][0]
    columns = [(m, v) for m in ["stereo", *modes] for v in params["variants"]]
    fig, axes = plt.subplots(frames, len(columns) + 1, figsize=(2.4 * (len(columns) + 1), 0.9 * frames + 0.4))
    axes = np.atleast_2d(axes)
    for i in range(frames):
        axes[i, 0].imshow(read_image(repo / index["left"][i]))
        axes[i, 0].set_title("image" if i == 0 else "", fontsize=7)
        for j, (mode, variant) in enumerate(columns, 1):
            disp = np.load(out / "runs" / mode / "outputs" / variant / f"seed{seed}" / "disparities.npy")[i]
            axes[i, j].imshow(disp, cmap="magma", vmax=np.percentile(disp, 95))  # Monodepth2's display
            axes[i, j].set_title(f"{mode} {variant}" if i == 0 else "", fontsize=7)
    for ax in axes.ravel():
        ax.axis("off")
    fig.tight_layout()
    write_figure(out / "disparities.png", fig, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Snapshot stereo, run and snapshot every mode not yet under ``--out``; write the tables and figure."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repo", type=Path, default=ROOT, help="the project checkout (default: this one)")
    ap.add_argument("--out", type=Path, default=None, help="default: <repo>/studies/results/monocular")
    ap.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    ap.add_argument("--sequence-length", type=int, default=5, help="data.synthetic.sequence_length")
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="one more -S of every experiment"
    )
    ap.add_argument("--cap", type=float, default=80.0)
    args = ap.parse_args(argv)
    repo = args.repo.resolve()
    out = (args.out or repo / "studies" / "results" / "monocular").resolve()
    try:  # before the hours of experiments: a file the study did not write is refused at once
        OutputPolicy(out, "monocular").claim([out / name for name in OUTPUTS], repo / "params.yaml")
    except OutputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if sh(["git", "status", "--porcelain", "--", *RESTORED], repo).strip():
        raise SystemExit(f"error: {repo}: uncommitted changes in {', '.join(RESTORED)}; commit them first")
    params = read_params_file(repo / "params.yaml")
    if params["train"].get("mode", "stereo") != "stereo":
        raise SystemExit(f"error: {repo}/params.yaml: train.mode must be stereo (the study's baseline)")
    (out / "runs").mkdir(parents=True, exist_ok=True)
    if not (out / "runs" / "stereo").is_dir():
        snapshot(repo, out / "runs" / "stereo", runs_of(params))
    for mode in args.modes:
        if not (out / "runs" / mode).is_dir():
            run_mode(repo, mode, args.sequence_length, args.set, out / "runs" / mode, runs_of(params))
    used = read_params_file(out / "runs" / args.modes[0] / "params.yaml")
    write_text(out / "table.md", table(out, args.modes, used, args.cap, repo))
    modes = {m: seed_values(out / "runs" / m, used, args.cap) for m in ["stereo", *args.modes]}
    values = {"cap": args.cap, "seeds": used["train"]["seeds"], "metric": "abs_rel", "modes": modes}
    values["settings"] = study_settings(used)
    write_text(out / "table.json", json.dumps(values, indent=1) + "\n")
    figure(out, repo, args.modes, used)
    print((out / "table.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(run_main("studies/monocular.py", main))
