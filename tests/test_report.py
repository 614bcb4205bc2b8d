"""docs/results.md and the README's headline are what the committed metrics give (issue 29 item 3),
and the report writes every number and verdict from the data (known answers on a small comparison)."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import pytest

from msdepth.errors import DataError
from msdepth.reporting.report import (
    ANSWER_BEGIN,
    ANSWER_END,
    BEGIN,
    END,
    _headline_table,
    _readme_answer,
    _readme_block,
    _replace_block,
    _results_block,
    load_results,
    main,
    rendered,
    stale,
    write_report,
)

ROOT = Path(__file__).resolve().parents[1]


def test_readme_block_and_results_page_are_what_the_committed_metrics_give():
    """Editing a number of docs/results.md or of the README's block, or committing new metrics
    without `dvc repro report`, fails here."""
    differ = stale(ROOT)
    assert not differ, (
        f"{[str(p.relative_to(ROOT)) for p in differ]}: run `python -m msdepth.reporting.report`"
    )


def _diff(mean: float, low: float, high: float, seeds: int = 3, n: int = 10) -> dict:
    return {
        "mean": mean,
        "low": low,
        "high": high,
        "n": n,
        "seeds": seeds,
        "reference_seeds": seeds,
        "excludes_zero": low > 0 or high < 0,
    }


def _full(abs_rel: float, rmse: float, a1: float) -> dict:
    return {"abs_rel": abs_rel, "sq_rel": 2 * abs_rel, "rmse": rmse, "a1": a1}


def _roi(abs_rel: float, car: float, glass: float) -> dict:
    return {
        "overall": {"abs_rel": abs_rel, "count": 7},
        "by_class": {"car": {"abs_rel": car}, "glass": {"abs_rel": glass}},
    }


# A comparison with known numbers: MS-SSIM 0.020 ahead of SSIM, interval [-0.030, -0.010] (marked
# over 3 seeds); the constant wins on glass, every variant on cars.
COMPARISON = {
    "variants": ["ssim", "msssim"],
    "baselines": ["constant", "prior"],
    "seeds": [0, 1, 2],
    "settings": {
        "ssim": {"kernel_size": 3, "padding": "valid"},
        "msssim": {"kernel_size": 3, "levels": 4, "weights": "wang"},
    },
    "full": {
        "cap80": {
            "ssim": _full(0.2, 7.0, 0.8),
            "msssim": _full(0.18, 7.5, 0.81),
            "constant": _full(0.5, 15.0, 0.2),
            "prior": _full(0.3, 10.0, 0.5),
        }
    },
    "roi": {
        "cap80": {
            "ssim": _roi(0.6, 0.45, 0.5),
            "msssim": _roi(0.55, 0.4, 0.55),
            "constant": _roi(0.45, 0.6, 0.3),
            "prior": _roi(0.7, 0.65, 0.6),
        }
    },
    "statistics": {
        "reference": "ssim",
        "confidence": 0.95,
        "bootstrap_samples": 100,
        "full": {
            "cap80": {
                "msssim": {"abs_rel": _diff(-0.02, -0.03, -0.01)},
                "constant": {"abs_rel": _diff(0.3, 0.25, 0.35)},
                "prior": {"abs_rel": _diff(0.1, 0.05, 0.15)},
            }
        },
        "roi": {"cap80": {"msssim": {"abs_rel": _diff(-0.05, -0.1, 0.01)}}},
    },
    "seed_spread": {
        "full": {"cap80": {"ssim": {"abs_rel": {"mean": 0.2, "sd": 0.004}}}},
        "roi": {"cap80": {"ssim": {"abs_rel": {"mean": 0.6, "sd": 0.02}}}},
    },
    "roi_masks": {"cap80": {"ssim": {"overall": {"abs_rel": 0.61}}}},
    "image_dependence": {
        "ssim/seed0": {"variation_ratio": 0.6, "image_blind": False},
        "msssim/seed0": {"variation_ratio": 0.7, "image_blind": False},
        "constant": {"variation_ratio": 0.0, "image_blind": True},
    },
}


def _project(tmp_path: Path, data: dict, readme: str | None = None) -> Path:
    (tmp_path / "metrics" / "train" / "ssim").mkdir(parents=True)
    (tmp_path / "metrics" / "compare.json").write_text(json.dumps(data))
    for seed in data["seeds"]:
        (tmp_path / "metrics" / "train" / "ssim" / f"seed{seed}.json").write_text(
            '{"steps": 1200, "epochs": 8}'
        )
    if readme is not None:
        (tmp_path / "README.md").write_text(readme)
    return tmp_path


def test_headline_table_known_answers(tmp_path: Path):
    r = load_results(_project(tmp_path, COMPARISON))
    lines = _headline_table(r).splitlines()
    assert lines[0] == (
        "| run | abs_rel | sq_rel | rmse (m) | a1 | ROI abs_rel | exact masks | car | glass |"
    )  # classes in verdict.CLASS_ORDER, the one order of every table
    # mean ± sd over seeds where the spread is known; the best variant per full-image column bold
    assert (
        lines[2]
        == "| SSIM | 0.200 ± 0.004 | 0.40 | **7.00** | 0.800 | 0.600 ± 0.020 | 0.610 | 0.450 | 0.500 |"
    )
    assert (
        lines[3] == "| MS-SSIM (k=3) | **0.180** | **0.36** | 7.50 | **0.810** | 0.550 | – | 0.400 | 0.550 |"
    )
    assert lines[4].startswith("| constant (image-blind) | 0.500 | 1.00 | 15.00 | 0.200 | 0.450 |")


def test_a_marked_difference_is_a_verdict_an_unmarked_one_is_not(tmp_path: Path):
    r = load_results(_project(tmp_path, COMPARISON))
    block = _readme_block(r)
    assert block.startswith(BEGIN + "\n") and block.endswith("\n" + END)
    text = " ".join(block.split())
    assert "**Verdict**: MS-SSIM (k=3) has an abs_rel 0.020 lower than SSIM's" in text
    assert "[−0.030, −0.010] over images and seeds, which excludes 0 (marked `*`" in text
    assert "the constant on glass" in text and "car" not in text.split("On the ROIs")[1]
    assert (
        "The committed run: rendered frames in KITTI 2015's layout, cap 80 m, 10 frames, 7 ROIs, "
        "3 seeds per loss." in text
    )


def test_with_one_seed_nothing_is_marked(tmp_path: Path):
    data = copy.deepcopy(COMPARISON)
    data["seeds"] = [0]
    for block in data["statistics"]["full"]["cap80"].values():
        block["abs_rel"]["seeds"] = block["abs_rel"]["reference_seeds"] = 1
    text = " ".join(_readme_block(load_results(_project(tmp_path, data))).split())
    assert "**No verdict yet**" in text and "**Verdict**" not in text
    assert "[−0.030, −0.010] over images, which excludes 0 but does not cover training noise" in text
    assert "7 ROIs, 1 seed per loss." in text


def test_settings_that_differ_from_the_defaults_name_the_row(tmp_path: Path):
    data = copy.deepcopy(COMPARISON)
    data["settings"]["msssim"].update(kernel_size=7, levels=3)
    table = _headline_table(load_results(_project(tmp_path, data)))
    assert "| MS-SSIM (k=7, levels=3) |" in table and "| SSIM |" in table


def test_image_blind_runs_are_flagged(tmp_path: Path):
    data = copy.deepcopy(COMPARISON)
    data["image_dependence"]["msssim/seed0"].update(variation_ratio=0.1, image_blind=True)
    data["image_dependence"]["msssim/seed1"] = {"variation_ratio": 0.5, "image_blind": False}
    r = load_results(_project(tmp_path, data))
    assert "| MS-SSIM (k=3) (1 of 2 runs image-blind) |" in _headline_table(r)
    assert "msssim/seed0 is image-blind (variation below 0.25 of the GT's)" in " ".join(
        _results_block(r).split()
    )


def test_without_rois_or_extra_sets_their_parts_are_left_out(tmp_path: Path):
    data = copy.deepcopy(COMPARISON)
    for key in ("roi", "roi_masks"):
        del data[key]
    del data["statistics"]["roi"]
    r = load_results(_project(tmp_path, data))
    assert _headline_table(r).splitlines()[0] == "| run | abs_rel | sq_rel | rmse (m) | a1 |"
    page = _results_block(r)
    assert "on the ROIs" not in page and "Per ROI class" not in page
    assert "## The Eigen split" not in page


def test_results_page_known_answers(tmp_path: Path):
    data = copy.deepcopy(COMPARISON)
    data["sets"] = {"eigen": copy.deepcopy({k: data[k] for k in ("full", "statistics", "seed_spread")})}
    data["sets"]["eigen"]["images"] = 10
    page = " ".join(_results_block(load_results(_project(tmp_path, data))).split())
    assert "3 training runs per variant (seeds 0, 1, 2), each 1,200 steps over 8 epochs" in page
    assert "Every trained run follows the image (variation 0.60–0.70 of the GT's" in page
    assert (
        "the constant +0.300 [+0.250, +0.350] and the per-pixel prior +0.100 [+0.050, +0.150], so SSIM beats"
        in page
    )
    assert "glass 0.500–0.550 against the constant's 0.300" in page
    assert "Every variant is ahead on car. Every variant is behind on glass." in page
    assert "## The Eigen split" in page and "10 images" in page


def test_replace_block_keeps_the_rest_and_needs_both_markers(tmp_path: Path):
    text = f"# title\n\n{BEGIN}\nold\n{END}\n\n## next\n"
    assert (
        _replace_block(text, f"{BEGIN}\nnew\n{END}", Path("README.md"))
        == f"# title\n\n{BEGIN}\nnew\n{END}\n\n## next\n"
    )
    for broken in ("# no block\n", f"{END}\n{BEGIN}\n", f"{BEGIN}\n{BEGIN}\n{END}\n"):
        with pytest.raises(DataError, match=r"^README\.md: needs one generated block"):
            _replace_block(broken, "x", Path("README.md"))
    # The README's answer has markers of its own: the results block's markers do not stand for them.
    with pytest.raises(DataError, match="end of answer"):
        _replace_block(text, "x", Path("README.md"), ANSWER_BEGIN, ANSWER_END)


README = f"# title\n\n{ANSWER_BEGIN}\n{ANSWER_END}\n\n## Quick start\n\n{BEGIN}\n{END}\n\nhand-written\n"


def test_write_then_check_and_a_hand_edit_is_found(tmp_path: Path, capsys):
    root = _project(tmp_path, COMPARISON, readme=README)
    assert main(["--root", str(root), "--check"]) == 1
    assert write_report(root) == [root / "docs" / "results.md", root / "README.md"]
    assert main(["--root", str(root), "--check"]) == 0
    assert write_report(root) == []  # unchanged files are left alone
    readme = (root / "README.md").read_text()
    assert readme.endswith(f"{END}\n\nhand-written\n") and "| SSIM | 0.200 ± 0.004 |" in readme
    answer = " ".join(readme[readme.index(ANSWER_BEGIN) : readme.index(ANSWER_END)].split())
    assert (
        "**Answer so far, on the rendered frames** ([docs/results.md](docs/results.md)): **Verdict**: MS-SSIM"
        in answer
    )
    (root / "README.md").write_text(readme.replace("0.200 ± 0.004", "0.199 ± 0.004"))
    capsys.readouterr()
    assert main(["--root", str(root), "--check"]) == 1
    assert "README.md: not what the metrics give" in capsys.readouterr().err


def test_the_results_pages_prose_is_kept_and_only_its_block_rewritten(tmp_path: Path):
    """docs/results.md is written by hand around one generated block: the report rewrites the
    block and leaves the prose; a page without the block is one line naming it."""
    root = _project(tmp_path, COMPARISON)
    page = root / "docs" / "results.md"
    page.parent.mkdir()
    page.write_text(f"# Results\n\nby hand\n\n{BEGIN}\nold 0.123\n{END}\n\n## Terms\n\nby hand too\n")
    write_report(root)
    text = page.read_text()
    assert text.startswith(f"# Results\n\nby hand\n\n{BEGIN}")
    assert text.endswith(f"{END}\n\n## Terms\n\nby hand too\n")
    assert "old 0.123" not in text and "| SSIM | 0.200 ± 0.004 |" in text
    page.write_text("# Results\n\nno block\n")
    with pytest.raises(DataError, match=r"results\.md: needs one generated block"):
        rendered(root)


def test_the_committed_results_page_holds_the_terms_the_readme_links_to():
    """The glossary is docs/results.md's, by hand; the README's table links to it."""
    page = (ROOT / "docs" / "results.md").read_text(encoding="utf-8")
    terms = page[page.index("## Terms") :].split("\n## ")[0]
    for term in ("*Difference*", "*n*", "*Networks*", "*Loss's own optimum (wW)*", "*X frames*", "*X boxes*"):
        assert term in terms
    assert "(docs/results.md#terms)" in (ROOT / "README.md").read_text(encoding="utf-8")


def test_a_project_without_readme_gets_only_the_results_page(tmp_path: Path):
    root = _project(tmp_path, COMPARISON)
    assert list(rendered(root)) == [root / "docs" / "results.md"]


def test_missing_or_broken_metrics_are_one_line(tmp_path: Path):
    env_root = str(ROOT / "src")
    proc = subprocess.run(
        [sys.executable, "-m", "msdepth.reporting.report", "--root", str(tmp_path)],
        capture_output=True,
        text=True,
        env={"PYTHONPATH": env_root, "PATH": ""},
    )
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [
        f"error: {tmp_path / 'metrics' / 'compare.json'}: missing; run `dvc repro compare` first"
    ]
    data = copy.deepcopy(COMPARISON)
    del data["full"]
    with pytest.raises(DataError, match=r"compare\.json: no full \(re-run the compare stage\)"):
        load_results(_project(tmp_path, data))


def test_the_verdict_table_goes_into_the_readme_and_the_sentences_into_the_page(tmp_path: Path):
    from msdepth.analysis.verdict import Row, verdict_data

    rows = [
        Row("stereo networks", "windshield", -0.04, -0.13, 0.06, 66, "m", "network"),
        Row("optimum w10", "windshield", -0.01, -0.04, -0.002, 66, "m", "optimum"),
    ]
    data = copy.deepcopy(COMPARISON)
    data["verdict"] = verdict_data(rows, 80.0, 0.95, "MS-SSIM", "SSIM")
    r = load_results(_project(tmp_path, data))
    block = " ".join(_readme_block(r).split())
    assert block.startswith(BEGIN + " MS-SSIM − SSIM abs_rel per surface class and instrument at cap 80 m")
    assert "`*`: the 95 % interval excludes 0; terms: [docs/results.md](docs/results.md#terms)" in block
    assert "| windshield | −0.040 [−0.130, +0.060], n = 66 ROIs × 0 seeds a side |" in block
    answer = " ".join(_readme_answer(r).split())
    assert answer == (
        f"{ANSWER_BEGIN} **Answer so far, on the rendered frames** ([docs/results.md](docs/results.md)): "
        "MS-SSIM's abs_rel against SSIM's: stereo networks lower on 1 of 1 class, no interval excluding 0; "
        "loss's own optimum, w10 lower on 1 of 1 class, 1 interval excluding 0. **On real KITTI frames**, "
        "never pooled with these ([their page](studies/results/real_sets/README.md)): not measured in this "
        f"project copy. {ANSWER_END}"
    )
    flipped = copy.deepcopy(data)
    flipped["verdict"] = verdict_data(
        [*rows, Row("optimum w30", "windshield", 0.02, 0.01, 0.03, 66, "m", "optimum")],
        80.0,
        0.95,
        "MS-SSIM",
        "SSIM",
    )
    flipped["data_source"] = "kitti"
    answer = " ".join(_readme_answer(load_results(_project(tmp_path / "flipped", flipped))).split())
    assert "**Answer so far, on the real KITTI frames**" in answer and "their page" not in answer
    assert "The sign depends on the optimum's smoothness weight on windshield." in answer
    page = " ".join(_results_block(r).split())
    assert "## What the study finds Is MS-SSIM's depth error (abs_rel) lower than SSIM's?" in page
    assert "Per class, every instrument ([verdict.png](../plots/figures/verdict.png)" in page
    assert "- windshield: MS-SSIM's error is lower in 2 of 2 instruments;" in page
    assert page.count("- windshield:") == 1  # the sentences once
    plain = load_results(_project(tmp_path / "plain", copy.deepcopy(COMPARISON)))
    assert "verdict.png" not in _readme_block(plain) and "## What the study finds" not in _results_block(
        plain
    )


def test_the_real_frames_get_their_own_table_and_words_never_pooled(tmp_path: Path):
    """Issue 66 item 5: the real-sets study's compare.json (REAL_SETS_COMPARE) gives the README a
    second table and sentence, of its real places' columns only; its rendered columns stay out."""
    from msdepth.analysis.verdict import Column, Row, verdict_data
    from msdepth.pipeline.paths import REAL_SETS_COMPARE

    rendered_rows = [
        Row("optimum own best", "car", -0.02, -0.03, -0.01, 91, "m", "optimum"),
        Row("optimum own best", "full frame", -0.015, -0.02, -0.01, 40, "m", "optimum"),
    ]
    data = copy.deepcopy(COMPARISON)
    data["verdict"] = verdict_data(rendered_rows, 80.0, 0.95, "MS-SSIM", "SSIM")
    project = _project(tmp_path, data, readme=f"# x\n\n{ANSWER_BEGIN}\n{ANSWER_END}\n\n{BEGIN}\n{END}\n")
    real_rows = [
        *rendered_rows,  # the study's own rendered frames: not the real answer
        Row("optimum own best on kitti2012", "reflective", 0.03, None, None, 2, "m", "optimum"),
        Row("optimum own best on kitti2012", "full frame", 0.02, None, None, 2, "m", "optimum"),
        Row("optimum own best on kitti2015 boxes", "car", 0.01, None, None, 16, "m", "optimum"),
    ]
    columns = [
        Column("optimum own best", "optimum", "optimum own best"),
        Column("own best, kitti2012 frames", "optimum", "optimum own best on kitti2012"),
        Column("own best, kitti2015 boxes", "optimum", "optimum own best on kitti2015 boxes"),
    ]
    study = {"verdict": verdict_data(real_rows, 80.0, 0.95, "MS-SSIM", "SSIM", columns=columns)}
    (project / REAL_SETS_COMPARE).parent.mkdir(parents=True)
    (project / REAL_SETS_COMPARE).write_text(json.dumps(study))
    readme = " ".join(rendered(project)[project / "README.md"].split())
    real_table = readme[readme.index("On the shared real frames, apart") :]
    assert readme.index("The committed run:") < readme.index("On the shared real frames")
    assert "| class | own best, kitti2012 frames | own best, kitti2015 boxes |" in real_table
    assert "| reflective | +0.030 (no interval), n = 2 " in real_table
    assert "| car | – | +0.010 (no interval), n = 16 " in real_table
    assert "| optimum own best |" not in real_table and "−0.020" not in real_table  # nothing pooled
    words = [
        "**On real KITTI frames**, never pooled with these ([their",
        "page](studies/results/real_sets/README.md)): each loss at its own best weight, own best,",
        "kitti2012 frames lower on 0 of 2 classes; own best, kitti2015 boxes lower on 0 of 1 class",
        "(point estimates: too few frames). The sign depends on the frames (full frame, own best:",
        "rendered −0.015, kitti2012 +0.020).",
    ]
    assert " ".join(words) in readme
