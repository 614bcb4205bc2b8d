"""Every study that writes files claims them through the output policy before its work (the project's
rule for every entry point): a user's file at an output name is refused in one line naming it and
left as it was, and the results committed under studies/results are listed in their studies'
manifests, so a rerun may replace them."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import load_study

from msdepth.outputs import MANIFEST_PREFIX, _read_manifest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "studies" / "results"

# study: (its arguments with "{out}" for the output folder, the user's file it would write over)
CASES = {
    "learning": (["--variants", "ssim", "--seeds", "0", "--out", "{out}"], "ssim_seed0.json"),
    "monocular": (["--repo", str(ROOT), "--out", "{out}"], "table.md"),
    "prepare_set": (["--out", "{out}"], "params.yaml"),
    "power": (["--out", "{out}/power.md"], "power.md"),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_a_study_refuses_a_file_it_did_not_write(name: str, tmp_path: Path, monkeypatch, capsys) -> None:
    """The claim comes first: the study stops in one line naming the user's file, which is unchanged,
    and nothing else is written (no manifest, no other output)."""
    arguments, target = CASES[name]
    out = tmp_path.resolve() / "out"
    out.mkdir()
    user = out / target
    user.write_bytes(b"the user's own file\n")
    monkeypatch.chdir(ROOT)  # learning.py reads ./params.yaml, as from the repository root
    code = load_study(name).main([a.replace("{out}", str(out)) for a in arguments])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(lines) == 1 and lines[0].startswith(f"error: {user}: exists and was not written"), lines
    assert user.read_bytes() == b"the user's own file\n"
    assert [p.name for p in out.iterdir()] == [target]


def test_the_committed_results_are_listed_in_their_studies_manifests() -> None:
    """Each manifest under studies/results lists only files that are there; every committed result
    of the studies is listed in one."""
    manifests = sorted(RESULTS.rglob(f"{MANIFEST_PREFIX}*"))
    listed = set()
    for manifest in manifests:
        names = _read_manifest(manifest)
        assert names and all((manifest.parent / n).is_file() for n in names), manifest
        listed |= {manifest.parent / n for n in names}
    for path in ("grid/summary.md", "monocular/table.md", "optimum/sizes.md", "optimum/starts.md"):
        assert RESULTS / path in listed, path
    for path in ("roi_errors.md", "glass/windshield.png", "input_96x320/disparity.png", "power.md"):
        assert RESULTS / path in listed, path


def test_the_monocular_snapshot_leaves_a_users_folder_alone_and_no_partial_one(tmp_path: Path) -> None:
    """The snapshot stages into a fresh folder of its own: a user's ``stereo.tmp`` (the fixed name it
    once cleared) keeps its file, a complete snapshot lands at ``dest``, and a failed copy leaves
    nothing behind, neither ``dest`` nor a partial folder."""
    study = load_study("monocular")
    repo, runs = tmp_path / "repo", tmp_path / "out" / "runs"
    (repo / "metrics").mkdir(parents=True)
    (repo / "metrics" / "compare.md").write_text("table\n")
    (repo / "params.yaml").write_text("variants: [ssim]\n")
    (runs / "stereo.tmp").mkdir(parents=True)
    (runs / "stereo.tmp" / "mine.txt").write_text("the user's\n")
    study.snapshot(repo, runs / "stereo", [])
    assert (runs / "stereo.tmp" / "mine.txt").read_text() == "the user's\n"
    assert (runs / "stereo" / "params.yaml").read_text() == "variants: [ssim]\n"
    assert (runs / "stereo" / "metrics" / "compare.md").is_file()
    (repo / "params.yaml").unlink()  # the copy fails midway
    with pytest.raises(FileNotFoundError):
        study.snapshot(repo, runs / "mono", [])
    assert sorted(p.name for p in runs.iterdir()) == ["stereo", "stereo.tmp"]
