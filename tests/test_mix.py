"""The ``mix`` appearance term (Zhao et al. 2017): identities, its pieces, gradients, config, training."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from msdepth.config.checks import has_per_pixel_cost
from msdepth.config.params import LossConfig, params_from_dict
from msdepth.config.variants import configs
from msdepth.config.variants.mix import MixConfig
from msdepth.config.variants.msssim import MSSSIMConfig
from msdepth.config.variants.ssim import SSIMConfig
from msdepth.errors import ConfigError
from msdepth.losses.appearance import build_appearance, terms
from msdepth.losses.appearance.mix import MixAppearance, _gaussian_l1
from msdepth.losses.monodepth import MonodepthLoss
from msdepth.losses.ssim import _reference_ssim_terms, ms_ssim
from msdepth.training.train import TrainOptions, TrainOutputs, load_model, train_variant


def _rand(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed))


def _noisy(x: torch.Tensor, std: float, seed: int = 1) -> torch.Tensor:
    noise = torch.randn(x.shape, generator=torch.Generator().manual_seed(seed))
    return (x + std * noise).clamp(0, 1)


def _mix(**cfg: object) -> MixAppearance:
    return MixAppearance(MixConfig(**cfg), LossConfig())  # type: ignore[arg-type]


def test_mix_is_registered_with_zhaos_defaults() -> None:
    assert terms()["mix"] is MixAppearance and configs()["mix"] is MixConfig
    cfg = params_from_dict({}).appearance["mix"]
    assert cfg == MixConfig() and (cfg.alpha, cfg.sigma, cfg.weights) == (0.84, 0.5, "ones")
    assert cfg.l1_sigma == 4.0  # 0.5 px at the 4th level: 0.5 * 2**3 px of the compared image
    assert MixConfig(levels=5).l1_sigma == 8.0  # Zhao et al.'s σ_G^M for 5 scales
    assert "mix" not in params_from_dict({}).variants  # the default run does not train it


def test_mix_of_identical_images_is_zero() -> None:
    x = _rand(2, 3, 32, 48)
    for value in _mix()([x, x[..., ::2, ::2]], [x, x[..., ::2, ::2]]):
        assert value.item() == pytest.approx(0.0, abs=1e-6)


def test_gaussian_l1_hand_computed() -> None:
    # A constant error c is c wherever the window reaches (the in-image mass is the divisor) ...
    x = _rand(1, 3, 16, 20).double() * 0.5
    assert _gaussian_l1(x, x + 0.25, 4.0).item() == pytest.approx(0.25, abs=1e-12)
    # ... and one pixel's error d far from the border is spread, not changed: d / (H·W) in all.
    y = torch.zeros(1, 1, 64, 64, dtype=torch.float64)
    y[0, 0, 32, 32] = 0.5
    assert _gaussian_l1(torch.zeros_like(y), y, 4.0).item() == pytest.approx(0.5 / 64**2, rel=1e-9)


def test_mix_reduces_to_its_pieces() -> None:
    x = _rand(2, 3, 32, 48).double()
    y = _noisy(x, 0.1).double()
    # alpha = 0: the Gaussian-weighted L1 of the coarsest level's σ.
    (l1,) = _mix(alpha=0.0, levels=3)([x], [y])
    assert l1.item() == pytest.approx(_gaussian_l1(x, y, 0.5 * 2**2).item(), rel=1e-12)
    # alpha = 1, one level: 1 - the mean SSIM map of a 0.5 px Gaussian window, "same" padding.
    (one_level,) = _mix(alpha=1.0, levels=1)([x], [y])
    ssim_map = _reference_ssim_terms(x, y, 5, "gaussian", 0.5, "same")[1]
    assert one_level.item() == pytest.approx(1 - ssim_map.mean().item(), rel=1e-9)
    # alpha = 1: 1 - MS-SSIM with Zhao et al.'s exponents of 1, the product of the levels.
    (msssim,) = _mix(alpha=1.0, levels=3)([x], [y])
    expected = ms_ssim(x, y, 5, 3, [1.0, 1.0, 1.0], "gaussian", 0.5, "same")
    assert msssim.item() == pytest.approx(1 - expected.mean().item(), rel=1e-12)
    # The weights combine the two.
    (mixed,) = _mix(alpha=0.84, levels=3)([x], [y])
    assert mixed.item() == pytest.approx(0.84 * msssim.item() + 0.16 * l1.item(), rel=1e-12)


def test_mix_fast_and_reference_kernels_agree() -> None:
    x = _rand(2, 3, 32, 48).double()
    y = _noisy(x, 0.1).double()
    fast = MixAppearance(MixConfig(), LossConfig())([x], [y])[0]
    reference = MixAppearance(MixConfig(), LossConfig(kernels="reference"))([x], [y])[0]
    assert fast.item() == pytest.approx(reference.item(), abs=1e-10)


@pytest.mark.parametrize(
    "pair",
    [
        lambda: (_rand(2, 3, 32, 64), 1 - _rand(2, 3, 32, 64)),
        lambda: (torch.zeros(2, 3, 32, 64), torch.zeros(2, 3, 32, 64)),
        lambda: (torch.full((2, 3, 32, 64), 0.5), _rand(2, 3, 32, 64)),
    ],
    ids=["anticorrelated", "zeros", "constant_vs_noise"],
)
def test_monodepth_loss_with_mix_has_finite_gradients(pair) -> None:
    left, right = pair()
    left.requires_grad_(True)
    disps = [(0.3 * _rand(2, 2, 32 >> s, 64 >> s, seed=s)).requires_grad_(True) for s in range(4)]
    terms = MonodepthLoss(LossConfig(), _mix())(disps, left, right)
    assert all(torch.isfinite(v) for v in terms.values())
    terms["total"].backward()
    for t in (left, *disps):
        assert t.grad is not None and torch.isfinite(t.grad).all()


def test_monodepth_loss_with_mix_prefers_the_true_disparity() -> None:
    base = torch.nn.functional.avg_pool2d(_rand(2, 3, 32, 72, seed=5), 3, stride=1, padding=1)
    left, right = base[..., :64], base[..., 8:72]
    loss = MonodepthLoss(LossConfig(), _mix())

    def appearance(pixels: float) -> float:
        disps = [torch.full((2, 2, 32 >> s, 64 >> s), pixels / 64) for s in range(4)]
        return loss(disps, left, right)["appearance"].item()

    right_value = appearance(8)
    assert all(right_value < 0.3 * appearance(wrong) for wrong in (0, 3, 16))


@pytest.mark.parametrize(
    ("section", "key"),
    [
        ({"alpha": 1.5}, "mix.alpha"),
        ({"sigma": 0}, "mix.sigma"),
        ({"kernel_size": 4}, "mix.kernel_size"),
        ({"levels": 5}, "mix.levels"),  # 64 x 192: the coarsest training scale has no 5th level
        ({"weights": "learned"}, "mix.weights"),
        ({"sigmaa": 1.0}, "mix.sigmaa"),  # unknown keys are rejected
    ],
)
def test_bad_mix_params_name_the_key(section: dict, key: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(key)):
        params_from_dict({"mix": section, "variants": ["ssim", "mix"]})


def test_the_pipeline_trains_mix(tmp_path, pairs) -> None:
    """A small train_variant run of ``mix``: finite losses, its own section in the fingerprint,
    and the same weights from the same seed."""
    h, w = 32, 64  # the shared ``pairs`` fixture's size (tests/conftest.py)
    raw = {
        "data": {"height": h, "width": w},
        "model": {"width_multiplier": 0.0625},
        "train": {"epochs": 2, "batch_size": 4, "threads": 1, "seeds": [0]},
        "msssim": {"levels": 3},  # 32 x 64: the coarsest training scale (4 x 8 px) has 3 levels
        "mix": {"levels": 3},
        "variants": ["ssim", "mix"],
        "optimum": {"start": "sgbm"},  # mix has no per-pixel cost for the default start, cost
    }
    params = params_from_dict(raw)
    assert isinstance(build_appearance(params, "mix"), MixAppearance)
    weights = []
    for run in ("a", "b"):
        outputs = TrainOutputs(tmp_path / run / "model.pt", tmp_path / run / "ck.pt")
        result = train_variant(params, "mix", pairs, outputs, TrainOptions(progress=False))
        assert result.steps == 4 and all(np.isfinite(v) for v in result.final_losses.values())
        model, meta = load_model(tmp_path / run / "model.pt")
        assert meta["variant"] == "mix"
        weights.append(model.state_dict())
    assert all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])
    # Resumed only by the same mix section: another alpha trains anew.
    other = params_from_dict({**raw, "mix": {"levels": 3, "alpha": 0.5}})
    outputs = TrainOutputs(tmp_path / "a" / "model.pt", tmp_path / "a" / "ck.pt")
    again = train_variant(other, "mix", pairs, outputs, TrainOptions(progress=False))
    assert again.resumed_from_epoch == 0


def test_the_cost_start_refuses_a_variant_without_a_per_pixel_cost() -> None:
    """optimum.start: cost matches on each variant's own cost volume; mix has none (one line)."""
    with pytest.raises(ConfigError) as err:
        params_from_dict({"variants": ["ssim", "mix"]})
    assert str(err.value) == (
        "optimum.start: cost needs each variant's per-pixel cost and ['mix'] have none: "
        "set it to sgbm or constant"
    )
    for start in ("sgbm", "constant"):
        assert (
            params_from_dict({"variants": ["ssim", "mix"], "optimum": {"start": start}}).variants[1] == "mix"
        )
    assert params_from_dict({}).optimum.start == "cost"  # ssim and msssim have one
    assert (SSIMConfig.per_pixel_cost, MSSSIMConfig.per_pixel_cost, MixConfig.per_pixel_cost) == (
        True,
        True,
        False,
    )
    assert not has_per_pixel_cost(object())  # a config that does not say has none
