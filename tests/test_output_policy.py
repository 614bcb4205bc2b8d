"""The shared output policy (:class:`msdepth.outputs.OutputPolicy`) and every ``msdepth`` subcommand
that writes.

:data:`WRITERS` holds, per subcommand, the arguments that make it write into a folder of the test's
choosing; ``test_every_subcommand_is_walked`` enumerates the subcommands from the parser itself, so a
new subcommand fails until it is added there and passes the same hostile cases (issue 42): an output
that is an input or the model, a user's own file at an output name, ``--out`` that names a file (or
a folder, for a file output), lies under a file or cannot be created. Each must be refused in one
line with nothing changed.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest
from conftest import save_tiny_model

from msdepth.__main__ import _build_parser, main
from msdepth.config.params import SyntheticConfig
from msdepth.errors import OutputError
from msdepth.io import write_text
from msdepth.outputs import OutputPolicy, _manifest_line, _read_manifest, claim_output_file
from msdepth.render import generate

FAST_OPTIMUM = ["--variant", "ssim", "--set", "optimum.iterations=2", "--set", "optimum.levels=1", "--quiet"]
TINY = SyntheticConfig(seed=3, drives=1, train_pairs=2, eval_frames=1, height=24, width=80)


def _image(path: Path, value: int = 1) -> bytes:
    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(value)
    ok, data = cv2.imencode(path.suffix, cv2.resize(rng.integers(0, 256, (6, 16, 3), np.uint8), (128, 48)))
    assert ok
    path.write_bytes(data.tobytes())
    return data.tobytes()


@pytest.fixture(scope="module")
def model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save_tiny_model(tmp_path_factory.mktemp("model") / "model.pt")


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("synthetic") / "data"
    generate(TINY, root, progress=False, workers=1, lidar=False)
    return root


# Per subcommand: (the arguments that write to OUT, the input folder or file a hostile --out may
# name, a file the command would write under OUT, whether --out names a file rather than a folder).
Writer = Callable[[Path, Path, Path, Path], tuple[list[str], Path, Path, bool]]


def _predict(tmp: Path, out: Path, model: Path, synthetic: Path) -> tuple[list[str], Path, Path, bool]:
    _image(tmp / "in" / "a.png")
    return (
        ["predict", str(tmp / "in"), "--model", str(model), "--out", str(out), "--quiet"],
        tmp / "in",
        out / "a_disp.png",
        False,
    )


def _optimum(tmp: Path, out: Path, model: Path, synthetic: Path) -> tuple[list[str], Path, Path, bool]:
    _image(tmp / "L" / "a.png", 1)
    _image(tmp / "R" / "a.png", 2)
    return (
        ["optimum", str(tmp / "L"), str(tmp / "R"), "--out", str(out), *FAST_OPTIMUM],
        tmp / "L",
        out / "a_ssim_disp.npy",
        False,
    )


def _export_onnx(tmp: Path, out: Path, model: Path, synthetic: Path) -> tuple[list[str], Path, Path, bool]:
    return ["export-onnx", "--model", str(model), "--out", str(out)], model, out, True


def _export_folder(tmp: Path, out: Path, model: Path, synthetic: Path) -> tuple[list[str], Path, Path, bool]:
    return ["export-folder", "--from", str(synthetic), "--to", str(out)], synthetic, out / "eval.txt", False


def _photometry(tmp: Path, out: Path, model: Path, synthetic: Path) -> tuple[list[str], Path, Path, bool]:
    source = synthetic / "kitti2015"  # training/: image_2, image_3, disp_occ_0
    return ["photometry", str(source), "--out", str(out), "--width", "40"], source, out, True


WRITERS: dict[str, Writer] = {
    "predict": _predict,
    "optimum": _optimum,
    "export-onnx": _export_onnx,
    "export-folder": _export_folder,
    "photometry": _photometry,
}
# Subcommands that write no file (their output is stdout): nothing for the hostile cases to reach.
READ_ONLY = frozenset({"experiments"})


def test_every_subcommand_is_walked() -> None:
    # A new subcommand fails here until WRITERS says how it writes, so the hostile cases reach it.
    sub = next(a for a in _build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert set(sub.choices) == set(WRITERS) | READ_ONLY


def _tree(root: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in root.rglob("*") if p.is_file()}


def _one_line_refusal(argv: list[str], capsys: pytest.CaptureFixture[str], expected: str) -> None:
    assert main(argv) == 1
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert "Traceback" not in err and len(errors) == 1, err
    assert expected in errors[0], errors[0]


def _user_file_at_output(
    args: list[str], source: Path, target: Path, file_out: bool
) -> tuple[list[str], str]:
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(b"the user's own file")  # where the command would write
    return args, "exists and" if not file_out else "was not written by msdepth"


def _out_is_the_input(args: list[str], source: Path, target: Path, file_out: bool) -> tuple[list[str], str]:
    out = args[args.index("--to" if "--to" in args else "--out") + 1]
    return [source.as_posix() if a == out else a for a in args], "input"


def _out_is_the_other_kind(
    args: list[str], source: Path, target: Path, file_out: bool
) -> tuple[list[str], str]:
    flag = "--to" if "--to" in args else "--out"
    out = Path(args[args.index(flag) + 1])
    if file_out:
        out.mkdir(parents=True)
        return args, "a folder"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(b"the user's own file")
    return args, "not a folder"


def _out_under_a_file(args: list[str], source: Path, target: Path, file_out: bool) -> tuple[list[str], str]:
    flag = "--to" if "--to" in args else "--out"
    out = Path(args[args.index(flag) + 1])
    _image(out.parent / "photo.png", 9)  # the user's photo, where a folder would have to be
    args[args.index(flag) + 1] = str(out.parent / "photo.png" / "sub" / out.name)
    return args, "under the file"


def _out_in_proc(args: list[str], source: Path, target: Path, file_out: bool) -> tuple[list[str], str]:
    flag = "--to" if "--to" in args else "--out"
    args[args.index(flag) + 1] = "/proc/msdepth-test/out" + (".onnx" if file_out else "")
    return args, "/proc/msdepth-test"


def _out_is_the_root(args: list[str], source: Path, target: Path, file_out: bool) -> tuple[list[str], str]:
    # Issue 56: predict and optimum listed their inputs, every one inside the output folder and so left
    # out, then said "no images"; the policy refuses the root before any input is listed.
    flag = "--to" if "--to" in args else "--out"
    args[args.index(flag) + 1] = "/"
    return args, "a folder" if file_out else "/: the filesystem root, not an output folder"


def _out_holds_the_input(
    args: list[str], source: Path, target: Path, file_out: bool
) -> tuple[list[str], str]:
    # the same inside any folder: its inputs were left out as outputs, then "no images"
    flag = "--to" if "--to" in args else "--out"
    args[args.index(flag) + 1] = str(source.parent)
    return args, "a folder" if file_out else f"the output folder holds the input folder {source}"


CASES = {
    "out_is_the_root": _out_is_the_root,
    "out_holds_an_input": _out_holds_the_input,
    "user_file_at_an_output_name": _user_file_at_output,
    "out_is_an_input": _out_is_the_input,
    "out_is_a_file_or_a_folder": _out_is_the_other_kind,
    "out_under_a_file": _out_under_a_file,
    "out_cannot_be_created": _out_in_proc,
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("command", sorted(WRITERS))
def test_every_subcommand_refuses_hostile_outputs_in_one_line(
    command: str, case: str, model: Path, synthetic: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out" / ("m.onnx" if command == "export-onnx" else "")
    args, source, target, file_out = WRITERS[command](tmp_path, out, model, synthetic)
    args, expected = CASES[case](args, source, target, file_out)
    before = {**_tree(tmp_path), **_tree(model.parent), **_tree(synthetic)}
    _one_line_refusal(args, capsys, expected)
    after = {**_tree(tmp_path), **_tree(model.parent), **_tree(synthetic)}
    assert {p: after.get(p) for p in before} == before  # nothing replaced or removed
    assert not [p for p in after if p not in before and not p.name.startswith(".msdepth-")]


def test_predict_and_optimum_refuse_two_inputs_with_one_output(
    model: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Issue 42 case 2: a.png and a.jpg both wrote a_*, "2 of 2 written", one result lost.
    for side, value in (("L", 1), ("R", 2)):
        _image(tmp_path / side / "a.png", value)
        _image(tmp_path / side / "a.jpg", value)
    out = tmp_path / "out"
    _one_line_refusal(
        ["optimum", str(tmp_path / "L"), str(tmp_path / "R"), "--out", str(out), *FAST_OPTIMUM],
        capsys,
        "a.png: same output name as",
    )
    optimum = _tree(out)
    assert (
        main(["predict", str(tmp_path / "L"), "--model", str(model), "--out", str(tmp_path / "p"), "--quiet"])
        == 1
    )
    assert "L/a.png: same output name as" in capsys.readouterr().err
    assert _tree(out) == optimum and (out / "a_ssim_disp.npy").is_file()


def test_optimum_refuses_left_equal_to_right(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Issue 42 case 14: LEFT == RIGHT wrote a result (mean 1.2 px disparity) with no warning.
    _image(tmp_path / "L" / "a.png")
    for left, right in (
        (tmp_path / "L", tmp_path / "L"),
        (tmp_path / "L" / "a.png", tmp_path / "L" / "a.png"),
    ):
        _one_line_refusal(
            ["optimum", str(left), str(right), "--out", str(tmp_path / "out"), *FAST_OPTIMUM],
            capsys,
            "LEFT and RIGHT are the same",
        )
    assert not (tmp_path / "out").exists()


def test_names_with_any_byte_keep_the_manifest_exact(
    model: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Issue 42 cases 3 and 9: "evil\nscene.png" forged the manifest line "scene_disp.png"; U+2028 in
    # a name made every rerun refuse predict's own outputs; "caf\xe9.png" crashed the manifest write.
    names = [
        "evil\nscene.png",
        "line\u2028sep.png",
        "cr\rname.png",
        "nel\x85.png",
        os.fsdecode(b"caf\xe9.png"),
    ]
    for i, name in enumerate(names):
        _image(tmp_path / "in" / name, i)
    users = _image(tmp_path / "out" / "scene_disp.png", 9)
    argv = ["predict", str(tmp_path / "in"), "--model", str(model), "--out", str(tmp_path / "out"), "--quiet"]
    assert main(argv) == 0, capsys.readouterr().err
    assert main(argv) == 0, capsys.readouterr().err  # its own outputs, however named, may be rewritten
    assert "scene_disp.png" not in _read_manifest(tmp_path / "out" / ".msdepth-predict")
    _image(tmp_path / "in" / "scene.png", 7)
    assert main(argv) == 1
    assert "scene_disp.png: exists and was not written by msdepth predict" in capsys.readouterr().err
    assert (tmp_path / "out" / "scene_disp.png").read_bytes() == users
    for name in names:
        assert (tmp_path / "out" / (Path(name).stem + "_disp.png")).is_file()


def test_manifest_lines_round_trip_any_name_and_read_old_plain_manifests(tmp_path: Path) -> None:
    names = ["a\nb", "c\u2028d", "e\rf", "g\x85", os.fsdecode(b"caf\xe9"), '"quoted', "plain"]
    manifest = tmp_path / ".msdepth-predict"
    manifest.write_text("".join(_manifest_line(n) for n in names), encoding="ascii")
    assert manifest.read_bytes().count(b"\n") == len(names)
    assert _read_manifest(manifest) == set(names)
    manifest.write_text("old_disp.png\nsub/old_depth.png\n")  # an earlier version's plain lines
    assert _read_manifest(manifest) == {"old_disp.png", "sub/old_depth.png"}


def test_a_policy_refuses_the_manifest_and_paths_leaving_the_folder(tmp_path: Path) -> None:
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "link").symlink_to(tmp_path / "elsewhere")
    policy = OutputPolicy(tmp_path / "out", "predict")
    for path in (tmp_path / "out" / ".msdepth-predict", tmp_path / "out" / "link" / "x.png"):
        with pytest.raises(OutputError, match="not a path msdepth predict may write"):
            policy.claim([path], "in.png")
    assert not (tmp_path / "out" / ".msdepth-predict").exists()


def test_the_root_or_a_folder_holding_an_input_is_no_output_folder(tmp_path: Path) -> None:
    # Issue 56: --out / for a study or a command; every path that resolves to the root counts.
    (tmp_path / "in").mkdir()
    (tmp_path / "up").symlink_to("/")
    for root in ("/", tmp_path / "up", "/tmp/.."):
        with pytest.raises(OutputError, match=r": the filesystem root, not an output folder"):
            OutputPolicy(root, "learning")
    with pytest.raises(OutputError, match=r": the output folder holds the input folder .*in, whose files"):
        OutputPolicy(tmp_path, "predict", input_dirs=(tmp_path / "in",))
    OutputPolicy(tmp_path / "in" / "out", "predict", input_dirs=(tmp_path / "in",))  # inside one: allowed


def test_a_study_claims_its_one_file_or_refuses_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "report.md"
    assert claim_output_file(None, "power", "metrics")  # nothing asked: nothing to claim
    assert claim_output_file(out, "power", "metrics") and not out.exists()
    assert _read_manifest(tmp_path / ".msdepth-power") == set()  # pending until written
    write_text(out, "the study's own report\n")
    assert _read_manifest(tmp_path / ".msdepth-power") == {"report.md"}
    assert claim_output_file(out, "power", "metrics")  # its own file, listed: rewritable
    users = tmp_path / "notes.md"
    users.write_text("a user's notes\n")
    capsys.readouterr()
    assert not claim_output_file(users, "power", "metrics")
    assert not claim_output_file(tmp_path, "power", "metrics")  # a folder
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and "notes.md: exists and was not written by msdepth power" in err[0]
    assert "a folder" in err[1] and users.read_text() == "a user's notes\n"


def test_optimum_writes_each_batch_before_the_next_is_optimised(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Issue 42 case 8: nothing was written until the last pair finished, so a kill lost the whole run.
    # Here the second batch's optimisation is interrupted: the first pair's outputs are already there.
    import msdepth.optimum.solver as solver

    calls = []

    def optimum_disparities(pairs, *args, **kwargs):
        calls.append(len(pairs))
        if len(calls) > 1:
            raise KeyboardInterrupt  # as a kill midway would stop it
        return [np.full(left.shape[:2], 0.05, np.float32) for left, _ in pairs]

    monkeypatch.setattr(solver, "optimum_disparities", optimum_disparities)
    for name in ("a", "b"):
        _image(tmp_path / "L" / f"{name}.png", 1)
        _image(tmp_path / "R" / f"{name}.png", 2)
    out = tmp_path / "out"
    argv = ["optimum", str(tmp_path / "L"), str(tmp_path / "R"), "--out", str(out), *FAST_OPTIMUM]
    with pytest.raises(KeyboardInterrupt):
        main([*argv, "--set", "optimum.batch_size=1"])
    assert calls == [1, 1]
    assert sorted(p.name for p in out.iterdir()) == [
        ".msdepth-optimum",
        *(f"a_ssim{s}" for s in OPTIMUM_SUFFIXES),
    ]


OPTIMUM_SUFFIXES = ("_depth.npy", "_disp.npy", "_disp.png")


def test_export_folder_refuses_a_folder_inside_the_tree_it_exports(
    synthetic: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Issue 68 (a turn-5 case): `--from data/synthetic --to data/synthetic/out` wrote into the tree,
    # a DVC output, and `--to data/synthetic/raw/x` among its drives.
    before = _tree(synthetic)
    for inside in (synthetic / "out", synthetic / "raw" / "x"):
        _one_line_refusal(
            ["export-folder", "--from", str(synthetic), "--to", str(inside)],
            capsys,
            "inside the tree it exports",
        )
    assert _tree(synthetic) == before
