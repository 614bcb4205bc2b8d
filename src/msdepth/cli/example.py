"""The predict example of docs/user-guide.md, regenerated from the committed models.

``python -m msdepth.cli.example`` (after ``dvc repro``, or ``dvc pull`` of the models) copies
evaluation frame :data:`FRAME` of the data tree to ``docs/example/`` and writes beside it the
disparity that each variant's first-seed model predicts for it, as ``msdepth predict --colorbar``
draws it (``<frame>_disp_<variant>.png``). ``docs/example/example.json`` records which model
(path and md5, the hash ``dvc.lock`` gives it) made each image and its size, so that
tests/test_example.py can tell, without the models, whether the committed images are the
committed models' (the images are not a pipeline output: their text labels are drawn by OpenCV,
whose pixels change between releases, and a fresh clone must stay clean).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import sys
import tempfile
from pathlib import Path

from msdepth.config.params import Params, load_params
from msdepth.data.imagefile import png_size
from msdepth.data.kitti import kitti2015_paths
from msdepth.data.layout import layout
from msdepth.errors import DataError, MsdepthError, unexpected_error
from msdepth.io import atomic_path, write_json
from msdepth.outputs import OutputPolicy, settle_outputs
from msdepth.pipeline.paths import model_path, run_name

COMMAND = "python -m msdepth.cli.example"
FRAME = "000003_10"
OUT = Path("docs/example")
MANIFEST = "example.json"


def _disparity_name(variant: str) -> str:
    """The example image of ``variant``'s model."""
    return f"{FRAME}_disp_{variant}.png"


def md5(path: Path) -> str:
    """The file's md5, as DVC records it in dvc.lock."""
    digest = hashlib.md5()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _example_models(params: Params, root: Path) -> dict[str, Path]:
    """Each variant's first-seed model under ``root``; DataError naming the first one missing."""
    models = {v: root / model_path(run_name(v, params.train.seeds[0])) for v in params.variants}
    for path in models.values():
        if not path.is_file():
            raise DataError(
                f"{path}: missing; the example is drawn from the trained models: run `dvc repro` first"
            )
    return models


def _example_frame(params: Params, root: Path) -> Path:
    """The left image of :data:`FRAME` in the data tree (KITTI 2015 layout)."""
    if params.data.source == "folder":
        raise DataError(
            "params.yaml: data.source folder: the example is a KITTI 2015 frame (synthetic or kitti)"
        )
    frame = kitti2015_paths(root / layout(params).kitti2015_root, FRAME)["left"]
    if not frame.is_file():
        raise DataError(f"{frame}: missing; run `dvc repro prepare_data` first")
    return frame


def _make_example(params: Params, root: Path = Path("."), out: Path | None = None) -> dict:
    """Write the example into ``out`` (default ``root/docs/example``): the frame, each variant's
    disparity and the manifest; return the manifest. Every file is written whole (temp, rename)."""
    from msdepth.cli.predict import PredictOptions, predict

    out = root / OUT if out is None else out
    frame, models = _example_frame(params, root), _example_models(params, root)
    options = PredictOptions(
        disp_format="png", depth_format="none", colorbar=True, device="cpu", progress=False
    )
    manifest: dict = {"command": COMMAND, "frame": FRAME, "input": f"{FRAME}.png", "images": {}}
    # Through the output policy (manifest out/.msdepth-example): a user's file at an output name is
    # refused in one line (OutputError) before anything is written.
    outputs = [out / f"{FRAME}.png", *(out / _disparity_name(v) for v in models), out / MANIFEST]
    OutputPolicy(out, "example", (frame, *models.values())).claim(outputs, frame)
    with atomic_path(out / f"{FRAME}.png") as tmp:
        shutil.copyfile(frame, tmp)
    for variant, model in models.items():
        with tempfile.TemporaryDirectory(dir=out) as work:
            report = predict(frame, model, work, options)
            if report.failed:
                raise DataError(f"{frame}: {report.failed[0][1]}")
            written = Path(work) / f"{FRAME}_disp.png"
            width, height = png_size(written.read_bytes())
            with atomic_path(out / _disparity_name(variant)) as tmp:
                os.replace(written, tmp)
        manifest["images"][variant] = {
            "file": _disparity_name(variant),
            "model": model.relative_to(root).as_posix(),
            "model_md5": md5(model),
            "width": width,
            "height": height,
        }
    write_json(out / MANIFEST, manifest)
    return manifest


def main(argv: list[str] | None = None) -> int:
    """Regenerate docs/example/ from the trained models (exit 1, one line, on an error)."""
    ap = argparse.ArgumentParser(
        prog=COMMAND, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--root", type=Path, default=Path("."), help="the project folder (params.yaml, models/, data/)"
    )
    args = ap.parse_args(argv)
    try:
        manifest = _make_example(load_params(args.root / "params.yaml"), args.root)
    except (MsdepthError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # a bug: one line naming the command, the traceback in a log file
        print(unexpected_error("msdepth.cli.example", exc, list(argv or sys.argv[1:])), file=sys.stderr)
        return 1
    finally:
        settle_outputs()  # docs/example/.msdepth-example lists only the files that were written
    for image in manifest["images"].values():
        print(f"{OUT / image['file']}: {image['width']} x {image['height']} from {image['model']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
