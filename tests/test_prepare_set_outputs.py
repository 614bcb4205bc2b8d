"""``studies/prepare_set.py --out DIR`` claims every file it or the stages it runs (index, rois,
cache) write before any work (issue 68, item 5): a user's file planted at any of those names is
refused in one line naming it and left as it was, and nothing is written. Before, the rois stage's
``data/index/set_rois/<set>.csv`` and ``.png`` were never claimed, and a user's were replaced."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from conftest import load_study

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("index", "rois", "cache")
EXTRA_SETS = yaml.safe_load((ROOT / "params.yaml").read_text())["eval"]["extra_sets"]
# The files under the stages' folder outs, per set of eval.extra_sets.
PER_SET = {"data/index/sets": ("{}.csv",), "data/index/set_rois": ("{}.csv", "{}.png")}


def _written() -> list[str]:
    """params.yaml and the stages' outs as dvc.yaml declares them, a folder out by its files."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    names = ["params.yaml"]
    for stage in STAGES:
        for out in stages[stage]["outs"]:
            out = out if isinstance(out, str) else next(iter(out))
            names += (
                [f"{out}/{f.format(s)}" for s in EXTRA_SETS for f in PER_SET[out]]
                if out in PER_SET
                else [out]
            )
    return names


def test_the_written_names_cover_the_stages_outs() -> None:
    assert EXTRA_SETS, "params.yaml lists no extra set: the per-set files go unchecked"
    assert {"data/index/set_rois/eigen.csv", "data/index/set_rois/eigen.png"} <= set(_written())


@pytest.mark.parametrize("name", _written())
def test_a_users_file_at_any_name_prepare_set_writes_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    monkeypatch.chdir(tmp_path)  # prepare() enters --out before rendering: restored after
    study = load_study("prepare_set")
    monkeypatch.setattr(study, "generate", lambda *a, **k: pytest.fail(f"{name} was not claimed: rendering"))
    out = tmp_path.resolve() / "study"
    user = out / name
    user.parent.mkdir(parents=True)
    user.write_bytes(b"the user's own file\n")
    code = study.main(["--out", str(out)])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(lines) == 1 and lines[0].startswith(f"error: {user}: exists and was not written"), lines
    assert user.read_bytes() == b"the user's own file\n"
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) == [name]
