"""The figures module on a tiny pipeline-shaped tree built by the real stage functions."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import stage

from msdepth.config.params import params_from_dict
from msdepth.data import kitti
from msdepth.data.eval_index import read_eval_index
from msdepth.errors import DataError
from msdepth.evaluation.results import SUITES
from msdepth.evaluation.suites import load_frames
from msdepth.pipeline import paths as pipeline
from msdepth.render import generate
from msdepth.reporting.figures import FIGURES, make_figures, roi_examples

VARIANTS = ["ssim", "msssim"]
RUNS = {v: f"{v}/seed0" for v in VARIANTS}  # label -> run, as the figures stage passes them
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def tree(tmp_path_factory) -> Path:
    """data/index, outputs/<v>, metrics/<suite>/<v>.csv and dvclive TSVs, as the pipeline writes them."""
    root = tmp_path_factory.mktemp("figures")
    params = params_from_dict(
        {
            "data": {
                "height": 32,
                "width": 96,
                "synthetic": {
                    "seed": 1,
                    "drives": 1,
                    "train_pairs": 1,
                    "eval_frames": 3,
                    "height": 48,
                    "width": 160,
                },
            },
            "msssim": {"levels": 3},
        }
    )
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(root)  # the stage functions read and write relative to the project root
        generate(params.data.synthetic, Path(params.data.root), progress=False, workers=1)
        stage("index").index(params)
        stage("rois").rois(params)
        rng = np.random.default_rng(0)
        ramp = np.linspace(0.01, 0.12, 32, dtype=np.float32)[None, :, None]  # nearer towards the bottom
        for k, v in enumerate(VARIANTS):
            disp = ramp * (1 + 0.1 * k) * (1 + 0.2 * rng.random((3, 32, 96), dtype=np.float32))
            pipeline.run_dir(RUNS[v]).mkdir(parents=True)
            np.save(pipeline.run_dir(RUNS[v]) / "disparities.npy", disp.astype(np.float32))
            stage("depth").depth(params, v, "0")
            for suite in SUITES:
                stage("evaluate").evaluate(params, suite, v, "0")
            live = Path("plots/train") / RUNS[v] / "plots/metrics/train"
            live.mkdir(parents=True)
            for term in ("total", "appearance"):
                loss = 0.5 / (1 + k) * np.exp(-0.2 * np.arange(4)) + (0.01 if term == "total" else 0)
                pd.DataFrame({"step": np.arange(4), term: loss}).to_csv(
                    live / f"{term}.tsv", sep="\t", index=False
                )
    return root


@pytest.fixture(autouse=True)
def _in_tree(tree: Path, monkeypatch):
    # The evaluation index names files relative to the project root, as in the real pipeline.
    monkeypatch.chdir(tree)


def _paths(root: Path) -> dict:
    return {
        "eval_index": root / "data/index/eval_frames.csv",
        "rois": root / "data/index/rois.csv",
        "outputs": root / "outputs",
    }


def _eval_cfg():
    return params_from_dict({}).eval


def test_every_figure_is_a_png_and_no_temp_file_is_left(tree: Path, tmp_path: Path):
    out = tmp_path / "figs"
    written = make_figures(
        RUNS,
        out,
        **_paths(tree),
        metrics=tree / "metrics",
        train_plots=tree / "plots/train",
        eval_cfg=_eval_cfg(),
    )
    assert written == [out / name for name in FIGURES]
    for path in written:
        data = path.read_bytes()
        assert data.startswith(PNG_MAGIC), path
        assert len(data) > 10_000, (path, len(data))
        # No matplotlib version in the file: the committed figures survive a matplotlib upgrade.
        assert b"atplotlib" not in data, path
    assert sorted(p.name for p in out.iterdir()) == sorted(FIGURES)  # no .<name>.*.png temp files


def test_one_variant_gives_no_scatter(tree: Path, tmp_path: Path):
    written = make_figures(
        {"msssim": RUNS["msssim"]},
        tmp_path,
        **_paths(tree),
        metrics=tree / "metrics",
        train_plots=tree / "plots/train",
        eval_cfg=_eval_cfg(),
        frames=1,
    )
    assert [p.name for p in written] == [n for n in FIGURES if n != "error_scatter.png"]


def test_printed_numbers_equal_the_suites_csvs(tree: Path):
    cfg = _eval_cfg()
    cap = cfg.caps[0]
    examples = roi_examples(RUNS, **_paths(tree), eval_cfg=cfg)
    assert examples, "the tiny set should have at least one ROI with >= 50% valid GT"
    assert len({ex.cls for ex in examples}) == len(examples)  # one example per class
    for v in VARIANTS:
        roi = pd.read_csv(tree / "metrics/roi" / f"{RUNS[v]}.csv")
        grad = pd.read_csv(tree / "metrics/gradients" / f"{RUNS[v]}.csv")
        for ex in examples:
            assert ex.gt_valid_fraction >= 0.5
            row = roi[(roi["roi"] == ex.roi) & (roi["cap"] == cap)].iloc[0]
            # The CSV holds 6 significant digits: the printed number rounds to exactly it.
            assert float(f"{ex.abs_rel[v]:.6g}") == row["abs_rel"]
            assert ex.abs_rel[v] == pytest.approx(row["abs_rel"], abs=1e-6)
            g = grad[(grad["roi"] == ex.roi) & (grad["cap"] == cap)].iloc[0]
            assert ex.pred_sobel_x[v] == pytest.approx(g["pred_sobel_x"], rel=1e-5, abs=1e-6)
            if not np.isnan(g["gt_sobel_x"]):  # the suite reports GT gradients only for dense GT
                assert ex.gt_sobel_x == pytest.approx(g["gt_sobel_x"], rel=1e-5, abs=1e-6)


def test_missing_tsv_is_one_data_error_naming_it(tree: Path, tmp_path: Path):
    plots = tmp_path / "plots"
    shutil.copytree(tree / "plots/train", plots)
    missing = plots / "msssim/seed0/plots/metrics/train/appearance.tsv"
    missing.unlink()
    out = tmp_path / "figs"
    with pytest.raises(DataError, match=str(missing)):
        make_figures(
            RUNS,
            out,
            **_paths(tree),
            metrics=tree / "metrics",
            train_plots=plots,
            eval_cfg=_eval_cfg(),
        )
    assert not out.exists() or not any(out.iterdir())  # inputs are checked before any figure is drawn


def test_missing_depth_maps_is_a_data_error_naming_them(tree: Path, tmp_path: Path):
    outputs = tmp_path / "outputs"
    shutil.copytree(tree / "outputs", outputs)
    (outputs / "msssim/seed0/depth.npz").unlink()
    paths = {**_paths(tree), "outputs": outputs}
    with pytest.raises(DataError, match=str(outputs / "msssim/seed0/depth.npz")):
        make_figures(
            RUNS,
            tmp_path / "figs",
            **paths,
            metrics=tree / "metrics",
            train_plots=tree / "plots/train",
            eval_cfg=_eval_cfg(),
        )


def test_training_curves_draw_every_seed_and_name_a_missing_one(tree: Path, tmp_path: Path, monkeypatch):
    import msdepth.reporting.figures as figures_mod

    plots = tmp_path / "plots"
    shutil.copytree(tree / "plots/train", plots)
    shutil.copytree(plots / "ssim/seed0", plots / "ssim/seed1")
    drawn = {}
    real_save = figures_mod._save

    def keep(fig, path):
        drawn[path.name] = [[line.get_label() for line in ax.get_lines()] for ax in fig.axes]
        drawn[path.name + " x"] = [ax.get_xlabel() for ax in fig.axes]
        return real_save(fig, path)

    monkeypatch.setattr(figures_mod, "_save", keep)
    curves = {"ssim": ["ssim/seed0", "ssim/seed1"], "msssim": ["msssim/seed0"]}
    make_figures(
        RUNS,
        tmp_path / "figs",
        **_paths(tree),
        metrics=tree / "metrics",
        train_plots=plots,
        curves=curves,
        eval_cfg=_eval_cfg(),
    )
    for labels in drawn["training_curves.png"]:  # per panel: 2 ssim seeds, 1 msssim; each seed labelled
        assert labels == ["ssim, seed0", "ssim, seed1", "msssim, seed0"]
    assert drawn["error_scatter.png x"] == ["abs rel, ssim/seed0 (cap 80 m)"]  # the run drawn, with its seed
    missing = plots / "ssim/seed1/plots/metrics/train/total.tsv"
    missing.unlink()
    with pytest.raises(DataError, match=str(missing)):
        make_figures(
            RUNS,
            tmp_path / "figs2",
            **_paths(tree),
            metrics=tree / "metrics",
            train_plots=plots,
            curves=curves,
            eval_cfg=_eval_cfg(),
        )


def test_sparse_gt_shows_the_densest_roi_of_each_class(tree: Path, tmp_path: Path, monkeypatch):
    """With GT as sparse as one LiDAR scan, no ROI has 50 % valid GT: each class's densest is shown."""
    sparse = tmp_path / "tree"
    shutil.copytree(tree, sparse)
    monkeypatch.chdir(sparse)
    rng = np.random.default_rng(0)
    for path in Path("data/synthetic/kitti2015/training/disp_noc_0").glob("*.png"):
        disp = kitti.read_disparity(path)
        kitti.write_disparity(path, np.where(rng.random(disp.shape) < 0.05, disp, 0))
    examples = roi_examples(RUNS, **_paths(sparse), eval_cfg=_eval_cfg())
    assert examples and all(0 < ex.gt_valid_fraction < 0.5 for ex in examples)
    boxes = pd.read_csv(sparse / "data/index/rois.csv", dtype={"image": str})
    for ex in examples:
        fractions = []
        for roi in boxes[boxes["class"] == ex.cls].itertuples():
            disp = kitti.read_disparity(f"data/synthetic/kitti2015/training/disp_noc_0/{roi.image}.png")
            fractions.append((disp[roi.y0 : roi.y1, roi.x0 : roi.x1] > 0).mean())
        assert ex.gt_valid_fraction == pytest.approx(max(fractions))
    written = make_figures(
        RUNS,
        tmp_path / "figs",
        **_paths(sparse),
        metrics=sparse / "metrics",
        train_plots=sparse / "plots/train",
        eval_cfg=_eval_cfg(),
    )
    assert [p.name for p in written] == list(FIGURES)


def test_disparity_figure_shows_the_gt_and_outlines_cars_and_windshields(
    tree: Path, tmp_path: Path, monkeypatch
):
    """Each row: input, GT, then one panel per variant; every panel outlines the exact pixels of the
    row's cars and windshields from the frame's class map."""
    import msdepth.reporting.figures as figures

    drawn: list = []
    real_write = figures.write_figure

    def keep(path, fig, **kwargs):
        if Path(path).name == "disparity.png":
            drawn.append(
                [(ax.get_title(), len(ax.collections)) for ax in fig.axes if ax.get_label() != "<colorbar>"]
            )
        return real_write(path, fig, **kwargs)

    monkeypatch.setattr(figures, "write_figure", keep)
    make_figures(
        RUNS,
        tmp_path / "figs",
        **_paths(tree),
        metrics=tree / "metrics",
        train_plots=tree / "plots/train",
        eval_cfg=_eval_cfg(),
    )
    panels = drawn[0]
    titles = [t for t, _ in panels]
    assert titles[:4] == [titles[0], "GT", "ssim", "msssim"] and titles[0].startswith("input ")
    frames = load_frames(read_eval_index(tree / "data/index/eval_frames.csv"))
    for r, frame in enumerate(frames[: len(panels) // 4]):
        classes = sum(
            bool(((frame.class_map & kitti.CLASS_BITS[c]) > 0).any()) for c in ("car", "windshield")
        )
        assert [n for _, n in panels[4 * r : 4 * r + 4]] == [classes] * 4, (frame.name, classes)
    assert any(n > 0 for _, n in panels)
