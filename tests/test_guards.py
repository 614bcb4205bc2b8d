"""Guards by class (issue 56): the output manifest lists only files that were written completely and
is read only from a regular file; a symlink loop in an output path is one line; every entry point
that writes into a user-named folder goes through the output policy.

Each case is a hostile input a user could give; each must end in one line naming the file, with no
user file changed.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import load_study, save_tiny_model

from msdepth.__main__ import main
from msdepth.errors import OutputError
from msdepth.io import write_text
from msdepth.outputs import (
    OutputPolicy,
    _manifest_entries,
    _manifest_line,
    _pending_line,
    _read_manifest,
    settle_outputs,
)

ROOT = Path(__file__).resolve().parents[1]
USERS = b"the user's own file\n"
FAST_OPTIMUM = ["--variant", "ssim", "--set", "optimum.iterations=2", "--set", "optimum.levels=1", "--quiet"]


def _image(path: Path, value: int = 1) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    small = np.random.default_rng(value).integers(0, 256, (6, 16, 3), np.uint8)
    assert cv2.imwrite(str(path), cv2.resize(small, (128, 48)))


def _users_file(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(USERS)
    return path


def _one_line(code: int, capsys: pytest.CaptureFixture[str], expected: str) -> None:
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert code == 1 and "Traceback" not in err and len(errors) == 1, err
    assert expected in errors[0], errors[0]


def _predict(tmp: Path, model: Path, out: Path) -> list[str]:
    _image(tmp / "in" / "a.png")
    return ["predict", str(tmp / "in"), "--model", str(model), "--out", str(out), "--quiet"]


# --- the manifest lists a name only once its file is written --------------------------------------


def _huge_model(path: Path) -> Path:
    """A model file whose weights are finite and huge: the network's output is not finite."""
    import torch

    state = torch.load(save_tiny_model(path), weights_only=True)
    state["model"] = {k: v * 1e30 if v.is_floating_point() else v for k, v in state["model"].items()}
    torch.save(state, path)
    return path


def test_predict_that_writes_nothing_lists_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Issue 56 case 2: the outputs' names stayed listed, so a user's file saved there later was replaced.
    out = tmp_path / "out"
    argv = _predict(tmp_path, _huge_model(tmp_path / "huge.pt"), out)
    _one_line(main(argv), capsys, "NaN or infinite")
    assert not (out / ".msdepth-predict").exists()  # created by the run, and nothing to list
    users = _users_file(out / "a_disp.png")
    _one_line(main(argv), capsys, "a_disp.png: exists and was not written by msdepth predict")
    assert users.read_bytes() == USERS


def test_optimum_that_writes_nothing_lists_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # Issue 56 case 2 ("0 of 1 written"): a disparity that cannot be written left a_* listed.
    import msdepth.optimum.solver as solver

    def not_finite(pairs, *args, **kwargs):
        return [np.full(left.shape[:2], np.nan, np.float32) for left, _ in pairs]

    monkeypatch.setattr(solver, "optimum_disparities", not_finite)
    _image(tmp_path / "L" / "a.png", 1)
    _image(tmp_path / "R" / "a.png", 2)
    out = tmp_path / "out"
    argv = ["optimum", str(tmp_path / "L"), str(tmp_path / "R"), "--out", str(out), *FAST_OPTIMUM]
    _one_line(main(argv), capsys, "NaN or infinite")
    assert not (out / ".msdepth-optimum").exists()
    users = _users_file(out / "a_ssim_disp.npy")
    _one_line(main(argv), capsys, "a_ssim_disp.npy: exists and was not written by msdepth optimum")
    assert users.read_bytes() == USERS


def test_a_study_that_fails_before_writing_lists_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Issue 56 case 2: `studies/power.py --root nowhere` left power.md listed (and ended in a traceback).
    out = tmp_path / "power.md"
    _one_line(load_study("power").main(["--root", str(tmp_path / "nowhere"), "--out", str(out)]), capsys, "")
    assert _read_manifest(tmp_path / ".msdepth-power") == set()  # pending only, until the run ends
    settle_outputs()  # as at the study's exit
    assert not (tmp_path / ".msdepth-power").exists()
    _users_file(out)
    assert OutputPolicy(tmp_path, "power").ours == set()


def test_a_killed_run_may_rewrite_what_it_wrote_and_nothing_else(tmp_path: Path) -> None:
    # A run killed (no settle) after writing a.txt, before writing b.txt: a.txt is its own, b.txt
    # only pending, so a user's file saved as b.txt is refused and the killed write's temp removed.
    out = tmp_path / "out"
    OutputPolicy(out, "predict").claim([out / "a.txt", out / "b.txt"], "in")
    write_text(out / "a.txt", "written\n")
    assert _manifest_entries(out / ".msdepth-predict") == [
        ("a.txt", False),
        ("b.txt", False),
        ("a.txt", True),
    ]
    temp = out / ".b.txt.msdepth-tmp-abcd1234.txt"
    temp.write_text("half")
    _users_file(out / "b.txt")
    rerun = OutputPolicy(out, "predict")
    assert not temp.exists() and rerun.ours == {"a.txt"}
    rerun.claim([out / "a.txt"], "in")
    with pytest.raises(OutputError, match="b.txt: exists and was not written"):
        rerun.claim([out / "b.txt"], "in")
    rerun.settle()
    assert (out / ".msdepth-predict").read_text() == _manifest_line("a.txt")
    assert (out / "b.txt").read_bytes() == USERS


def test_a_settled_manifest_has_the_lines_a_complete_run_always_wrote(tmp_path: Path) -> None:
    # Outputs stay byte-identical: one written line per name, in claim order, whatever the write order.
    out = tmp_path / "out"
    policy = OutputPolicy(out, "learning")
    policy.claim([out / "b.md", out / "a.md", out / "c.md"], "params.yaml")
    write_text(out / "a.md", "a\n")
    (out / "c.md").write_text("c\n")  # as a subprocess writes it: found at the end of the run
    write_text(out / "b.md", "b\n")
    policy.settle()
    assert (out / ".msdepth-learning").read_text() == "".join(
        _manifest_line(n) for n in ("b.md", "a.md", "c.md")
    )
    again = OutputPolicy(out, "learning")
    again.claim([out / "a.md"], "params.yaml")
    before = (out / ".msdepth-learning").stat().st_mtime_ns
    again.settle()
    assert (out / ".msdepth-learning").stat().st_mtime_ns == before  # nothing new: not rewritten


# --- a manifest is read only from a regular file the policy wrote -----------------------------------


def _symlink_to_a_file(manifest: Path, target: Path) -> None:
    target.write_text("export PATH=/usr/bin\nalias ll='ls -l'\n")
    manifest.symlink_to(target)


def _fifo(manifest: Path, target: Path) -> None:
    os.mkfifo(manifest)


def _folder(manifest: Path, target: Path) -> None:
    manifest.mkdir()


def _not_manifest_lines(manifest: Path, target: Path) -> None:
    manifest.write_text(_manifest_line("a_disp.png") + '"unterminated\n')


def _a_name_outside(manifest: Path, target: Path) -> None:
    manifest.write_text(_manifest_line("../elsewhere.png"))


def _too_large(manifest: Path, target: Path) -> None:
    with open(manifest, "wb") as f:
        f.truncate((64 << 20) + 1)  # sparse: no disk used


HOSTILE_MANIFESTS = {
    "symlink": (_symlink_to_a_file, "symbolic link"),
    "fifo": (_fifo, "not a regular file"),
    "folder": (_folder, "a folder, not a file"),
    "bad_line": (_not_manifest_lines, "line 2 is not an output manifest line"),
    "name_outside": (_a_name_outside, "line 1 is not an output manifest line"),
    "too_large": (_too_large, "over the limit of 64 MiB for output manifest files"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE_MANIFESTS))
def test_a_manifest_that_is_not_one_is_refused_in_one_line(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Issue 56 case 3: `ln -s ~/.bashrc OUT/.msdepth-predict` made predict append to the link's target
    # and trust its lines as names it wrote.
    make, expected = HOSTILE_MANIFESTS[case]
    out, target = tmp_path / "out", tmp_path / "bashrc"
    out.mkdir()
    make(out / ".msdepth-predict", target)
    before = target.read_bytes() if target.exists() else None
    _one_line(main(_predict(tmp_path, save_tiny_model(tmp_path / "m.pt"), out)), capsys, expected)
    assert (target.read_bytes() if target.exists() else None) == before
    assert sorted(p.name for p in out.iterdir()) == [".msdepth-predict"]


def test_pending_lines_are_never_trusted(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _users_file(out / "a_disp.png")
    (out / ".msdepth-predict").write_text(_pending_line("a_disp.png"))
    with pytest.raises(OutputError, match="exists and was not written"):
        OutputPolicy(out, "predict").claim([out / "a_disp.png"], "a.png")


# --- symlink loops ---------------------------------------------------------------------------------


def test_a_symlink_loop_as_out_or_an_output_name_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Issue 56 case 5: RuntimeError: Symlink loop.
    model = save_tiny_model(tmp_path / "m.pt")
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    _one_line(main(_predict(tmp_path, model, loop)), capsys, "symbolic link loop")
    _one_line(main(_predict(tmp_path, model, loop / "sub")), capsys, "symbolic link loop")
    out = tmp_path / "out"
    out.mkdir()
    (out / "a_disp.png").symlink_to(out / "a_disp.png")
    _one_line(main(_predict(tmp_path, model, out)), capsys, "symbolic link loop")
    assert (out / "a_disp.png").is_symlink()
    _one_line(load_study("power").main(["--out", str(loop)]), capsys, "symbolic link loop")


# --- every entry point that writes into a user-named folder goes through the policy ------------------

# studies/prepare_set.py's outputs besides params.yaml (tests/test_study_outputs.py plants that one):
# the index, rois and cache stages' files, and an extra set's index that the index stage would remove.
PREPARED = (
    "data/index/train_pairs.txt",
    "data/index/eval_frames.csv",
    "data/index/report.json",
    "data/index/rois.csv",
    "data/index/rois.png",
    "data/index/sets/mine.csv",
    "data/cache/train_pairs.npy",
    "data/cache/train_pairs.txt",
    "data/cache/report.json",
)


@pytest.mark.parametrize("name", PREPARED)
def test_prepare_set_refuses_a_users_file_at_every_output_name(
    name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Issue 56 case 1: `prepare_set.py --out DIR` replaced DIR/data/index/train_pairs.txt and
    # eval_frames.csv with rc 0 (its manifest listed only params.yaml).
    out = tmp_path.resolve() / "project"
    user = _users_file(out / name)
    code = load_study("prepare_set").main(["--out", str(out)])
    _one_line(code, capsys, f"{user}: exists and was not written by msdepth prepare-set")
    assert user.read_bytes() == USERS
    assert [p for p in out.rglob("*") if p.is_file()] == [user]


# --- numeric params that had no upper bound ---------------------------------------------------------


@pytest.mark.parametrize(
    "section, key, too_large, largest",
    [
        # 10^12 passed validation, then numpy was asked for 7.28 TiB.
        ("compare", "bootstrap_samples", 10**12, 1_000_000),
        # 10^6 passed; torch.set_num_threads(10**6) made process creation fail machine-wide.
        ("train", "threads", 10**6, 4 * (os.cpu_count() or 1)),
        ("optimum", "threads", 10**6, 4 * (os.cpu_count() or 1)),
    ],
)
def test_unbounded_numbers_are_refused_in_one_line(
    section: str, key: str, too_large: int, largest: int
) -> None:
    from msdepth.config.params import params_from_dict
    from msdepth.errors import ConfigError

    with pytest.raises(ConfigError, match=rf"^{section}\.{key}: must be in \d+\.\.[\d,]+ .*got {too_large}$"):
        params_from_dict({section: {key: too_large}})
    assert getattr(getattr(params_from_dict({section: {key: largest}}), section), key) == largest
    with pytest.raises(ConfigError, match=rf"^{section}\.{key}: "):
        params_from_dict({section: {key: largest + 1}})


# --- tracebacks and hangs that are one line now --------------------------------------------------------


def _deep_file(path: Path, depth: int = 5000) -> Path:
    """A torch.save'd dict holding a list nested ``depth`` deep (torch.save needs the recursion)."""
    import torch

    nested: list = []
    for _ in range(depth):
        nested = [nested]
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(4 * depth)
    try:
        torch.save({"model": nested, "encoder.conv1.weight": torch.zeros(1)}, path)
    finally:
        sys.setrecursionlimit(limit)
    return path


def test_a_file_nested_5000_deep_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Issue 56 case 5: a RecursionError traceback from load_checkpoint / load_pretrained.
    import torch

    from msdepth.errors import MsdepthError
    from msdepth.networks.resnet import ResNetEncoder, load_pretrained
    from msdepth.training.train import _load_checkpoint

    deep = _deep_file(tmp_path / "deep.pt")
    expected = "nest deeper than 32 levels"
    with pytest.raises(MsdepthError, match=expected):
        _load_checkpoint(deep, torch.device("cpu"))
    with pytest.raises(MsdepthError, match=expected):
        load_pretrained(ResNetEncoder(), deep)
    _one_line(main(_predict(tmp_path, deep, tmp_path / "out")), capsys, expected)


def test_a_pretrained_path_with_a_name_too_long_is_one_line(tmp_path: Path) -> None:
    # Issue 56 case 5: OSError: File name too long, during params validation.
    from msdepth.config.params import params_from_dict
    from msdepth.errors import ConfigError

    model = {"architecture": "resnet18", "width_multiplier": 1.0, "pretrained": str(tmp_path / ("a" * 300))}
    with pytest.raises(ConfigError, match=r"^model\.pretrained: cannot open it \(File name too long\): "):
        params_from_dict({"data": {"height": 64, "width": 64}, "model": model})


def test_a_fifo_as_the_video_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Issue 56 case 6: OpenCV's open of a FIFO named clip.mp4 blocked forever.
    from conftest import unblocking

    fifo = tmp_path / "clip.mp4"
    os.mkfifo(fifo)
    argv = [
        "predict",
        str(fifo),
        "--model",
        str(save_tiny_model(tmp_path / "m.pt")),
        "--out",
        str(tmp_path / "o"),
    ]
    with unblocking(fifo):
        _one_line(main([*argv, "--quiet"]), capsys, "clip.mp4: not a regular file")
