"""Run a trained model on images, folders or videos: disparity, metric depth, point clouds.

Every input frame is resized to the network's input size, predicted (with Monodepth's flip
post-processing unless disabled), and its disparity brought back to the frame's own resolution
in pixels. Metric depth is ``focal * baseline / disparity`` with the focal length in pixels at
that resolution (KITTI's by default) and the baseline in metres (KITTI's 0.54 m by default).

Outputs for a frame whose output stem is ``S`` (see :func:`predict` for the stems):

- ``S_disp.png``: colour-mapped disparity (plasma, min .. 95th percentile), optional colour bar;
- ``S_disp.npy``: disparity in pixels at the input resolution (float32, H x W);
- ``S_depth.png``: depth in millimetres (uint16); 0 = invalid or beyond ``max_depth``, depths
  of 65.535 m or more are stored as 65535 (the largest code);
- ``S_depth.npy``: depth in metres (float32); 0 = invalid or beyond ``max_depth``;
- ``S.ply``: coloured point cloud in the camera frame (x right, y down, z forward, metres).

Nothing but these outputs is ever replaced (the shared output policy, :class:`msdepth.outputs.OutputPolicy`):
every file written under the output folder is listed in its ``.msdepth-predict`` file, and a frame
whose output name is taken by a file not listed there (a user's own ``S_disp.png``), by the input,
by the model or by another input's output (``a.png`` and ``a.jpg``) is refused. The output folder
may lie inside an input folder (it is then skipped when the inputs are listed) but may not be it.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
import torch
from tqdm import tqdm

from msdepth.config.network_sizes import sides_problem
from msdepth.data import kitti
from msdepth.data.imagefile import MAX_IMAGE_PIXELS, batches_by_pixels, check_pixel_limit
from msdepth.data.pairs import resize, to_tensor
from msdepth.errors import DataError, MsdepthError, PixelLimitError
from msdepth.evaluation.infer import network_disparity
from msdepth.geometry.depth import disparity_to_depth, pixel_disparity
from msdepth.io import atomic_path, save_npy, write_png
from msdepth.networks.device import resolve_device
from msdepth.networks.model_file import MAX_INPUT_SIDE, DepthNetwork, load_model
from msdepth.outputs import OutputPolicy
from msdepth.render import focal_for_width

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm")
VIDEO_EXTENSIONS = (".avi", ".mp4", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv")
FORMATS = ("png", "npy", "both", "none")
PLY_FORMATS = ("none", "binary", "ascii")
DEPTH_PNG_SCALE = 1000.0  # codes per metre: millimetres, so 65535 = 65.535 m
COLORMAP = cv2.COLORMAP_PLASMA  # Monodepth's figures use plasma
COLOR_PERCENTILE = 95  # the colour scale saturates here, so a few near pixels don't flatten the rest


@dataclass(frozen=True)
class PredictOptions:
    """How to predict and what to write (see the module docstring for the outputs)."""

    height: int | None = None  # network input size; None = the size saved in the model file
    width: int | None = None
    post_process: bool = True
    focal: float | None = None  # px at the input image's resolution; None = KITTI's (_default_focal)
    baseline: float = kitti.KITTI_BASELINE  # m
    cx: float | None = None  # principal point (px); None = the image centre
    cy: float | None = None
    max_depth: float = 80.0  # m; farther pixels are invalid in the depth outputs and point cloud
    disp_format: str = "both"
    depth_format: str = "png"
    ply: str = "none"
    colorbar: bool = False
    batch_size: int = 8
    device: str = "auto"
    progress: bool = True
    max_megapixels: float = MAX_IMAGE_PIXELS / 1e6  # larger images are refused before decoding

    def __post_init__(self) -> None:
        checks = {
            "disp_format": self.disp_format in FORMATS,
            "depth_format": self.depth_format in FORMATS,
            "ply": self.ply in PLY_FORMATS,
            "height": self.height is None or self.height > 0,
            "width": self.width is None or self.width > 0,
            # inf and NaN would give a wrong (or empty) output with exit code 0
            "focal": self.focal is None or _finite_positive(self.focal),
            "baseline": _finite_positive(self.baseline),
            "cx": self.cx is None or bool(np.isfinite(self.cx)),
            "cy": self.cy is None or bool(np.isfinite(self.cy)),
            "max_depth": self.max_depth > 0,  # inf: no limit
            "batch_size": self.batch_size > 0,
            "device": self.device in ("auto", "cpu", "cuda"),
            "max_megapixels": _finite_positive(self.max_megapixels),
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise MsdepthError(
                f"invalid prediction option(s): {', '.join(f'{n}={getattr(self, n)!r}' for n in bad)}"
            )
        if self.disp_format == "none" and self.depth_format == "none" and self.ply == "none":
            raise MsdepthError("nothing to write: disparity, depth and point-cloud outputs are all 'none'")


def _finite_positive(value: float) -> bool:
    return bool(np.isfinite(value)) and value > 0


@dataclass
class PredictReport:
    """What a :func:`predict` run did: frames written, failures (input, message), files ignored."""

    written: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)
    ignored: list[Path] = field(default_factory=list)


@dataclass(frozen=True)
class _Frame:
    source: Path  # the input file
    label: str  # what messages name: the file, or "file frame N" for a video
    stem: Path  # output path without the "_disp.png" etc. suffix, relative to the output folder
    image: np.ndarray | None  # uint8 RGB, or None when it could not be read
    error: str | None = None

    def message(self, error: str) -> str:
        """One line that names the input (DataError messages already start with it)."""
        error = " ".join(error.splitlines())
        return error if error.startswith(str(self.source)) else f"{self.label}: {error}"


def load_trained(path: str | os.PathLike, device: str | torch.device = "cpu") -> tuple[DepthNetwork, dict]:
    """:func:`msdepth.networks.model_file.load_model`, with any failure turned into one MsdepthError naming
    the file."""
    try:
        return load_model(path, device)
    except MsdepthError:
        raise
    except Exception as exc:  # torch.load / state dict errors have long, path-less messages
        first_line = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise MsdepthError(f"{path}: cannot load the model ({first_line})") from None


def _default_focal(width: int) -> float:
    """Monodepth's focal (px) for a KITTI image width, else KITTI's focal scaled to ``width``.

    A KITTI frame resized to another width keeps its field of view, so its focal scales with
    the width (as the synthetic set's camera does).
    """
    return kitti.WIDTH_TO_FOCAL.get(width) or focal_for_width(width)


def _metric_depth(disp_px: np.ndarray, focal: float, baseline: float, max_depth: float) -> np.ndarray:
    """Depth in metres from disparity in pixels; 0 where disparity <= 0 or depth > ``max_depth``."""
    depth = disparity_to_depth(disp_px, focal, baseline)
    depth[~np.isfinite(depth) | (depth > max_depth)] = 0.0
    return depth


def _depth_to_png16(depth: np.ndarray) -> np.ndarray:
    """Depth (m, 0 = invalid) -> uint16 millimetres; saturates at 65535 (65.535 m).

    A valid depth under 0.5 mm is stored as 1 so it never reads as the invalid code 0.
    """
    depth = np.asarray(depth, dtype=np.float64)
    code = np.clip(np.round(depth * DEPTH_PNG_SCALE), 0, 65535)
    code[(depth > 0) & (code == 0)] = 1
    return code.astype(np.uint16)


def _colorize_disparity(disp_px: np.ndarray, colorbar: bool = False) -> np.ndarray:
    """Disparity -> uint8 RGB (plasma, min .. 95th percentile), optionally with a labelled colour bar."""
    return colorize_disparity(disp_px, color_scale(disp_px), colorbar)


def color_scale(disp_px: np.ndarray) -> tuple[float, float]:
    """The colour scale of a disparity map (px): its min and its :data:`COLOR_PERCENTILE` th percentile."""
    return float(disp_px.min()), float(np.percentile(disp_px, COLOR_PERCENTILE))


def colorize_disparity(disp_px: np.ndarray, scale: tuple[float, float], colorbar: bool = False) -> np.ndarray:
    """Disparity (px) -> uint8 RGB (plasma) on the colour scale ``scale`` (vmin, vmax: clipped beyond),
    optionally with a labelled colour bar: one scale for several maps makes them comparable by eye."""
    vmin, vmax = scale
    scale_factor = 255.0 / max(vmax - vmin, 1e-6)
    levels = np.clip((disp_px - vmin) * scale_factor, 0, 255).astype(np.uint8)
    rgb = cv2.cvtColor(cv2.applyColorMap(levels, COLORMAP), cv2.COLOR_BGR2RGB)
    if colorbar:
        rgb = np.concatenate([rgb, _colorbar(disp_px.shape[0], vmin, vmax)], axis=1)
    return rgb


def _colorbar(height: int, vmin: float, vmax: float) -> np.ndarray:
    """A vertical colour bar (top = vmax) with max / mid / min labels in pixels, on black."""
    font, thickness = cv2.FONT_HERSHEY_SIMPLEX, 1
    font_scale = max(0.25, height / 600)
    # Enough decimals to tell the labels apart, however narrow the range.
    decimals = int(np.clip(1 - np.floor(np.log10(max(vmax - vmin, 1e-6))), 1, 6))
    labels = [f"{vmax:.{decimals}f} px", f"{(vmin + vmax) / 2:.{decimals}f}", f"{vmin:.{decimals}f}"]
    sizes = [cv2.getTextSize(t, font, font_scale, thickness)[0] for t in labels]
    pad, bar_w = max(2, height // 60), max(6, height // 25)
    text_w = max(w for w, _ in sizes)
    panel = np.zeros((height, 3 * pad + bar_w + text_w, 3), dtype=np.uint8)
    ramp = np.linspace(255, 0, height).astype(np.uint8)[:, None]
    bar = cv2.cvtColor(cv2.applyColorMap(ramp, COLORMAP), cv2.COLOR_BGR2RGB)
    panel[:, pad : pad + bar_w] = bar
    x = 2 * pad + bar_w
    text_h = sizes[0][1]
    for text, y in zip(labels, (text_h + 1, (height + text_h) // 2, height - 2), strict=True):
        cv2.putText(panel, text, (x, y), font, font_scale, (255, 255, 255), thickness, cv2.LINE_AA)
    return panel


def _point_cloud(
    depth: np.ndarray, rgb: np.ndarray, focal: float, cx: float | None = None, cy: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Back-project valid pixels (depth > 0) with a pinhole camera, fx = fy = ``focal``.

    Returns float32 points (N, 3) in the camera frame (x right, y down, z forward, metres) and
    their uint8 RGB colours (N, 3). The principal point defaults to the image centre.
    """
    h, w = depth.shape
    cx = (w - 1) / 2 if cx is None else cx
    cy = (h - 1) / 2 if cy is None else cy
    v, u = np.nonzero(depth > 0)
    z = depth[v, u].astype(np.float64)
    points = np.stack([(u - cx) * z / focal, (v - cy) * z / focal, z], axis=1).astype(np.float32)
    return points, rgb[v, u].astype(np.uint8)


def _write_ply(path: str | os.PathLike, points: np.ndarray, colors: np.ndarray, binary: bool = True) -> None:
    """Write a coloured point cloud as PLY (binary little-endian or ASCII), atomically."""
    header = (
        "ply\n"
        f"format {'binary_little_endian' if binary else 'ascii'} 1.0\n"
        "comment written by msdepth predict: camera frame, x right, y down, z forward, metres\n"
        f"element vertex {len(points)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        "end_header\n"
    )
    vertices = np.empty(len(points), dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)])
    vertices["xyz"], vertices["rgb"] = points, colors
    with atomic_path(path, suffix=".ply") as tmp, open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        if binary:
            f.write(vertices.tobytes())
        else:
            np.savetxt(f, np.column_stack([points, colors]), fmt="%.4f %.4f %.4f %d %d %d")


def output_paths(stem: Path, options: PredictOptions) -> dict[str, Path]:
    """The files :func:`save_outputs` writes for ``stem``, by kind (``disp_png``, ..., ``ply``)."""
    wanted = {
        "disp_png": (options.disp_format in ("png", "both"), "_disp.png"),
        "disp_npy": (options.disp_format in ("npy", "both"), "_disp.npy"),
        "depth_png": (options.depth_format in ("png", "both"), "_depth.png"),
        "depth_npy": (options.depth_format in ("npy", "both"), "_depth.npy"),
        "ply": (options.ply != "none", ".ply"),
    }
    return {kind: Path(f"{stem}{suffix}") for kind, (on, suffix) in wanted.items() if on}


def save_outputs(stem: Path, rgb: np.ndarray, disp_fraction: np.ndarray, options: PredictOptions) -> None:
    """Write the requested outputs of one frame (:func:`output_paths`); MsdepthError, writing
    nothing, if the network's output is not finite (a damaged model)."""
    if not np.isfinite(disp_fraction).all():
        raise MsdepthError(
            "the model's output has NaN or infinite values (a damaged model file?); nothing written"
        )
    paths = output_paths(stem, options)
    h, w = rgb.shape[:2]
    disp = pixel_disparity(disp_fraction, h, w)
    if "disp_png" in paths:
        write_png(paths["disp_png"], _colorize_disparity(disp, options.colorbar))
    if "disp_npy" in paths:
        save_npy(paths["disp_npy"], disp)
    if options.depth_format == "none" and options.ply == "none":
        return
    focal = options.focal or _default_focal(w)
    depth = _metric_depth(disp, focal, options.baseline, options.max_depth)
    if "depth_png" in paths:
        write_png(paths["depth_png"], _depth_to_png16(depth))
    if "depth_npy" in paths:
        save_npy(paths["depth_npy"], depth)
    if "ply" in paths:
        points, colors = _point_cloud(depth, rgb, focal, options.cx, options.cy)
        _write_ply(paths["ply"], points, colors, binary=options.ply == "binary")


def _read(path: Path, stem: Path, max_pixels: int) -> _Frame:
    try:
        return _Frame(path, str(path), stem, kitti.read_image(path, max_pixels))
    except PixelLimitError as exc:
        return _Frame(path, str(path), stem, None, f"{exc} (raise it with --max-megapixels)")
    except DataError as exc:
        return _Frame(path, str(path), stem, None, str(exc))


def _inside(path: Path, folder: Path) -> bool:
    return path.resolve().is_relative_to(folder.resolve())


def _folder_frames(
    root: Path, report: PredictReport, skip: Path | None, max_pixels: int
) -> tuple[Iterator[_Frame], int]:
    files = sorted(
        (p for p in root.rglob("*") if p.is_file() and not (skip and _inside(p, skip))),
        key=lambda p: p.relative_to(root).as_posix(),
    )
    images = [p for p in files if p.suffix.lower() in IMAGE_EXTENSIONS]
    report.ignored.extend(p for p in files if p.suffix.lower() not in IMAGE_EXTENSIONS)
    if not images:
        raise DataError(f"{root}: no images ({', '.join(IMAGE_EXTENSIONS)}) in this folder or below")

    def frames() -> Iterator[_Frame]:
        # a.png and a.jpg share their outputs: the output policy refuses the second's
        for path in images:
            yield _read(path, path.relative_to(root).with_suffix(""), max_pixels)

    return frames(), len(images)


def _video_frames(path: Path, max_pixels: int) -> tuple[Iterator[_Frame], int]:
    capture = cv2.VideoCapture(str(path))
    opened = capture.isOpened()
    total = max(int(capture.get(cv2.CAP_PROP_FRAME_COUNT)), 0) if opened else 0
    size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    capture.release()  # reopened when iterated, so nothing stays open if the model then fails to load
    if not opened:
        raise DataError(f"{path}: OpenCV cannot open this video (corrupt, or a codec it lacks)")
    _check_video_size(path, *size, max_pixels)  # before any frame is decoded

    def frames() -> Iterator[_Frame]:
        capture = cv2.VideoCapture(str(path))
        index = 0
        try:
            while True:
                ok, bgr = capture.read()
                if not ok:
                    break
                label = f"{path} frame {index}"
                if bgr.shape[:2] != size[::-1]:  # a stream that changes size midway: not trusted
                    yield _Frame(
                        path, label, Path(path.stem) / f"{index:06d}", None, _size_changed(size, bgr)
                    )
                    break
                rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
                yield _Frame(path, label, Path(path.stem) / f"{index:06d}", rgb)
                index += 1
        finally:
            capture.release()
        if index == 0:
            yield _Frame(
                path, str(path), Path(path.stem), None, f"{path}: no frame could be decoded from this video"
            )

    return frames(), total


def _check_video_size(path: Path, width: int, height: int, max_pixels: int) -> None:
    """The image reader's pixel limit (:func:`check_pixel_limit`) on the frame size a video's
    container declares, with the file named and predict's option (PixelLimitError) added."""
    try:
        check_pixel_limit(width, height, max_pixels, "the video")
    except PixelLimitError as exc:
        raise PixelLimitError(f"{path}: {exc} (raise it with --max-megapixels)") from None
    except DataError as exc:
        raise DataError(f"{path}: {exc}; not decoded") from None


def _size_changed(size: tuple[int, int], bgr: np.ndarray) -> str:
    return (
        f"the frame is {bgr.shape[1]} x {bgr.shape[0]} px, not the {size[0]} x {size[1]} px the video "
        "declares; the rest of the video is skipped"
    )


def _input_frames(
    path: str | os.PathLike,
    report: PredictReport,
    skip: Path | None = None,
    max_pixels: int = MAX_IMAGE_PIXELS,
) -> tuple[Iterator[_Frame], int]:
    """The frames of an image, a folder of images (recursive, sorted) or a video, and their count.

    Output stems: an image ``x.png`` -> ``x``; a folder's ``sub/x.png`` -> ``sub/x`` (sub-folders
    mirrored); a video ``clip.mp4`` -> ``clip/000000``, ``clip/000001``, ... The count is the
    video's own frame count, which may be approximate (0 if unknown). Files under ``skip`` (the
    output folder) are not listed; images over ``max_pixels`` are refused before decoding.
    """
    path = Path(path)
    if path.is_dir():
        return _folder_frames(path, report, skip, max_pixels)
    if not path.exists():
        raise DataError(f"{path}: no such file or folder")
    if not path.is_file():  # a FIFO given as a video blocked OpenCV's open forever
        raise DataError(
            f"{path}: not a regular file (a FIFO, a device or a socket); give an image, folder or video"
        )
    suffix = path.suffix.lower()
    if suffix in IMAGE_EXTENSIONS:  # read now: an unreadable single image is a plain DataError
        frame = _read(path, Path(path.stem), max_pixels)
        if frame.error:
            raise DataError(frame.error)
        return iter([frame]), 1
    if suffix in VIDEO_EXTENSIONS:
        return _video_frames(path, max_pixels)
    raise DataError(
        f"{path}: unsupported file type {suffix or '(no extension)'!r}; "
        f"images: {' '.join(IMAGE_EXTENSIONS)}; videos: {' '.join(VIDEO_EXTENSIONS)}"
    )


def _network_batch(
    model: DepthNetwork,
    images: list[np.ndarray],
    size: tuple[int, int],
    device: torch.device,
    post_process: bool,
) -> list[np.ndarray | None]:
    """:func:`network_disparity` of the images resized to ``size`` (h, w); all None if memory runs
    out, so those frames fail and the next batch is still tried."""
    try:
        tensor = torch.stack([to_tensor(resize(image, *size)) for image in images]).to(device)
        return list(network_disparity(model, tensor, post_process))
    except (MemoryError, torch.OutOfMemoryError):
        return [None] * len(images)
    except RuntimeError as exc:  # torch's CPU allocator raises a plain RuntimeError
        if "can't allocate memory" not in str(exc):
            raise
        return [None] * len(images)


def _check_network_size(model_path: str | os.PathLike, meta: dict, height: int, width: int) -> None:
    """One MsdepthError naming the model when its network cannot run at ``height`` x ``width``."""
    architecture = meta.get("architecture", "vgg")  # files from before the option hold a VGG network
    if max(height, width) > MAX_INPUT_SIDE:  # what a model file may declare, and so what it may run at
        raise MsdepthError(
            f"{model_path}: the network input {height} x {width} is over {MAX_INPUT_SIDE} px a side "
            "(--height, --width)"
        )
    rule = sides_problem(architecture, (height, width))
    if rule is not None:
        raise MsdepthError(
            f"{model_path}: a {architecture} model runs at sides that are {rule}, "
            f"got {height} x {width} (--height, --width)"
        )


def predict(
    input_path: str | os.PathLike,
    model_path: str | os.PathLike,
    out_dir: str | os.PathLike,
    options: PredictOptions = PredictOptions(),
) -> PredictReport:
    """Predict every frame of ``input_path`` and write its outputs under ``out_dir``.

    A frame that cannot be read or written is reported (one line on stderr, naming the file)
    and skipped; the rest are still processed. Bad input as a whole (missing path, unsupported
    extension, folder without images, model that does not load) raises MsdepthError.
    """
    report = PredictReport()
    input_path, out_dir = Path(input_path), Path(out_dir)
    # an output folder inside the input folder is skipped when the inputs are listed
    single = () if input_path.is_dir() else (input_path,)
    policy = OutputPolicy(out_dir, "predict", (model_path, *single), (input_path,))
    max_pixels = int(options.max_megapixels * 1e6)
    # bad input fails before the model loads
    frames, total = _input_frames(input_path, report, out_dir if input_path.is_dir() else None, max_pixels)
    device = resolve_device(options.device)
    model, meta = load_trained(model_path, device)
    height, width = options.height or int(meta["height"]), options.width or int(meta["width"])
    _check_network_size(model_path, meta, height, width)
    policy.prepare()

    def fail(frame: _Frame, error: str) -> None:
        message = frame.message(error)
        report.failed.append((frame.label, message))
        tqdm.write(f"error: {message}", file=sys.stderr)

    def run(batch: list[_Frame]) -> None:
        disps = _network_batch(model, [f.image for f in batch], (height, width), device, options.post_process)
        for frame, disp in zip(batch, disps, strict=True):
            try:
                if disp is None:
                    raise MsdepthError(f"out of memory while predicting it in a batch of {len(batch)}")
                policy.claim(list(output_paths(out_dir / frame.stem, options).values()), frame.source)
                save_outputs(out_dir / frame.stem, frame.image, disp, options)
                report.written += 1
            except (MsdepthError, OSError) as exc:
                fail(frame, str(exc))
            except MemoryError:  # e.g. a point cloud of a huge frame; the next frame may fit
                fail(frame, "out of memory while writing its outputs")
            bar.update(1)

    with tqdm(total=total or None, desc="predict", unit="frame", disable=not options.progress) as bar:

        def readable() -> Iterator[_Frame]:
            for frame in frames:
                if frame.image is None:
                    fail(frame, frame.error or "unreadable")
                    bar.update(1)
                else:
                    yield frame

        # planned by memory: a batch closes at options.batch_size frames or BATCH_PIXEL_BUDGET pixels
        for batch in batches_by_pixels(readable(), _pixels, options.batch_size):
            run(batch)
    return report


def _pixels(frame: _Frame) -> int:
    return 0 if frame.image is None else frame.image.shape[0] * frame.image.shape[1]
