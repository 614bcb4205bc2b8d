"""The network-free instruments on an extra evaluation set (msdepth.optimum.sets; stages/match_set.py,
stages/optimum_set.py): on a tiny generated KITTI 2012 tree with a reflective class, their metric
files (exact class, D1 and EPE), a resume after a simulated kill, their dvc.yaml entries and their
rows in the set's section of compare.md."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from msdepth.config.params import params_from_dict
from msdepth.data import kitti, kitti2012
from msdepth.data.eval_index import read_eval_index, set_index_path, set_rois_path, write_eval_index
from msdepth.data.eval_sets import _build_kitti2012_index
from msdepth.errors import ConfigError
from msdepth.io import write_png
from msdepth.pipeline.paths import INDEX_DIR, SGBM_RUN, headline_path, match_run, optimum_run, suite_path

ROOT = Path(__file__).resolve().parents[1]
SET = "kitti2012"
DISPARITY = 8  # px: every pixel's, the scene a fronto-parallel plane
FRAMES = ("000000_10", "000001_10")
RAW = {
    "variants": ["ssim", "mix"],
    "mix": {"levels": 3},
    "eval": {"extra_sets": [SET]},
    # mix has no per-pixel cost: the optimum starts from SGBM; a few steps keep the test short
    "optimum": {"start": "sgbm", "threads": 1, "iterations": 4, "refine_iterations": 4, "levels": 2},
    "data": {"kitti": {"kitti2012_rois_csv": "boxes.csv"}},
}
# The user's boxes on the set (data.kitti.kitti2012_rois_csv): 2 cars and a pane of glass.
BOXES = (
    "image,class,x0,y0,x1,y1\n"
    "000000_10,car,0,24,80,48\n000000_10,glass,80,24,160,48\n000001_10,car,0,0,80,24\n"
)


def tiny_tree(root: Path, height: int = 48, width: int = 160) -> None:
    """A KITTI 2012 training tree of textured pairs at a disparity of :data:`DISPARITY` px, with a
    calibration per frame (any width), GT everywhere and the reflective GT in the lower half."""
    rng = np.random.default_rng(5)
    for n, frame in enumerate(FRAMES):
        noise = rng.integers(0, 255, (height // 4, (width + DISPARITY) // 4, 3), dtype=np.uint8)
        scene = cv2.resize(noise, (width + DISPARITY, height), interpolation=cv2.INTER_CUBIC)
        write_png(root / kitti2012.LEFT / f"{frame}.png", scene[:, :width])
        write_png(root / kitti2012.RIGHT / f"{frame}.png", scene[:, DISPARITY:])
        refl = np.zeros((height, width), np.float32)
        refl[height // 2 :] = DISPARITY
        for folder, disp in ((kitti2012.GT, np.full((height, width), DISPARITY, np.float32)),
                             (kitti2012.REFLECTIVE_GT, refl)):  # fmt: skip
            (root / folder).mkdir(parents=True, exist_ok=True)
            kitti.write_disparity(root / folder / f"{frame}.png", disp)
        (root / "calib").mkdir(exist_ok=True)
        p2, p3 = "P2: 200 0 80 0 0 200 24 0 0 0 1 0", "P3: 200 0 80 -108 0 200 24 0 0 0 1 0"
        (root / "calib" / f"{n:06d}.txt").write_text(f"{p2}\n{p3}\n")


@pytest.fixture
def project(tmp_path: Path, monkeypatch) -> Path:
    """A project folder holding the set's index and boxes, as the index and rois stages write them;
    the working folder."""
    from msdepth.data.rois import write_set_rois

    tiny_tree(tmp_path / "kitti2012-training")
    monkeypatch.chdir(tmp_path)
    index = _build_kitti2012_index(tmp_path / "kitti2012-training")
    write_eval_index(set_index_path(INDEX_DIR, SET), index)
    (tmp_path / "boxes.csv").write_text(BOXES)
    write_set_rois(params_from_dict(RAW), SET, index, set_rois_path(INDEX_DIR, SET))
    return tmp_path


def _set_metrics(run: str, suite: str = "full") -> tuple[dict, dict, pd.DataFrame]:
    """A run's summary, headline and per-unit table of ``suite`` on the set."""
    from msdepth.pipeline.paths import set_headline_dir, set_metrics_dir

    root = set_metrics_dir(SET)
    summary = json.loads(suite_path(suite, run, ".json", root).read_text())
    head = json.loads(headline_path(suite, run, set_headline_dir(SET)).read_text())
    return summary, head, pd.read_csv(suite_path(suite, run, ".csv", root))


def test_the_instruments_score_an_extra_set_with_its_class_d1_and_epe(project: Path):
    """SGM on ssim's cost, SGBM and ssim's optimum at optimum.smoothness_weight on the set's two
    frames: the default frames' run names below metrics/sets/kitti2012/full/, the reflective class
    with D1 and EPE; mix (no per-pixel cost) skipped with its reason; the scratch folders gone."""
    from conftest import stage

    from msdepth.evaluation.baselines import skipped_reason
    from msdepth.pipeline.paths import set_metrics_dir

    params = params_from_dict(RAW)
    match_set, optimum_set = stage("match_set").match_set, stage("optimum_set").optimum_set
    for matcher in ("ssim", "sgbm", "mix"):
        match_set(params, SET, matcher)
    optimum_set(params, SET, "ssim", "10.0")
    for run in (match_run("ssim"), SGBM_RUN, optimum_run("ssim", "10.0")):
        summary, head, table = _set_metrics(run)
        assert summary["images"] == 2 and len(table) == 2 * len(params.eval.caps), run
        assert summary["cap80"]["abs_rel"] < 0.1 and summary["cap80"]["d1"] < 0.1, run  # matched
        reflective = summary["masks"]["stereo"]["reflective"]
        assert reflective["frames"] == 2 and reflective["d1"] < 10 and reflective["epe"] < 1, run
        assert {"abs_rel", "a1", "reflective_abs_rel", "reflective_d1"} <= set(head), run
        roi, head, table = _set_metrics(run, "roi")  # each of the user's boxes a unit, D1 and EPE beside
        assert roi["rois"] == 3 and roi["excluded_rois"] == 0 and len(table) == 3 * len(params.eval.caps)
        assert (
            roi["cap80"]["by_class"]["car"]["count"] == 2 and roi["cap80"]["by_class"]["glass"]["count"] == 1
        )
        assert roi["cap80"]["overall"]["d1"] < 0.1 and set(table.columns) >= {"roi", "class", "d1", "epe"}
        assert head["roi"] == pytest.approx(roi["cap80"]["overall"]["abs_rel"]), run
    assert skipped_reason(set_metrics_dir(SET), match_run("mix"), ["full", "roi"]) == (
        "variant mix has no per-pixel cost: no cost volume to match on"
    )
    assert not (project / "checkpoints" / "sets").exists()
    assert not (project / "metrics" / "full").exists()  # the default frames' metrics untouched
    with pytest.raises(ConfigError, match=r"not in optimum\.set_weights \(\[10\.0\]\)"):
        optimum_set(params, SET, "ssim", "3.0")
    with pytest.raises(ConfigError, match="not in eval.extra_sets"):
        match_set(params, "eigen", "sgbm")


def test_a_killed_run_redoes_only_its_unfinished_frames(project: Path, monkeypatch):
    """A run killed on its second frame keeps the first in its scratch folder (and no metrics); the
    next run matches only the second, scores both and removes the folder. A changed param empties it."""
    from msdepth.optimum import sets, starts

    params = params_from_dict(RAW)
    matched = starts.start_disparity
    calls: list[int] = []

    def killed_on_the_second(*args, **kwargs) -> np.ndarray:
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt  # kill: nothing after it runs
        return matched(*args, **kwargs)

    monkeypatch.setattr(starts, "start_disparity", killed_on_the_second)
    with pytest.raises(KeyboardInterrupt):
        sets.score_set_match(params, SET, "sgbm", set_index_path(INDEX_DIR, SET))
    scratch = sets._scratch_dir(SET, SGBM_RUN)
    assert sorted(p.name for p in scratch.iterdir()) == sorted([sets.KEY, sets.FRAME_FILE.format(0)])
    assert not (project / "metrics").exists()
    calls.clear()
    monkeypatch.setattr(starts, "start_disparity", lambda *a, **k: calls.append(1) or matched(*a, **k))
    sets.score_set_match(params, SET, "sgbm", set_index_path(INDEX_DIR, SET))
    assert len(calls) == 1 and _set_metrics(SGBM_RUN)[0]["images"] == 2
    assert not scratch.exists()
    key = sets._scratch_key(params, "sgbm", None, set_index_path(INDEX_DIR, SET))
    assert sets._open_scratch(scratch, key) == 0
    np.save(scratch / sets.FRAME_FILE.format(0), np.zeros((2, 2), np.float32))
    assert sets._open_scratch(scratch, key) == 1  # the same key: the frame is kept
    other = dataclasses.replace(params, optimum=dataclasses.replace(params.optimum, max_width=320))
    changed = sets._scratch_key(other, "sgbm", None, set_index_path(INDEX_DIR, SET))
    assert sets._open_scratch(scratch, changed) == 0 and (scratch / sets.KEY).is_file()


def test_frames_of_old_images_or_old_code_are_not_resumed(project: Path, monkeypatch):
    """A run killed after its first frame, then every image replaced under the same name: the rerun
    redoes both frames (the key holds each image's size and modification time), as it does after
    a change to the optimum's code (the key holds its fingerprint)."""
    from msdepth.optimum import sets, starts

    params = params_from_dict(RAW)
    matched, calls = starts.start_disparity, []

    def killed_on_the_second(*args, **kwargs) -> np.ndarray:
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return matched(*args, **kwargs)

    monkeypatch.setattr(starts, "start_disparity", killed_on_the_second)
    with pytest.raises(KeyboardInterrupt):
        sets.score_set_match(params, SET, "sgbm", set_index_path(INDEX_DIR, SET))
    index = read_eval_index(set_index_path(INDEX_DIR, SET))
    key = sets._scratch_key(params, "sgbm", None, set_index_path(INDEX_DIR, SET))
    for left in index["left"]:  # new pictures, same names (and the same sizes: the time differs)
        image = cv2.imread(left)
        os.utime(left, ns=(time.time_ns(), time.time_ns() + 10**9))
        cv2.imwrite(left, 255 - image)
    assert sets._scratch_key(params, "sgbm", None, set_index_path(INDEX_DIR, SET)) != key
    calls.clear()
    monkeypatch.setattr(starts, "start_disparity", lambda *a, **k: calls.append(1) or matched(*a, **k))
    sets.score_set_match(params, SET, "sgbm", set_index_path(INDEX_DIR, SET))
    assert len(calls) == 2  # both frames of the new images, none resumed
    key = sets._scratch_key(params, "sgbm", None, set_index_path(INDEX_DIR, SET))
    monkeypatch.setattr(sets, "OPTIMUM_MODULES", sets.OPTIMUM_MODULES[:-1])
    assert sets._scratch_key(params, "sgbm", None, set_index_path(INDEX_DIR, SET))["code"] != key["code"]


def test_the_scratch_keys_code_is_the_set_stages_code_deps():
    """Every module of the scratch key's code fingerprint is in the set stages' code (their
    data/fingerprints file's import closure: a change to it reruns them, and they then redo their
    frames)."""
    from msdepth.optimum import sets
    from msdepth.pipeline.fingerprints import import_closure

    for name in ("match_set", "optimum_set"):  # the scripts of the set stages (sgbm_set runs match_set.py)
        closure = import_closure(ROOT / "stages" / f"{name}.py", ROOT / "src")
        src = [
            p.relative_to(ROOT / "src" / "msdepth").as_posix()
            for p in closure
            if p.is_relative_to(ROOT / "src")
        ]
        assert all(any(d == m or d.startswith(m + "/") for d in src) for m in sets.OPTIMUM_MODULES), name


def test_the_set_stages_list_what_they_read():
    """Each set stage lists its own keys: the optimum's every key that a pair's optimum reads (not
    the sweep's, the cost curves' or the batch size), the matchers none of the optimiser's; the
    default frames' stages list no key of the extra sets; each set stage depends on its own set's
    index and boxes, not on the folders of every set's."""
    import yaml

    from msdepth.config.params import OptimumConfig

    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    suites = {"eval.caps", "eval.min_depth", "eval.mask_gt_beyond_cap", "eval.median_scaling"}
    reads = {"optimum.threads", "optimum.jobs", "optimum.max_width"}
    assert set(stages["match_set"]["params"]) == {*reads, "loss.alpha", "${item.variant}", *suites}
    assert set(stages["sgbm_set"]["params"]) == {*reads, *suites}
    # set_weights and smoothness_weight: the matrix gives the weight (the stage checks it is listed)
    unread = {
        "sweep_frames",
        "cost_frames",
        "smoothness_sweep",
        "batch_size",
        "set_weights",
        "smoothness_weight",
    }
    expected = {f"optimum.{f.name}" for f in dataclasses.fields(OptimumConfig) if f.name not in unread}
    listed = set(stages["optimum_set"]["params"])
    assert {p for p in listed if p.startswith("optimum")} == expected
    assert "train.device" in listed and "train.device" in stages["optimum"]["params"]  # the refinement's
    assert stages["optimum_set"]["cmd"].endswith("${item.weight}")
    assert stages["optimum_set"]["matrix"]["weight"] == "${optimum.set_weights}"
    for name in ("optimum", "match", "sgbm", "cost_curves"):
        assert "eval.extra_sets" not in stages[name]["params"], name
    own = {"data/index/sets/${item.set}.csv", "data/index/set_rois/${item.set}.csv"}
    for name in ("eval_set", "baselines_set", "match_set", "sgbm_set", "optimum_set"):
        deps = set(stages[name]["deps"])  # its own set's files: another set's change reruns nothing here
        assert own <= deps and not deps & {"data/index/sets", "data/index/set_rois"}, name


def test_the_sets_section_of_compare_shows_the_instruments_beside_the_networks(project: Path):
    """compare_set: every instrument is a row of the set's table (D1 and EPE beside), with its
    difference to the reference and its reflective class; a skipped one is named with the reason;
    the set's boxes get their own table (D1, EPE, abs_rel per class) and intervals over the boxes."""
    from conftest import stage

    from msdepth.evaluation.results import score_set
    from msdepth.evaluation.suites import load_frames
    from msdepth.reporting.pipeline_compare import _compare_set

    params = params_from_dict({**RAW, "variants": ["ssim", "msssim"], "train": {"seeds": [0]}})
    frames = load_frames(read_eval_index(set_index_path(INDEX_DIR, SET)))
    for k, run in enumerate(("ssim/seed0", "msssim/seed0", "constant", "prior")):
        pred = {f.name: np.full(f.shape, 10.0 + k, np.float32) for f in frames}
        score_set(params, SET, run, pred, frames, rois=set_rois_path(INDEX_DIR, SET))
    stage("match_set").match_set(params, SET, "sgbm")
    stage("match_set").match_set(params, SET, "ssim")
    result, md = _compare_set(params, SET)
    rows = {"SGBM", "SGM (ssim cost)", "ssim", "msssim", "constant", "prior"}
    assert rows <= set(result["full"]["cap80"]) and rows <= set(result["masks"])
    assert "SGBM" in result["statistics"]["full"]["cap80"]
    assert "| SGBM | " in md and "D1 %" in md and "| reflective | SGBM |" in md
    assert "Instruments without metrics: SGM (msssim cost): no metrics/sets/kitti2012/full/optimum" in md
    assert "optimum ssim w10: no " in md
    assert "## kitti2012: ROI boxes, cap 80 m (3 boxes: car 2, glass 1)" in md
    assert "Difference to ssim (3 paired kitti2012 boxes in 2 frames, drawn by frame)" in md  # drawn by frame
    assert "| glass abs_rel |" in md
    assert rows <= set(result["roi"]) and "SGBM" in result["statistics"]["roi"]["cap80"]


def test_the_verdict_reads_the_sets_rows_frame_by_frame(project: Path):
    """set_verdict_rows: the networks paired by seed and the SGM cost starts paired by frame, on the
    whole frame and the reflective class, named after the set, and on the boxes' classes, named
    after the set's boxes; two frames and three boxes: the known difference (MS-SSIM 10 % off the GT
    depth, SSIM 20 %: −0.1) without an interval."""
    from conftest import stage

    from msdepth.analysis.sets import set_verdict_rows
    from msdepth.evaluation.results import score_set
    from msdepth.evaluation.suites import load_frames

    optimum = {**RAW["optimum"], "set_weights": [3.0, 10.0]}  # the sweep on the set: one param away
    params = params_from_dict(
        {**RAW, "variants": ["ssim", "msssim"], "train": {"seeds": [0, 1]}, "optimum": optimum}
    )
    frames = load_frames(read_eval_index(set_index_path(INDEX_DIR, SET)))
    depth = 200 * 0.54 / DISPARITY  # the tree's calibration
    for run, off in (("ssim/seed0", 1.2), ("ssim/seed1", 1.2), ("msssim/seed0", 1.1), ("msssim/seed1", 1.1)):
        pred = {f.name: np.full(f.shape, depth * off, np.float32) for f in frames}
        score_set(params, SET, run, pred, frames, rois=set_rois_path(INDEX_DIR, SET))
    for variant in ("ssim", "msssim"):
        stage("match_set").match_set(params, SET, variant)
        for weight in ("3.0", "10.0"):
            stage("optimum_set").optimum_set(params, SET, variant, weight)
    rows = {(r.instrument, r.cls): r for r in set_verdict_rows(params, SET, {"msssim": None})}
    assert set(rows) == {
        (f"{name} on {where}", cls)
        for name in ("stereo networks", "SGM cost start", "optimum w3", "optimum w10", "optimum own best")
        for where, classes in ((SET, ("full frame", "reflective")), (f"{SET} boxes", ("car", "glass")))
        for cls in classes
    }
    for where, cls, n in ((SET, "full frame", 2), (SET, "reflective", 2), (f"{SET} boxes", "car", 2)):
        net = rows[(f"stereo networks on {where}", cls)]
        assert net.diff == pytest.approx(-0.1, abs=1e-4) and net.n == n and not net.has_interval
        unit = f"{SET} frames" if where == SET else f"{where} in 2 frames"  # the boxes drawn by frame
        assert net.unit == unit and net.seeds == 2 and net.kind == "network"
        assert (f"frames (each with all its {where})" if where != SET else unit) in net.method
        assert rows[(f"SGM cost start on {where}", cls)].kind == "optimum"

    # each frame at the weight the other frame preferred (ties: the smaller weight), by hand
    def own_best(variant: str) -> pd.Series:
        err = {w: _set_metrics(optimum_run(variant, w))[2].query("cap == 80").set_index("frame")["abs_rel"]
               for w in ("3.0", "10.0")}  # fmt: skip
        other = dict(zip(FRAMES, reversed(FRAMES), strict=True))
        pick = {f: min(err, key=lambda w: (err[w][other[f]], float(w))) for f in FRAMES}
        return pd.Series({f: err[pick[f]][f] for f in FRAMES})

    own = rows[(f"optimum own best on {SET}", "full frame")]
    assert own.diff == pytest.approx((own_best("msssim") - own_best("ssim")).mean(), abs=1e-9)
    assert "each fold of frames at the weight best on the other fold" in own.method and own.n == 2
    assert rows[(f"optimum own best on {SET} boxes", "car")].kind == "optimum"


class ProcessId:
    """A picklable stand-in instrument: the id of the process that ran it, after a pause long
    enough for every worker to take a frame."""

    def __call__(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        time.sleep(1.0)
        return np.full((2, 2), os.getpid(), np.float32)


def test_jobs_run_the_frames_in_processes_with_the_same_bytes(project: Path):
    """optimum.jobs 2: the two frames in two spawned workers give the bytes one process gives (a
    frame's result depends on optimum.threads only), for SGM and the optimum; the scratch key
    ignores jobs, so a resumed run keeps its frames whatever the count."""
    from msdepth.optimum import sets

    params = params_from_dict(RAW)
    index = read_eval_index(set_index_path(INDEX_DIR, SET))
    for instrument in (
        sets.SetInstrument(params, "cost", "ssim"),
        sets.SetInstrument(params, "optimum", "ssim", 10.0),
    ):
        one, two = project / "one", project / "two"
        for folder, jobs in ((one, 1), (two, 2)):
            folder.mkdir()
            sets.frame_disparities(index, folder, instrument, instrument.start, jobs=jobs, threads=1)
        for i in range(len(FRAMES)):
            name = sets.FRAME_FILE.format(i)
            assert (one / name).read_bytes() == (two / name).read_bytes(), (instrument.start, name)
        for folder in (one, two):
            shutil.rmtree(folder)
    pids = project / "pids"
    pids.mkdir()
    sets.frame_disparities(index, pids, ProcessId(), "pid", jobs=2)
    seen = {int(np.load(pids / sets.FRAME_FILE.format(i))[0, 0]) for i in range(len(FRAMES))}
    assert len(seen) == 2 and os.getpid() not in seen  # one worker per frame, not this process
    jobs = dataclasses.replace(params, optimum=dataclasses.replace(params.optimum, jobs=2))
    keys = [sets._scratch_key(p, "cost", "ssim", set_index_path(INDEX_DIR, SET)) for p in (params, jobs)]
    assert keys[0] == keys[1]


def test_a_failing_frame_in_a_worker_is_one_line_and_keeps_the_finished_ones(project: Path):
    """A frame whose image cannot be read fails in its worker: the parent raises the reader's
    DataError naming the file, and the other frame's disparity stays for the next run."""
    from msdepth.errors import DataError
    from msdepth.optimum import sets

    params = params_from_dict(RAW)
    index = read_eval_index(set_index_path(INDEX_DIR, SET))
    broken = Path(index.loc[1, "left"])
    broken.write_bytes(b"not a png")
    folder = project / "scratch"
    folder.mkdir()
    with pytest.raises(DataError, match=str(broken)):
        sets.frame_disparities(index, folder, sets.SetInstrument(params, "sgbm", "sgbm"), "sgbm", jobs=2)
    assert [p.name for p in folder.iterdir()] == [sets.FRAME_FILE.format(0)]


def test_jobs_times_threads_is_bounded_in_one_line():
    """optimum.jobs x optimum.threads past 4 per core is refused naming optimum.jobs; either one out
    of its own range gets its own key's line."""
    from msdepth.config.params import MAX_THREADS

    raw = {**RAW, "optimum": {**RAW["optimum"], "jobs": MAX_THREADS, "threads": 2}}
    with pytest.raises(ConfigError, match=rf"^optimum\.jobs: times threads must be <= {MAX_THREADS}, got"):
        params_from_dict(raw)
    raw["optimum"]["threads"] = 1
    assert params_from_dict(raw).optimum.jobs == MAX_THREADS
    raw["optimum"]["jobs"] = MAX_THREADS + 1
    with pytest.raises(ConfigError, match=r"^optimum\.jobs: must be in 1\.\."):
        params_from_dict(raw)


class Dies:
    """A picklable stand-in instrument whose worker process dies (as the kernel's OOM killer ends one)."""

    def __call__(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        os._exit(9)


def test_a_worker_that_dies_is_one_line(project: Path):
    """A worker process killed mid-frame ends the run in one line naming the run and the remedy,
    not a BrokenProcessPool traceback."""
    from msdepth.errors import MsdepthError
    from msdepth.optimum import sets

    index = read_eval_index(set_index_path(INDEX_DIR, SET))
    folder = project / "scratch"
    folder.mkdir()
    with pytest.raises(MsdepthError, match=r"^sgbm on kitti2012: a worker process died .*lower optimum"):
        sets.frame_disparities(index, folder, Dies(), "sgbm on kitti2012", jobs=2)
    assert not list(folder.iterdir())
