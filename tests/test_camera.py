"""The camera each rendered view passes through (msdepth.render.sensor): each effect does what its
param says, the ground truth never changes, and ``enabled: false`` gives the ideal views' bytes
(tests/test_synthetic_lidar.py pins those: its digests predate the camera)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from msdepth.config.params import CameraConfig, Params, load_params
from msdepth.errors import ConfigError
from msdepth.render import EVAL, render_frame
from msdepth.render.sensor import record, vignette

# Every effect off: the camera only quantises (and auto-exposes).
PLAIN = CameraConfig(
    blur=0.0,
    vignetting=0.0,
    rectification=0.0,
    gain_mismatch=0.0,
    white_balance=0.0,
    read_noise=0.0,
    shot_noise=0.0,
)


def _flat(level: float, shape: tuple[int, int] = (64, 96)) -> np.ndarray:
    return np.full((*shape, 3), level, np.float32)


def _record(left: np.ndarray, right: np.ndarray | None = None, seed: int = 0, **changes) -> list[np.ndarray]:
    cfg = dataclasses.replace(PLAIN, **changes)
    return record(left, left if right is None else right, cfg, np.random.default_rng(seed))


def test_disabled_camera_is_the_ideal_renderer() -> None:
    ideal = render_frame(2017, EVAL, 3, 48, 160)
    off = render_frame(2017, EVAL, 3, 48, 160, sensor=CameraConfig(enabled=False))
    assert np.array_equal(ideal.left, off.left) and np.array_equal(ideal.right, off.right)


def test_the_camera_changes_the_images_and_nothing_else() -> None:
    ideal = render_frame(2017, EVAL, 5, 48, 160)
    seen = render_frame(2017, EVAL, 5, 48, 160, sensor=CameraConfig())
    assert not np.array_equal(ideal.left, seen.left) and not np.array_equal(ideal.right, seen.right)
    for name in ("disp", "disp_right", "noc", "obj_map", "class_map"):
        assert np.array_equal(getattr(ideal, name), getattr(seen, name)), name
    assert ideal.rois == seen.rois and ideal.focal == seen.focal
    again = render_frame(2017, EVAL, 5, 48, 160, sensor=CameraConfig())
    assert np.array_equal(seen.left, again.left) and np.array_equal(seen.right, again.right)


def test_plain_camera_exposes_to_the_target_and_keeps_the_views_equal() -> None:
    left, right = _record(_flat(0.1), exposure=0.4)
    assert np.array_equal(left, right)
    assert left.mean() == pytest.approx(0.4 * 255, abs=0.6)


def test_gain_mismatch_and_white_balance_make_the_views_differ_in_brightness() -> None:
    gaps = [
        abs(float(a.mean()) - float(b.mean()))
        for a, b in (_record(_flat(0.2), seed=s, gain_mismatch=0.05) for s in range(20))
    ]
    assert 0.5 < float(np.mean(gaps)) < 10.0  # |N(0, 0.05)| of ~110 levels: ~4.4 on average
    left, _ = _record(_flat(0.2), white_balance=0.05)
    channel_means = left.reshape(-1, 3).mean(axis=0)
    assert channel_means.max() - channel_means.min() > 1.0


def test_vignetting_darkens_the_corners_by_its_strength() -> None:
    v = vignette(65, 97, 0.3)
    assert (
        v[32, 48, 0] == pytest.approx(1.0)
        and v[0, 0, 0] == pytest.approx(0.7)
        and v[-1, -1, 0] == pytest.approx(0.7)
    )
    left, _ = _record(_flat(0.2), vignetting=0.3)
    assert left[0, 0, 0] / left[32, 48, 0] == pytest.approx(0.7, abs=0.02)


def test_noise_grows_with_the_signal_and_differs_per_view() -> None:
    dark = _record(_flat(0.1), exposure=0.1, shot_noise=8.0)
    bright = _record(_flat(0.1), exposure=0.8, shot_noise=8.0)
    ratio = float(bright[0].astype(float).std() / dark[0].astype(float).std())
    assert ratio == pytest.approx(np.sqrt(8.0), rel=0.15)  # shot noise: sigma grows as sqrt(signal)
    assert not np.array_equal(bright[0], bright[1])
    read = _record(_flat(0.02), exposure=0.4, read_noise=3.0)[0].astype(float)
    assert read.std() == pytest.approx(3.0, rel=0.1)


def test_blur_spreads_an_edge_and_keeps_its_light() -> None:
    step = _flat(0.1)
    step[:, 48:] = 0.3
    sharp, _ = _record(step, exposure=0.4)
    soft, _ = _record(step, exposure=0.4, blur=1.5)
    assert (np.diff(soft[32, :, 1].astype(int)) != 0).sum() > (
        np.diff(sharp[32, :, 1].astype(int)) != 0
    ).sum()
    assert soft.mean() == pytest.approx(sharp.mean(), abs=0.5)


def test_rectification_moves_the_right_view_vertically_by_at_most_its_bound() -> None:
    bars = _flat(0.1)
    bars[30:, :] = 0.3  # a horizontal edge between rows 29 and 30
    for seed in range(5):
        left, right = _record(bars, seed=seed, exposure=0.4, rectification=2.0)
        assert np.array_equal(left[:, :, 1], _record(bars, seed=seed, exposure=0.4)[0][:, :, 1])
        rows = np.abs(right[:, :, 1].astype(int) - left[:, :, 1].astype(int)).max(axis=1) > 0
        assert rows.any() and np.flatnonzero(rows).min() >= 30 - 3 and np.flatnonzero(rows).max() <= 29 + 3


def test_jpeg_round_trip_only_when_asked() -> None:
    x = np.linspace(0, 6 * np.pi, 96, dtype=np.float32)
    texture = np.broadcast_to((0.15 + 0.1 * np.sin(x))[None, :, None], (64, 96, 3)).copy()
    png, _ = _record(texture, exposure=0.4)
    jpeg, _ = _record(texture, exposure=0.4, jpeg_quality=70)
    assert not np.array_equal(png, jpeg) and np.abs(png.astype(int) - jpeg.astype(int)).mean() < 3


def test_camera_params_are_read_and_range_checked(tmp_path) -> None:
    text = "data:\n  synthetic:\n    camera:\n      enabled: false\n      read_noise: 3.5\n"
    path = tmp_path / "params.yaml"
    path.write_text(text)
    cam = load_params(path).data.synthetic.camera
    assert cam == dataclasses.replace(Params().data.synthetic.camera, enabled=False, read_noise=3.5)
    path.write_text(text.replace("3.5", "-1"))
    with pytest.raises(ConfigError, match="data.synthetic.camera.read_noise"):
        load_params(path)
