"""studies/objects.py's tiled inference of a crop-trained network (train.crop_scale > 1)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import load_study

from msdepth.io import write_png


@pytest.fixture(scope="module")
def objects():
    return load_study("objects")


def test_windows_cover_every_pixel_and_end_flush(objects) -> None:
    assert objects.window_starts(128, 64, 32) == [0, 32, 64]
    assert objects.window_starts(384, 192, 96) == [0, 96, 192]
    assert objects.window_starts(100, 64, 32) == [0, 32, 36]
    assert objects.window_starts(64, 64, 32) == [0]


def test_tiles_of_a_pointwise_network_give_back_its_whole_image_answer(objects, tmp_path: Path) -> None:
    """A 'network' whose disparity is each pixel's red channel: every tile agrees with every
    other where they overlap, so the tiled mean is exactly the whole image's answer; a network
    that sees its window (the window's mean) gives the mean of the windows covering each pixel."""
    rng = np.random.default_rng(0)
    path = tmp_path / "image.png"
    write_png(path, rng.integers(0, 256, (40, 96, 3), dtype=np.uint8))
    pointwise = objects.tiled_disparities(lambda b: [b[:, :1]], [path], (40, 96), (16, 32))
    from msdepth.data.pairs import to_tensor

    red = to_tensor(np.asarray(objects.kitti.read_image(path)))[0].numpy()
    assert pointwise.shape == (1, 40, 96)
    np.testing.assert_allclose(pointwise[0], red, rtol=0, atol=1e-6)
    windowed = objects.tiled_disparities(
        lambda b: [b[:, :1].mean(dim=(-2, -1), keepdim=True).expand_as(b[:, :1])], [path], (40, 96), (16, 32)
    )
    tops, lefts = objects.window_starts(40, 16, 8), objects.window_starts(96, 32, 16)
    covering = [
        red[t : t + 16, x : x + 32].mean()
        for t in tops
        for x in lefts
        if t <= 20 < t + 16 and x <= 50 < x + 32
    ]
    assert windowed[0, 20, 50] == pytest.approx(np.mean(covering), abs=1e-6)
    assert torch.is_grad_enabled()
