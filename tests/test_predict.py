"""`msdepth predict` / `msdepth export-onnx`: outputs, bad input, video, ONNX parity."""

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from msdepth.__main__ import main
from msdepth.cli.predict import PredictReport, _input_frames
from msdepth.data.kitti import KITTI_BASELINE, WIDTH_TO_FOCAL
from msdepth.data.pairs import resize, to_tensor
from msdepth.evaluation.infer import post_process_disparity
from msdepth.io import atomic_path
from msdepth.networks.vgg import MonodepthVGG

NET_H, NET_W = 32, 96  # the tiny model's "training" size
IMG_H, IMG_W = 48, 128  # inputs differ from it, so resizing back is exercised


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> tuple[Path, MonodepthVGG]:
    """A randomly initialised MonodepthVGG(0.0625) saved as save_model writes it."""
    torch.manual_seed(0)
    model = MonodepthVGG(0.0625).eval()
    path = tmp_path_factory.mktemp("model") / "model.pt"
    state = {
        "model": model.state_dict(),
        "criterion": {},
        "width_multiplier": 0.0625,
        "height": NET_H,
        "width": NET_W,
        "variant": "tiny",
    }
    torch.save(state, path)
    return path, model


def make_image(seed: int, h: int = IMG_H, w: int = IMG_W) -> np.ndarray:
    """Smooth random RGB (uint8), so the network sees some structure."""
    small = np.random.default_rng(seed).integers(0, 256, (h // 8, w // 8, 3), dtype=np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def write_image(path: Path, seed: int) -> np.ndarray:
    path.parent.mkdir(parents=True, exist_ok=True)
    rgb = make_image(seed)
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return rgb


def run(*args: str | Path) -> int:
    return main(["predict", *map(str, args), "--quiet"])


def expected_disparity(model: MonodepthVGG, rgb: np.ndarray, post_process: bool = True) -> np.ndarray:
    """Disparity in px at the image's resolution, computed independently of msdepth.cli.predict."""
    x = to_tensor(resize(rgb, NET_H, NET_W))[None]
    with torch.no_grad():
        d = model(x)[0][0, 0].numpy()
        if post_process:
            d_f = model(torch.flip(x, dims=[-1]))[0][0, 0].numpy()
            d = post_process_disparity(d, d_f)
    h, w = rgb.shape[:2]
    return w * cv2.resize(d, (w, h), interpolation=cv2.INTER_LINEAR)


def read_ply(path: Path) -> np.ndarray:
    """Minimal PLY reader for x y z (float) red green blue (uchar) vertices."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[0] == "ply"
    fmt = next(line.split()[1] for line in header if line.startswith("format"))
    count = int(next(line.split()[2] for line in header if line.startswith("element vertex")))
    props = [line.split()[1:] for line in header if line.startswith("property")]
    assert props == [
        ["float", "x"],
        ["float", "y"],
        ["float", "z"],
        ["uchar", "red"],
        ["uchar", "green"],
        ["uchar", "blue"],
    ]
    dtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    if fmt == "binary_little_endian":
        assert len(data) - end == count * dtype.itemsize
        return np.frombuffer(data, dtype=dtype, offset=end)
    assert fmt == "ascii"
    rows = np.loadtxt(data[end:].decode("ascii").splitlines(), ndmin=2).reshape(-1, 6)
    assert len(rows) == count
    out = np.empty(count, dtype=dtype)
    for i, name in enumerate(dtype.names):
        out[name] = rows[:, i]
    return out


def test_all_outputs_of_one_image(tiny, tmp_path):
    model_path, model = tiny
    rgb = write_image(tmp_path / "in" / "frame.png", seed=1)
    out = tmp_path / "out"
    rc = run(
        tmp_path / "in" / "frame.png",
        "--model",
        model_path,
        "--out",
        out,
        "--depth-format",
        "both",
        "--ply",
        "binary",
    )
    assert rc == 0
    assert sorted(p.name for p in out.iterdir()) == [
        ".msdepth-predict",  # the files predict wrote, which a later run may replace
        "frame.ply",
        "frame_depth.npy",
        "frame_depth.png",
        "frame_disp.npy",
        "frame_disp.png",
    ]

    color = cv2.imread(str(out / "frame_disp.png"), cv2.IMREAD_UNCHANGED)
    assert color.dtype == np.uint8 and color.shape == (IMG_H, IMG_W, 3)
    assert color.std() > 0

    disp = np.load(out / "frame_disp.npy")
    assert disp.dtype == np.float32 and disp.shape == (IMG_H, IMG_W)
    np.testing.assert_allclose(disp, expected_disparity(model, rgb), rtol=1e-4, atol=1e-4)

    # Default focal: KITTI's, scaled to this width; baseline 0.54 m; all depths well under 80 m.
    focal = WIDTH_TO_FOCAL[1242] * IMG_W / 1242
    depth = np.load(out / "frame_depth.npy")
    np.testing.assert_allclose(depth, focal * KITTI_BASELINE / disp, rtol=1e-5)
    mm = cv2.imread(str(out / "frame_depth.png"), cv2.IMREAD_UNCHANGED)
    assert mm.dtype == np.uint16 and mm.shape == (IMG_H, IMG_W)
    valid = mm > 0
    assert valid.all()
    assert np.abs(mm[valid] / 1000.0 - depth[valid]).max() <= 0.001

    cloud = read_ply(out / "frame.ply")
    assert len(cloud) == IMG_H * IMG_W
    np.testing.assert_allclose(cloud["z"], depth.ravel(), rtol=1e-6)
    # Pixel (row 0, col 0): principal point at the centre, fx = fy = focal, colour from the image.
    cx, cy = (IMG_W - 1) / 2, (IMG_H - 1) / 2
    z = depth[0, 0]
    np.testing.assert_allclose([cloud["x"][0], cloud["y"][0]], [-cx * z / focal, -cy * z / focal], rtol=1e-5)
    assert (cloud["r"][0], cloud["g"][0], cloud["b"][0]) == tuple(rgb[0, 0])


def test_max_depth_invalidates_depth_and_drops_points(tiny, tmp_path):
    model_path, _ = tiny
    image = tmp_path / "a.jpg"
    write_image(image, seed=2)
    rc = run(
        image,
        "--model",
        model_path,
        "--out",
        tmp_path / "o1",
        "--disp-format",
        "npy",
        "--depth-format",
        "none",
        "--focal",
        "700",
        "--baseline",
        "0.5",
    )
    assert rc == 0
    assert sorted(p.name for p in (tmp_path / "o1").iterdir()) == [".msdepth-predict", "a_disp.npy"]
    depth_all = 700 * 0.5 / np.load(tmp_path / "o1" / "a_disp.npy")
    max_depth = float(np.median(depth_all))
    rc = run(
        image,
        "--model",
        model_path,
        "--out",
        tmp_path / "o2",
        "--disp-format",
        "none",
        "--depth-format",
        "both",
        "--ply",
        "ascii",
        "--focal",
        "700",
        "--baseline",
        "0.5",
        "--max-depth",
        str(max_depth),
        "--cx",
        "0",
        "--cy",
        "0",
    )
    assert rc == 0
    kept = depth_all <= max_depth
    assert 0 < kept.sum() < kept.size
    cloud = read_ply(tmp_path / "o2" / "a.ply")
    assert len(cloud) == kept.sum()
    mm = cv2.imread(str(tmp_path / "o2" / "a_depth.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(mm > 0, kept)
    np.testing.assert_array_equal(np.load(tmp_path / "o2" / "a_depth.npy") > 0, kept)
    v, u = np.nonzero(kept)  # principal point (0, 0): x = u * z / f
    # ASCII PLY keeps 4 decimals (0.1 mm).
    np.testing.assert_allclose(cloud["x"], u * cloud["z"] / 700, atol=2e-4)
    np.testing.assert_allclose(cloud["y"], v * cloud["z"] / 700, atol=2e-4)


def test_depth_png_saturates_far_depths(tiny, tmp_path):
    model_path, _ = tiny
    image = tmp_path / "far.png"
    write_image(image, seed=3)
    # A huge baseline puts every pixel beyond 65.535 m but within --max-depth.
    rc = run(
        image,
        "--model",
        model_path,
        "--out",
        tmp_path,
        "--disp-format",
        "none",
        "--baseline",
        "100",
        "--max-depth",
        "1e9",
    )
    assert rc == 0
    mm = cv2.imread(str(tmp_path / "far_depth.png"), cv2.IMREAD_UNCHANGED)
    assert (mm == 65535).all()


def test_colorbar_and_no_post_process(tiny, tmp_path):
    model_path, model = tiny
    image = tmp_path / "img.png"
    rgb = write_image(image, seed=4)
    rc = run(
        image,
        "--model",
        model_path,
        "--out",
        tmp_path / "o",
        "--colorbar",
        "--no-post-process",
        "--depth-format",
        "none",
    )
    assert rc == 0
    color = cv2.imread(str(tmp_path / "o" / "img_disp.png"), cv2.IMREAD_UNCHANGED)
    assert color.shape[0] == IMG_H and color.shape[1] > IMG_W
    disp = np.load(tmp_path / "o" / "img_disp.npy")
    np.testing.assert_allclose(disp, expected_disparity(model, rgb, post_process=False), rtol=1e-4, atol=1e-4)


def test_folder_recursive_sorted_with_a_bad_file(tiny, tmp_path, capsys):
    model_path, _ = tiny
    root = tmp_path / "in"
    for i, name in enumerate(["b.png", "a.png", "sub/c.jpg", "sub/deeper/d.png"]):
        write_image(root / name, seed=10 + i)
    (root / "sub" / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really a png")
    (root / "notes.txt").write_text("not an image")

    frames, total = _input_frames(root, report := PredictReport())
    assert total == 5 and report.ignored == [root / "notes.txt"]
    assert [f.stem.as_posix() for f in frames] == ["a", "b", "sub/bad", "sub/c", "sub/deeper/d"]

    out = tmp_path / "out"
    rc = run(root, "--model", model_path, "--out", out, "--batch-size", "2")
    assert rc == 1
    err = capsys.readouterr().err
    bad_lines = [line for line in err.splitlines() if "bad.png" in line]
    assert bad_lines and all(line.startswith("error: ") for line in bad_lines)
    assert str(root / "sub" / "bad.png") in bad_lines[0]
    written = sorted(p.relative_to(out).as_posix() for p in out.rglob("*.png"))
    assert written == [f"{s}_{k}.png" for s in ["a", "b", "sub/c", "sub/deeper/d"] for k in ("depth", "disp")]


def test_same_stem_twice_is_reported(tiny, tmp_path, capsys):
    model_path, _ = tiny
    write_image(tmp_path / "in" / "x.png", seed=5)
    write_image(tmp_path / "in" / "x.jpg", seed=6)
    assert run(tmp_path / "in", "--model", model_path, "--out", tmp_path / "out") == 1
    assert "x.png: same output name as" in capsys.readouterr().err
    assert (tmp_path / "out" / "x_disp.png").exists()


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda d: (d / "empty").mkdir() or d / "empty", "no images"),
        (lambda d: (d / "notes.txt").write_text("x") and d / "notes.txt", "unsupported file type '.txt'"),
        (lambda d: d / "missing.png", "no such file or folder"),
        (lambda d: (d / "cut.png").write_bytes(b"\x89PNG\r\n\x1a\nxx") and d / "cut.png", "truncated PNG"),
        (
            lambda d: (d / "junk.avi").write_bytes(bytes(range(256)) * 8) and d / "junk.avi",
            "cannot open this video",
        ),
    ],
    ids=["empty-folder", "unsupported-extension", "missing", "unreadable-image", "unreadable-video"],
)
def test_bad_input_is_one_clear_line(tiny, tmp_path, capsys, make, message):
    model_path, _ = tiny
    path = make(tmp_path)
    assert run(path, "--model", model_path, "--out", tmp_path / "out") == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {path}") and message in err[0]
    assert not (tmp_path / "out").exists()


def test_bad_model_file(tmp_path, capsys):
    write_image(tmp_path / "a.png", seed=7)
    (tmp_path / "broken.pt").write_bytes(b"garbage")
    for model in ("missing.pt", "broken.pt"):
        assert run(tmp_path / "a.png", "--model", tmp_path / model, "--out", tmp_path / "out") == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(tmp_path / model) in err[0]


def test_video_one_output_per_frame(tiny, tmp_path):
    model_path, _ = tiny
    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (IMG_W, IMG_H))
    if not writer.isOpened():
        pytest.skip("OpenCV has no MJPG video writer here")
    for i in range(3):
        writer.write(cv2.cvtColor(make_image(20 + i), cv2.COLOR_RGB2BGR))
    writer.release()
    if not cv2.VideoCapture(str(video)).isOpened():
        pytest.skip("OpenCV cannot read back the MJPG video")
    assert run(video, "--model", model_path, "--out", tmp_path / "out", "--batch-size", "2") == 0
    names = sorted(p.relative_to(tmp_path / "out").as_posix() for p in (tmp_path / "out").rglob("*_disp.npy"))
    assert names == ["clip/000000_disp.npy", "clip/000001_disp.npy", "clip/000002_disp.npy"]
    assert np.load(tmp_path / "out" / "clip" / "000002_disp.npy").shape == (IMG_H, IMG_W)


def test_python_dash_m(tiny, tmp_path):
    model_path, _ = tiny
    write_image(tmp_path / "a.png", seed=8)
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "msdepth",
            "predict",
            str(tmp_path / "a.png"),
            "--model",
            str(model_path),
            "--out",
            str(tmp_path / "out"),
            "--device",
            "cpu",
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "out" / "a_disp.png").exists() and (tmp_path / "out" / "a_depth.png").exists()


def test_onnx_export_removes_the_temp_a_killed_export_left(tiny, tmp_path):
    # Issue 27, item 12: an export killed mid-write (kill -9) left its temp beside --out for good.
    out = tmp_path / "model.onnx"
    writer = atomic_path(out, suffix=".onnx")  # kept referenced: collected, it would clean up
    killed = writer.__enter__()
    user = tmp_path / ".model.onnx.k1ll3d_9.onnx"  # not the project's temp form
    user.write_text("a user's file")
    main(["export-onnx", "--model", str(tiny[0]), "--out", str(out)])  # 1 where onnx is not installed
    assert not killed.exists() and user.exists()


def test_onnx_export_matches_pytorch(tiny, tmp_path):
    ort = pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    model_path, model = tiny
    out = tmp_path / "model.onnx"
    assert main(["export-onnx", "--model", str(model_path), "--out", str(out)]) == 0
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == ["image"]
    assert [o.name for o in session.get_outputs()] == ["disparity"]
    meta = session.get_modelmeta().custom_metadata_map
    assert meta["msdepth.height"] == str(NET_H) and meta["msdepth.variant"] == "tiny"
    # The export size and another one (batch, height and width are dynamic).
    for shape in [(1, 3, NET_H, NET_W), (2, 3, IMG_H, IMG_W)]:
        x = torch.rand(*shape, generator=torch.Generator().manual_seed(0))
        with torch.no_grad():
            expected = model(x)[0].numpy()
        (got,) = session.run(None, {"image": x.numpy()})
        assert got.shape == expected.shape == (shape[0], 2, shape[2], shape[3])
        np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-5)
