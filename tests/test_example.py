"""docs/example/ (the predict example of docs/user-guide.md): `python -m msdepth.cli.example` regenerates
it from the trained models, and the committed images are the committed models' (issue 29 item 3)."""

from __future__ import annotations

import json
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import yaml
from conftest import committed_file, require_git_checkout

from msdepth.__main__ import main as msdepth_main
from msdepth.cli.example import FRAME, MANIFEST, OUT, _disparity_name, main, md5
from msdepth.data.imagefile import png_size
from msdepth.networks.vgg import MonodepthVGG
from msdepth.outputs import _manifest_line, _read_manifest

ROOT = Path(__file__).resolve().parents[1]


# Reads a project file (a path relative to the project) as bytes; None where it is missing.
Reader = Callable[[str], "bytes | None"]


def workspace(root: Path) -> Reader:
    """A reader of the files under ``root`` as they are on disk."""
    return lambda path: (root / path).read_bytes() if (root / path).is_file() else None


def committed(root: Path) -> Reader:
    """A reader of the files as git's HEAD at ``root`` holds them (the test skips outside a checkout):
    a `dvc repro` on another CPU rewrites the models and dvc.lock's hashes, never the commit."""
    require_git_checkout(root)
    return lambda path: committed_file(root, path)


def locked_md5(lock: bytes | None, path: str) -> str | None:
    """The md5 that the dvc.lock text ``lock`` records for the output ``path`` (None if it lists no
    such output, or there is no lock)."""
    stages = (yaml.safe_load(lock or b"") or {}).get("stages", {})
    outs = [entry for stage in stages.values() for entry in stage.get("outs", [])]
    return next((entry.get("md5") for entry in outs if entry.get("path") == path), None)


def stale_example(read: Reader) -> list[str]:
    """Why the example that ``read`` gives is not the models' that its dvc.lock records (empty if it
    is): per image, a model hash other than dvc.lock's or a size other than the manifest's."""
    name = (OUT / MANIFEST).as_posix()
    try:
        manifest = json.loads(read(name) or b"")
    except json.JSONDecodeError as exc:
        return [f"{name}: missing or not JSON ({exc})"]
    lock = read("dvc.lock")
    problems = []
    for image in manifest["images"].values():
        path = (OUT / image["file"]).as_posix()
        locked = locked_md5(lock, image["model"])
        if locked != image["model_md5"]:
            problems.append(
                f"{path}: drawn by {image['model']} md5 {image['model_md5']}, dvc.lock has {locked}"
            )
        drawn = read(path)
        if drawn is None or png_size(drawn) != (image["width"], image["height"]):
            problems.append(f"{path}: not the {image['width']} x {image['height']} image the command wrote")
    return problems


def test_the_committed_example_is_drawn_by_the_committed_models():
    """Fails when the committed dvc.lock's models change (a retrained default run) until the example
    is redrawn, or when an image is not the size the command wrote. It reads the commit, not the
    workspace: `dvc repro` on another CPU trains other bytes and rewrites the workspace's dvc.lock."""
    problems = stale_example(committed(ROOT))
    assert not problems, "\n".join(problems) + "\nrun `python -m msdepth.cli.example` after `dvc repro`"


def _tiny_model(path: Path, seed: int) -> None:
    torch.manual_seed(seed)
    state = {
        "model": MonodepthVGG(0.0625).eval().state_dict(),
        "criterion": {},
        "width_multiplier": 0.0625,
        "height": 32,
        "width": 96,
        "variant": "tiny",
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, path)


@pytest.fixture
def project(tmp_path: Path) -> Path:
    """The committed params, a rendered frame 000003_10 (48 x 128) and two tiny models."""
    shutil.copy(ROOT / "params.yaml", tmp_path / "params.yaml")
    root = yaml.safe_load((ROOT / "params.yaml").read_text())["data"]["root"]
    frame = tmp_path / root / "kitti2015" / "training" / "image_2" / f"{FRAME}.png"
    frame.parent.mkdir(parents=True)
    small = np.random.default_rng(0).integers(0, 256, (6, 16, 3), dtype=np.uint8)
    assert cv2.imwrite(str(frame), cv2.resize(small, (128, 48), interpolation=cv2.INTER_LINEAR))
    for i, variant in enumerate(("ssim", "msssim")):
        _tiny_model(tmp_path / "models" / variant / "seed0" / "model.pt", i)
    return tmp_path


def _lock(root: Path, manifest: dict) -> None:
    """A dvc.lock recording the models' md5s, as `dvc repro` would."""
    stages = {
        f"train@{v}-0": {"outs": [{"path": image["model"], "hash": "md5", "md5": image["model_md5"]}]}
        for v, image in manifest["images"].items()
    }
    (root / "dvc.lock").write_text(yaml.safe_dump({"schema": "2.0", "stages": stages}))


def test_the_command_draws_each_variant_as_predict_does(project: Path, tmp_path_factory):
    assert main(["--root", str(project)]) == 0
    out = project / OUT
    frame = project / "data" / "synthetic" / "kitti2015" / "training" / "image_2" / f"{FRAME}.png"
    assert (out / f"{FRAME}.png").read_bytes() == frame.read_bytes()
    manifest = json.loads((out / MANIFEST).read_text())
    written = [f"{FRAME}.png", _disparity_name("ssim"), _disparity_name("msssim"), MANIFEST]
    assert sorted(p.name for p in out.iterdir()) == sorted([*written, ".msdepth-example"])
    assert (out / ".msdepth-example").read_text() == "".join(_manifest_line(n) for n in written)
    for variant in ("ssim", "msssim"):
        image = manifest["images"][variant]
        model = project / "models" / variant / "seed0" / "model.pt"
        assert image["model"] == f"models/{variant}/seed0/model.pt" and image["model_md5"] == md5(model)
        # the same bytes as `msdepth predict --colorbar` writes
        alone = tmp_path_factory.mktemp("alone")
        args = [str(frame), "--model", str(model), "--out", str(alone), "--colorbar", "--quiet"]
        assert msdepth_main(["predict", *args, "--depth-format", "none", "--device", "cpu"]) == 0
        drawn = (out / image["file"]).read_bytes()
        assert drawn == (alone / f"{FRAME}_disp.png").read_bytes()
        width, height = png_size(drawn)
        assert (image["width"], image["height"]) == (width, height) and height == 48 and width > 128
    _lock(project, manifest)
    assert stale_example(workspace(project)) == []


def test_a_retrained_model_or_a_resized_image_is_found(project: Path):
    assert main(["--root", str(project)]) == 0
    manifest = json.loads((project / OUT / MANIFEST).read_text())
    _lock(project, manifest)
    _tiny_model(project / "models" / "msssim" / "seed0" / "model.pt", 7)  # retrained
    manifest["images"]["msssim"]["model_md5"] = md5(project / "models" / "msssim" / "seed0" / "model.pt")
    _lock(project, manifest)
    problems = stale_example(workspace(project))
    image = (OUT / _disparity_name("msssim")).as_posix()
    assert len(problems) == 1 and problems[0].startswith(f"{image}: drawn by")
    shutil.copy(project / OUT / f"{FRAME}.png", project / OUT / _disparity_name("ssim"))  # another size
    assert any("not the" in p and _disparity_name("ssim") in p for p in stale_example(workspace(project)))


def _git(root: Path, *args: str) -> None:
    """``git <args>`` in ``root``, with an identity of its own (a commit needs one)."""
    identity = ["-c", "user.email=t@t", "-c", "user.name=t"]
    subprocess.run(["git", "-C", str(root), *identity, *args], check=True, capture_output=True)


def test_a_retrain_with_other_bytes_leaves_the_committed_example_checked(project: Path):
    """Issue 53: after README's command 1 on another CPU, the workspace's models and dvc.lock hold
    other bytes than the commit's; the check reads the commit, so it still passes there, and still
    finds a commit whose models are not the example's."""
    assert main(["--root", str(project)]) == 0
    manifest = json.loads((project / OUT / MANIFEST).read_text())
    _lock(project, manifest)
    for args in (["init", "-q"], ["add", "-A"], ["commit", "-qm", "the committed run"]):
        _git(project, *args)
    for i, variant in enumerate(("ssim", "msssim")):  # `dvc repro` on another CPU: other bytes
        _tiny_model(project / "models" / variant / "seed0" / "model.pt", 10 + i)
        manifest["images"][variant]["model_md5"] = md5(project / "models" / variant / "seed0" / "model.pt")
    _lock(project, manifest)
    assert len(stale_example(workspace(project))) == 2  # the workspace's lock is not the example's
    assert stale_example(committed(project)) == []
    _git(project, "commit", "-qam", "relocked")
    assert len(stale_example(committed(project))) == 2  # a committed relock without a redrawn example


def test_missing_models_are_one_line(project: Path, capsys):
    (project / "models" / "msssim" / "seed0" / "model.pt").unlink()
    assert main(["--root", str(project)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"error: {project / 'models/msssim/seed0/model.pt'}: missing; the example is drawn from the "
        "trained models: run `dvc repro` first"
    ]
    assert not (project / OUT).exists()


@pytest.mark.parametrize("name", [f"{FRAME}.png", _disparity_name("msssim"), MANIFEST])
def test_a_users_file_at_an_output_name_is_refused_in_one_line(project: Path, capsys, name: str):
    """Issue 56 case 4: the command replaced a user's docs/example/* files; it goes through the output
    policy now: the user's file is named in one line and left as it was, nothing else is written."""
    user = project / OUT / name
    user.parent.mkdir(parents=True)
    user.write_bytes(b"the user's own file\n")
    assert main(["--root", str(project)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {user}: exists and was not written"), err
    assert user.read_bytes() == b"the user's own file\n"
    assert [p.name for p in (project / OUT).iterdir()] == [name]


def test_the_committed_example_is_listed_in_its_manifest():
    """The committed images are the command's own: a rerun may replace them, and only them."""
    names = {
        f"{FRAME}.png",
        MANIFEST,
        *(image["file"] for image in json.loads((ROOT / OUT / MANIFEST).read_text())["images"].values()),
    }
    assert _read_manifest(ROOT / OUT / ".msdepth-example") == names
