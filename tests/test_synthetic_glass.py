"""The synthetic set's glass model: dielectric reflectance, and no pixel but glass depends on it."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from msdepth import render
from msdepth.render import cars, street
from msdepth.render.scene import GLASS_IOR, fresnel_f0

# Evaluation frame 0 of seed 2017 at 48 x 160 has 131 (left) and 121 (right) glass pixels.
FRAME = (2017, render.EVAL, 0, 48, 160)
# sha256 of that frame's left then right image with glass pixels zeroed, rendered by the previous
# glass model (Schlick F0 drawn from U(0.25, 0.5) for cars, U(0.2, 0.45) for shop windows): the
# index-of-refraction draw replaced the F0 draw one for one, so the random stream and with it every
# non-glass byte is unchanged (docs/glass.md; the retired glass_check study checked whole sets:
# studies/results/glass/README.md).
NON_GLASS_SHA256 = "0ff96e96c51c19137c1924fd266f4eccbf860a935062e9a96c5eb27eaac90c11"


def _non_glass_digest(frame: render.Frame, masks: tuple[np.ndarray, np.ndarray]) -> str:
    digest = hashlib.sha256()
    for image, mask in zip((frame.left, frame.right), masks, strict=True):
        image = image.copy()
        image[mask] = 0
        digest.update(image.tobytes())
    return digest.hexdigest()


def test_f0_of_glass_is_dielectric() -> None:
    assert fresnel_f0(1.5) == pytest.approx(0.04)
    assert fresnel_f0(1.0) == 0.0
    lo, hi = (fresnel_f0(n) for n in GLASS_IOR)
    assert 0.035 < lo < hi < 0.045  # uncoated glass, not the polished-metal 0.2-0.5 of before


def test_non_glass_pixels_keep_the_previous_models_bytes() -> None:
    masks = render.glass_pixels(*FRAME)
    assert masks[0].sum() == 131 and masks[1].sum() == 121
    assert _non_glass_digest(render.render_frame(*FRAME), masks) == NON_GLASS_SHA256


def test_only_glass_pixels_depend_on_the_glass_model(monkeypatch: pytest.MonkeyPatch) -> None:
    """A wildly different index (same number of draws) changes glass pixels and nothing else."""
    before = render.render_frame(*FRAME)
    monkeypatch.setattr(cars, "GLASS_IOR", (2.5, 3.0))
    monkeypatch.setattr(street, "GLASS_IOR", (2.5, 3.0))
    after = render.render_frame(*FRAME)
    masks = render.glass_pixels(*FRAME)
    for a, b, mask in zip((before.left, before.right), (after.left, after.right), masks, strict=True):
        changed = (a != b).any(axis=2)
        assert not (changed & ~mask).any()
        assert changed[mask].mean() > 0.5
    np.testing.assert_array_equal(before.disp, after.disp)
