"""Readers and writers for KITTI's on-disk formats (raw data, KITTI 2015 stereo, split lists).

Every reader raises :class:`~msdepth.errors.DataError` with one message naming the file and the
problem, so a broken download is reported once and clearly. The same functions read the real
KITTI tree and the synthetic one (:mod:`msdepth.render` writes these formats).
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
import pandas as pd

from msdepth.data import imagefile
from msdepth.data.imagefile import MAX_IMAGE_PIXELS
from msdepth.errors import DataError
from msdepth.io import atomic_path, write_png, write_text
from msdepth.readers import read_bounded

# Monodepth's width -> focal table (px) for the four KITTI raw image widths, and its baseline (m).
WIDTH_TO_FOCAL: dict[int, float] = {1242: 721.5377, 1241: 718.856, 1224: 707.0493, 1238: 718.3351}
KITTI_BASELINE = 0.54

ROI_CLASSES = ("car", "windshield", "glass", "sign")
ROI_COLUMNS = ("image", "class", "x0", "y0", "x1", "y1")

PathLike = str | os.PathLike

# What each text or binary reader here reads at most (:func:`msdepth.readers.read_bounded`), far above
# KITTI's own files: a calibration file is ~5 KB (a 600 MB one took 1.5 GB to refuse), a Velodyne
# scan ~2 MB (about 120,000 points; the bound is 2 million), a split list ~3 MB (the bound: a
# million lines of 64 bytes, data.synthetic's most frames), an ROI CSV ~30 bytes a box (the bound:
# eight million boxes, a few on each of data.synthetic's most evaluation frames).
MAX_CALIB_BYTES = 1 << 20
MAX_VELODYNE_BYTES = 32 << 20
MAX_LIST_BYTES = 64 << 20
MAX_ROI_BYTES = 256 << 20


def _decode(
    path: PathLike, what: str, flags: int = cv2.IMREAD_UNCHANGED, max_pixels: int = MAX_IMAGE_PIXELS
) -> np.ndarray:
    """Read and decode an image file, or raise DataError naming it: :func:`imagefile.read_file`
    (the file's size and header checked before its body is read), then :func:`imagefile.decode`.
    ``IMREAD_UNCHANGED`` keeps the depth and channels."""
    path = Path(path)
    if not os.path.lexists(path):
        raise DataError(f"{path}: no such {what} file")
    try:  # a folder, a FIFO, an empty or oversized file: read_file's one line
        return imagefile.decode(imagefile.read_file(path, max_pixels), flags, max_pixels)
    except DataError as exc:
        raise type(exc)(f"{path}: {what}: {exc}") from None
    except OSError as exc:  # unreadable (permissions, an I/O error): still one line naming it
        raise DataError(f"{path}: {what}: cannot read it ({exc.strerror or exc})") from None


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_PALETTE = 3  # IHDR colour type of an indexed-colour PNG
# What a file named .png may really be, by its first bytes: each named in the refusal.
_OTHER_FORMATS = (
    (b"P5", "a PGM"),
    (b"P2", "a PGM"),
    (b"P6", "a PPM"),
    (b"\xff\xd8", "a JPEG"),
    (b"BM", "a BMP"),
)


def _decode_png(path: PathLike, what: str) -> tuple[np.ndarray, int, int]:
    """(pixels, bit depth, colour type) of the PNG ``path`` as :func:`_decode` reads it: a DataError
    naming the file unless its bytes are a PNG (a PGM named ``.png`` decodes as well, and was taken
    for KITTI GT). Below 8 bits OpenCV scales grey samples to 8 bits (a 1-bit 1 reads 255)."""
    path = Path(path)
    if not os.path.lexists(path):
        raise DataError(f"{path}: no such {what} file")
    try:
        data = imagefile.read_file(path, MAX_IMAGE_PIXELS)
    except DataError as exc:
        raise type(exc)(f"{path}: {what}: {exc}") from None
    except OSError as exc:
        raise DataError(f"{path}: {what}: cannot read it ({exc.strerror or exc})") from None
    if not data.startswith(_PNG_SIGNATURE):
        found = next((name for magic, name in _OTHER_FORMATS if data.startswith(magic)), "another format")
        raise DataError(f"{path}: {what}: not a PNG (its bytes are {found}); {what}s are PNG files")
    try:
        img = imagefile.decode(data, cv2.IMREAD_UNCHANGED, MAX_IMAGE_PIXELS)
    except DataError as exc:
        raise type(exc)(f"{path}: {what}: {exc}") from None
    return img, data[24], data[25]  # IHDR: bit depth, colour type (read_file checked IHDR comes first)


def _decode_as(path: PathLike, what: str, dtype: type, channels: int) -> np.ndarray:
    """:func:`_decode_png`, then a DataError unless the pixels are ``dtype`` with ``channels``
    channels (a palette PNG is called one)."""
    img, _, color_type = _decode_png(path, what)
    found = 1 if img.ndim == 2 else img.shape[2]
    if (
        img.dtype != dtype
        or found != channels
        or (channels == 1 and img.ndim != 2)
        or color_type == _PNG_PALETTE
    ):
        bits = 8 * np.dtype(dtype).itemsize
        layout = "single-channel" if channels == 1 else f"{channels}-channel"
        article = "an" if bits == 8 else "a"
        got = (
            "a palette PNG (colours, not values)"
            if color_type == _PNG_PALETTE
            else f"{img.dtype} with {found} channel(s)"
        )
        raise DataError(f"{path}: expected {article} {bits}-bit {layout} {what}, got {got}")
    return img


def read_image(path: PathLike, max_pixels: int = MAX_IMAGE_PIXELS) -> np.ndarray:
    """Read an image as uint8 RGB ``(H, W, 3)``, upright as a viewer shows it.

    As other tools do: a JPEG's EXIF orientation is applied, grey is repeated into three channels,
    an alpha channel is dropped and 16-bit samples are scaled to 8 bits (OpenCV's ``IMREAD_COLOR``).
    A file declaring more than ``max_pixels`` pixels is refused before it is decoded.
    """
    return cv2.cvtColor(_decode(path, "image", cv2.IMREAD_COLOR, max_pixels), cv2.COLOR_BGR2RGB)


def read_disparity(path: PathLike) -> np.ndarray:
    """Read a KITTI disparity PNG (uint16, value / 256) as float32 pixels; 0 marks no measurement."""
    return _decode_as(path, "KITTI disparity map", np.uint16, 1).astype(np.float32) / 256.0


def read_depth(path: PathLike) -> np.ndarray:
    """Read a KITTI depth-benchmark PNG (``proj_depth/groundtruth``: uint16, metres x 256) as float32 metres.

    0 marks no measurement, as in :func:`read_disparity`; the two formats differ only in what the
    value is, so which one a file holds is the index's to say.
    """
    return _decode_as(path, "KITTI depth map", np.uint16, 1).astype(np.float32) / 256.0


def write_disparity(path: PathLike, disp: np.ndarray) -> None:
    """Write a disparity map (pixels, 0 = invalid) as a KITTI uint16 x256 PNG, atomically.

    Positive disparities are stored as at least 1 so that a valid (if tiny) value never turns
    into the "invalid" code 0; values beyond 255.996 px are clipped to 65535.
    """
    disp = np.asarray(disp, dtype=np.float64)
    if disp.ndim != 2:
        raise DataError(f"{path}: a disparity map must be 2-D, got shape {disp.shape}")
    if np.isnan(disp).any() or (disp < 0).any():
        raise DataError(f"{path}: disparity has NaN or negative values (use 0 for invalid pixels)")
    code = np.clip(np.round(disp * 256.0), 0, 65535)
    code[(disp > 0) & (code == 0)] = 1
    write_png(path, code.astype(np.uint16))


def read_obj_map(path: PathLike) -> np.ndarray:
    """Read a KITTI 2015 ``obj_map`` PNG: uint8 instance ids ``(H, W)``, 0 = background."""
    return _decode_as(path, "object map", np.uint8, 1)


# Bits of a class map: the synthetic set's ROI classes, KITTI 2012's reflective surfaces (the pixels
# of its disp_refl_occ, msdepth.data.kitti2012), KITTI 2015's cars (obj_map > 0) and the classes a
# stereo folder's class maps may name (msdepth.data.ground_truth.read_classes: Booster-style
# transparent and specular masks). A pixel may carry several: a windshield pixel is also a car pixel.
CLASS_BITS = {
    "car": 1, "windshield": 2, "glass": 4, "sign": 8, "reflective": 16, "transparent": 32, "specular": 64
}  # fmt: skip


def read_class_map(path: PathLike) -> np.ndarray:
    """Read a class map PNG: uint8 ``(H, W)``, bit :data:`CLASS_BITS` [c] set on class c's pixels."""
    img = _decode_as(path, "class map", np.uint8, 1)
    if (img & ~np.uint8(sum(CLASS_BITS.values()))).any():
        raise DataError(f"{path}: class map has bits outside {CLASS_BITS}")
    return img


def read_label_map(path: PathLike) -> np.ndarray:
    """Read a PNG of integer labels, 8- or 16-bit with one channel (a stereo folder's class map,
    :func:`msdepth.data.ground_truth.read_label_class_map`). Any other format is refused: a JPEG's
    compression changes labels at every edge."""
    img, depth, color_type = _decode_png(path, "class map")
    if color_type == _PNG_PALETTE:
        raise DataError(
            f"{path}: expected an 8- or 16-bit single-channel class map (integer labels), got a palette "
            "PNG (colours, not labels): save the labels as a greyscale PNG"
        )
    if img.ndim != 2 or img.dtype not in (np.uint8, np.uint16):
        found = 1 if img.ndim == 2 else img.shape[2]
        raise DataError(
            f"{path}: expected an 8- or 16-bit single-channel class map (integer labels), "
            f"got {img.dtype} with {found} channel(s)"
        )
    if depth < 8:  # OpenCV scaled the 1-, 2- or 4-bit labels to 8 bits: back to the labels stored
        img = img // np.uint8(255 // (2**depth - 1))
    return img


def read_calib(path: PathLike) -> dict[str, np.ndarray]:
    """Parse a KITTI calibration text file into ``{key: float64 vector}``.

    Reads both the raw-data ``calib_cam_to_cam.txt`` (``P_rect_02``, ``S_rect_02``, ...) and the
    object-benchmark ``calib.txt`` (``P2``, ``P3``, ...). Non-numeric entries such as
    ``calib_time`` are skipped. Matrices stay flat (row-major); reshape as needed. Only a regular
    file of at most :data:`MAX_CALIB_BYTES` is read (:func:`msdepth.readers.read_bounded`).
    """
    path = Path(path)
    calib: dict[str, np.ndarray] = {}
    text = read_bounded(path, "calibration", MAX_CALIB_BYTES).decode("utf-8", errors="replace")
    for line in text.splitlines():
        key, sep, values = line.partition(":")
        if not sep or not key.strip():
            continue
        try:
            vector = np.array([float(v) for v in values.split()], dtype=np.float64)
        except ValueError:
            continue  # e.g. "calib_time: 09-Jan-2012 13:57:47"
        if vector.size:
            calib[key.strip()] = vector
    if not calib:
        raise DataError(f"{path}: no numeric 'key: values' entries (not a KITTI calibration file)")
    return calib


# Physical ranges of a rig's values, for camera files and KITTI calibrations alike: a focal length
# of 1 px to 1e5 px (a 1e5 px wide telephoto), a baseline of 1 mm to 10 m, an image 1 to 1e5 px
# wide. Outside them a value is a typo or a unit error (1.0e-300 put focal 9.6e+304 into the index).
CAMERA_RANGES = {"focal_px": (1.0, 1e5), "width_px": (1.0, 1e5), "baseline_m": (1e-3, 10.0)}


def stereo_from_calib(calib: dict[str, np.ndarray]) -> tuple[float, float]:
    """``(focal_px, baseline_m)`` of the rectified colour pair (camera 2 left, camera 3 right)."""
    for left, right in (("P_rect_02", "P_rect_03"), ("P2", "P3")):
        if left in calib and right in calib:
            if calib[left].size != 12 or calib[right].size != 12:
                raise DataError(
                    f"calibration: {left}/{right} must have 12 values (3x4), "
                    f"got {calib[left].size}/{calib[right].size}"
                )
            p2, p3 = calib[left].reshape(3, 4), calib[right].reshape(3, 4)
            if not (np.isfinite(p2).all() and np.isfinite(p3).all()):
                raise DataError(f"calibration: {left}/{right} contain NaN or infinite values")
            focal = float(p2[0, 0])
            (f_low, f_high), (b_low, b_high) = CAMERA_RANGES["focal_px"], CAMERA_RANGES["baseline_m"]
            if not f_low <= focal <= f_high:
                raise DataError(
                    f"calibration: {left}'s focal length must be {f_low:g} to {f_high:g} px, got {focal:g}"
                )
            baseline = float((p2[0, 3] - p3[0, 3]) / focal)
            # Depth = focal * baseline / disparity: a baseline out of range turns every depth into
            # garbage downstream (camera 3 must sit right of camera 2).
            if not (np.isfinite(baseline) and b_low <= baseline <= b_high):
                raise DataError(
                    f"calibration: {left}/{right} give a baseline of {baseline:g} m, "
                    f"outside {b_low:g} to {b_high:g} m"
                )
            return focal, baseline
    raise DataError(f"calibration: no P_rect_02/P_rect_03 or P2/P3 projections (keys: {sorted(calib)})")


def focal_and_baseline(width: int, calib_path: PathLike | None = None) -> tuple[float, float]:
    """Focal (px) and baseline (m) for a frame of ``width`` pixels, Monodepth's way first.

    A KITTI width uses Monodepth's table and 0.54 m (as the published numbers do); any other width
    (e.g. the synthetic set's) needs its calibration file.
    """
    if width in WIDTH_TO_FOCAL:
        return WIDTH_TO_FOCAL[width], KITTI_BASELINE
    if calib_path is not None and Path(calib_path).is_file():
        try:
            return stereo_from_calib(read_calib(calib_path))
        except DataError as exc:
            raise DataError(f"{calib_path}: {exc}") from None
    raise DataError(
        f"width {width} is not a KITTI image width ({sorted(WIDTH_TO_FOCAL)}) and no calibration file "
        f"was found{f' at {calib_path}' if calib_path is not None else ''}"
    )


# ------------------------------------------------------------------------ LiDAR ground truth


def read_velodyne(path: PathLike) -> np.ndarray:
    """Read a KITTI Velodyne scan (``velodyne_points/data/*.bin``): float32 ``(N, 4)`` x, y, z, reflectance.

    x points forward, y left, z up (metres). A size that is not a whole number of 16-byte points
    means a truncated or foreign file, which would otherwise shift every later point's fields. Only
    a regular file of at most :data:`MAX_VELODYNE_BYTES` is read (:func:`msdepth.readers.read_bounded`).
    """
    data = read_bounded(path, "Velodyne scan", MAX_VELODYNE_BYTES, allow_empty=True)  # a scan of no points
    if len(data) % 16:
        raise DataError(
            f"{path}: Velodyne scan is {len(data)} bytes, not a multiple of 16 (4 float32 per point)"
        )
    return np.frombuffer(data, dtype="<f4").reshape(-1, 4).astype(np.float32)


def write_velodyne(path: PathLike, points: np.ndarray) -> None:
    """Write a scan in KITTI's ``.bin`` format (float32 little-endian x, y, z, reflectance), atomically."""
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 4:
        raise DataError(f"{path}: a Velodyne scan must be (N, 4) x, y, z, reflectance, got {points.shape}")
    with atomic_path(path) as tmp:
        tmp.write_bytes(np.ascontiguousarray(points, dtype="<f4").tobytes())


# S_rect_02 sizes the depth map that a scan is projected into (KITTI's: 1242 x 375); an unbounded
# one made lidar_depth_map attempt 298 GiB.
MAX_CALIB_SIDE = 16384


@dataclass(frozen=True)
class RawCalib:
    """One KITTI raw day's calibration, as the LiDAR projection into camera 2 needs it.

    ``proj`` = ``P_rect_02`` (3x4), ``rect`` = ``R_rect_00`` (3x3, the rectifying rotation all
    cameras share), ``velo_to_cam`` = ``[R|T]`` of ``calib_velo_to_cam.txt`` (4x4) and ``shape``
    = ``S_rect_02`` as (height, width): the size of the rectified camera-2 images.
    """

    proj: np.ndarray
    rect: np.ndarray
    velo_to_cam: np.ndarray
    shape: tuple[int, int]


def _entry(calib: dict[str, np.ndarray], key: str, size: int, path: Path) -> np.ndarray:
    if key not in calib:
        raise DataError(f"{path}: no {key} entry (keys: {sorted(calib)})")
    value = calib[key]
    if value.size != size or not np.isfinite(value).all():
        raise DataError(f"{path}: {key} must be {size} finite numbers, got {value.size}: {value[:12]}")
    return value


def read_raw_calib(day_dir: PathLike) -> RawCalib:
    """Read ``calib_cam_to_cam.txt`` and ``calib_velo_to_cam.txt`` of a raw day folder (``raw/<date>/``)."""
    cam_path = Path(day_dir) / "calib_cam_to_cam.txt"
    velo_path = Path(day_dir) / "calib_velo_to_cam.txt"
    cam, velo = read_calib(cam_path), read_calib(velo_path)
    size = _entry(cam, "S_rect_02", 2, cam_path)
    width, height = (int(round(v)) for v in size)
    if not (0 < width <= MAX_CALIB_SIDE and 0 < height <= MAX_CALIB_SIDE) or not np.allclose(
        size, (width, height)
    ):
        raise DataError(
            f"{cam_path}: S_rect_02 must be a whole width and height from 1 to {MAX_CALIB_SIDE} px, "
            f"got {size}"
        )
    velo_to_cam = np.eye(4)
    velo_to_cam[:3, :3] = _entry(velo, "R", 9, velo_path).reshape(3, 3)
    velo_to_cam[:3, 3] = _entry(velo, "T", 3, velo_path)
    return RawCalib(
        proj=_entry(cam, "P_rect_02", 12, cam_path).reshape(3, 4),
        rect=_entry(cam, "R_rect_00", 9, cam_path).reshape(3, 3),
        velo_to_cam=velo_to_cam,
        shape=(height, width),
    )


def _homogeneous(matrix: np.ndarray, name: str) -> np.ndarray:
    """A 3x3, 3x4 or 4x4 transform as 4x4 (the missing rows and columns of the identity)."""
    matrix = np.asarray(matrix, dtype=np.float64)
    if matrix.shape not in ((3, 3), (3, 4), (4, 4)):
        raise ValueError(f"lidar_depth_map: {name} must be 3x3, 3x4 or 4x4, got {matrix.shape}")
    out = np.eye(4)
    out[: matrix.shape[0], : matrix.shape[1]] = matrix
    return out


def lidar_depth_map(
    points: np.ndarray,
    velo_to_cam: np.ndarray,
    rect: np.ndarray,
    proj: np.ndarray,
    shape: tuple[int, int],
) -> np.ndarray:
    """Sparse depth (m) of a Velodyne scan in the image, the field's raw-LiDAR GT; 0 = no point.

    As Monodepth2's ``generate_depth_map(..., vel_depth=True)`` computes the Eigen split's GT, so
    that numbers are comparable: points with x < 0 (behind the LiDAR) are dropped; the rest are
    projected with ``proj · rect · velo_to_cam``; the pixel is ``round(u) - 1, round(v) - 1``
    (KITTI's MATLAB convention; numpy's round, half to even); points outside ``shape`` (h, w)
    are dropped; where several land on one pixel the nearest wins; the value is the LiDAR's
    forward coordinate x, not the camera's z (a point at exactly x = 0 is kept and, as the
    nearest, blanks its pixel, as there). Unlike Monodepth2 (whose ``sub2ind`` also merges
    the last column of a row with the first of the next), only points on the same pixel compete.

    ``velo_to_cam`` is 3x4 or 4x4, ``rect`` 3x3 or 4x4, ``proj`` 3x4; returns float32 (h, w).
    """
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] < 3:
        raise ValueError(f"lidar_depth_map: points must be (N, 3) or (N, 4), got {points.shape}")
    proj = np.asarray(proj, dtype=np.float64)
    if proj.shape != (3, 4):
        raise ValueError(f"lidar_depth_map: proj must be 3x4, got {proj.shape}")
    height, width = shape
    if not (0 < height <= MAX_CALIB_SIDE and 0 < width <= MAX_CALIB_SIDE):
        raise ValueError(f"lidar_depth_map: shape must be 1..{MAX_CALIB_SIDE} px a side, got {shape}")
    xyz = points[points[:, 0] >= 0, :3].astype(np.float64)
    velo_to_image = proj @ _homogeneous(rect, "rect") @ _homogeneous(velo_to_cam, "velo_to_cam")
    uvz = xyz @ velo_to_image[:, :3].T + velo_to_image[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):  # z = 0: inf/NaN, dropped as outside
        col = np.round(uvz[:, 0] / uvz[:, 2]) - 1
        row = np.round(uvz[:, 1] / uvz[:, 2]) - 1
    inside = (col >= 0) & (row >= 0) & (col < width) & (row < height)
    col, row, depth = col[inside].astype(np.int64), row[inside].astype(np.int64), xyz[inside, 0]
    flat = np.full(height * width, np.inf)
    np.minimum.at(flat, row * width + col, depth)
    flat[np.isinf(flat)] = 0.0
    return flat.reshape(height, width).astype(np.float32)


def velodyne_depth(scan_path: PathLike, calib: RawCalib) -> np.ndarray:
    """The GT depth map (m, 0 = none) of one scan in camera 2, at the calibration's image size."""
    return lidar_depth_map(read_velodyne(scan_path), calib.velo_to_cam, calib.rect, calib.proj, calib.shape)


def list_lines(path: PathLike, missing: str) -> Iterator[tuple[int, str, list[str]]]:
    """``(line number, line, its whitespace-separated fields)`` of every non-blank line of a
    UTF-8 list file; ``missing`` is the error's text when the file does not exist."""
    path = Path(path)
    if not os.path.lexists(path):
        raise DataError(f"{path}: {missing}")
    try:
        text = read_bounded(path, "list", MAX_LIST_BYTES, allow_empty=True).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if fields:
            yield number, line, fields


def read_split(path: PathLike) -> list[tuple[str, str]]:
    """Read a split list: one ``left right`` pair of relative paths per line (blank lines skipped)."""
    pairs: list[tuple[str, str]] = []
    for number, line, fields in list_lines(path, "no such split file"):
        if len(fields) != 2:
            raise DataError(
                f"{path}:{number}: expected 'left right' (two paths), "
                f"got {len(fields)} field(s): {line.strip()!r}"
            )
        pairs.append((fields[0], fields[1]))
    if not pairs:
        raise DataError(f"{path}: split file lists no pairs")
    return pairs


def write_split(path: PathLike, pairs: list[tuple[str, str]]) -> None:
    """Write a split list (``left right`` per line), atomically."""
    for left, right in pairs:
        if not left or not right or any(c.isspace() for c in left + right):
            raise DataError(
                f"{path}: split paths must be non-empty and contain no whitespace: {left!r} {right!r}"
            )
    write_text(path, "".join(f"{left} {right}\n" for left, right in pairs))


def resolve_image(root: Path, rel: str) -> Path | None:
    """The file on disk for a listed image: ``rel`` as given, else as ``.png``, else as ``.jpg``.

    The Monodepth lists name ``.jpg`` (their converted copy); a KITTI download holds ``.png``.
    """
    path = Path(root) / rel
    for candidate in (path, path.with_suffix(".png"), path.with_suffix(".jpg")):
        if candidate.is_file():
            return candidate
    return None


# Far beyond any image, and small enough that float64 and int64 hold every coordinate exactly.
_MAX_COORD = 2**31 - 1


def _box_coordinate(value: object) -> int | None:
    """``value`` as an exact integer pixel coordinate, or None if it is not one."""
    if isinstance(value, (bool, np.bool_)):  # pandas reads a column of "true" as booleans
        return None
    if isinstance(value, (int, np.integer)):  # exact, however large (pandas may give uint64)
        return int(value)
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return int(number) if np.isfinite(number) and number == int(number) else None


def _check_rois(df: pd.DataFrame, path: PathLike) -> pd.DataFrame:
    """Validate an ROI table and return it with normalised dtypes, or raise DataError naming the row."""
    missing = [c for c in ROI_COLUMNS if c not in df.columns]
    if missing:
        raise DataError(f"{path}: missing ROI column(s) {missing}; expected {list(ROI_COLUMNS)}")
    df = df.loc[:, list(ROI_COLUMNS)].copy()
    coords = ["x0", "y0", "x1", "y1"]
    boxes: list[tuple[int, int, int, int]] = []
    # Row numbers in messages are CSV line numbers (header is line 1).
    for i, row in enumerate(df.itertuples(index=False), start=2):
        values = [getattr(row, c) for c in coords]
        numbers = [_box_coordinate(v) for v in values]
        if None in numbers:
            raise DataError(f"{path}: row {i}: box coordinates must be integers, got {values}")
        x0, y0, x1, y1 = numbers
        if min(x0, y0, x1, y1) < 0:
            raise DataError(f"{path}: row {i}: negative box coordinate in {values}")
        if max(x0, y0, x1, y1) > _MAX_COORD:
            raise DataError(f"{path}: row {i}: box coordinate beyond {_MAX_COORD} in {values}")
        if x1 <= x0 or y1 <= y0:
            raise DataError(f"{path}: row {i}: empty box (need x1 > x0 and y1 > y0), got {values}")
        if row[1] not in ROI_CLASSES:
            raise DataError(f"{path}: row {i}: class {row[1]!r} is not one of {list(ROI_CLASSES)}")
        if not isinstance(row[0], str) or not row[0]:
            raise DataError(f"{path}: row {i}: missing image name")
        boxes.append((x0, y0, x1, y1))
    # The checked integers themselves: a float round trip would round or overflow large values.
    df[coords] = np.array(boxes, dtype=np.int64).reshape(-1, 4)
    df["image"] = df["image"].astype(str)
    df["class"] = df["class"].astype(str)
    return df.reset_index(drop=True)


def read_rois(path: PathLike) -> pd.DataFrame:
    """Read ROI boxes: columns image, class, x0, y0, x1, y1 (pixels; x1/y1 exclusive).

    Only a regular, non-empty file of at most :data:`MAX_ROI_BYTES` is read
    (:func:`msdepth.readers.read_bounded`): pandas given the path would block on a FIFO and read any size.
    """
    path = Path(path)
    data = read_bounded(path, "ROI", MAX_ROI_BYTES)
    try:
        # Image names like "000000_10" must stay strings, not become numbers.
        df = pd.read_csv(io.BytesIO(data), dtype={"image": str, "class": str}, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        # pandas ends a tokenizer error with a newline: the message is kept, on one line
        raise DataError(f"{path}: not a readable ROI CSV: {' '.join(str(exc).split())}") from None
    return _check_rois(df, path)


def write_rois(path: PathLike, df: pd.DataFrame) -> None:
    """Validate and write ROI boxes as CSV, atomically."""
    df = _check_rois(df, path)
    with atomic_path(path, suffix=".csv") as tmp:
        df.to_csv(tmp, index=False)


def kitti2015_paths(root: Path, frame: str, gt: str = "disp_noc_0") -> dict[str, Path]:
    """Paths of one KITTI 2015 stereo training frame (e.g. ``"000000_10"``) under ``root``.

    Keys: left, right, disp (the ``gt`` folder), obj_map, calib, and class_map (written by the
    synthetic set only).
    """
    training = Path(root) / "training"
    return {
        "left": training / "image_2" / f"{frame}.png",
        "right": training / "image_3" / f"{frame}.png",
        "disp": training / gt / f"{frame}.png",
        "obj_map": training / "obj_map" / f"{frame}.png",
        "calib": training / "calib_cam_to_cam" / f"{frame.split('_')[0]}.txt",
        "class_map": training / "class_map" / f"{frame}.png",
    }
