"""Post-processing, the network's shapes and size, and config validation."""

import re

import numpy as np
import pytest
import torch

from msdepth.config.params import ConfigError, Params, load_params, params_from_dict
from msdepth.evaluation.infer import post_process_disparity
from msdepth.networks.vgg import MonodepthVGG


def monodepth_post_process(disp: np.ndarray) -> np.ndarray:
    """Monodepth's own function (utils: post_process_disparity), input (2, h, w)."""
    _, h, w = disp.shape
    l_disp = disp[0, :, :]
    r_disp = np.fliplr(disp[1, :, :])
    m_disp = 0.5 * (l_disp + r_disp)
    l, _ = np.meshgrid(np.linspace(0, 1, w), np.linspace(0, 1, h))  # noqa: E741 - Monodepth's name
    l_mask = 1.0 - np.clip(20 * (l - 0.05), 0, 1)
    r_mask = np.fliplr(l_mask)
    return r_mask * l_disp + l_mask * r_disp + (1.0 - l_mask - r_mask) * m_disp


def test_post_process_matches_monodepth():
    rng = np.random.default_rng(1)
    d, d_f = rng.random((2, 16, 64), dtype=np.float32)
    ours = post_process_disparity(d[None], d_f[None])[0]
    np.testing.assert_allclose(ours, monodepth_post_process(np.stack([d, d_f])), atol=1e-6)


def test_post_process_edges_and_symmetric_input():
    w = 100
    d = np.tile(np.linspace(0.0, 1.0, w, dtype=np.float32), (4, 1))
    d_f = np.zeros_like(d)  # flips back to zeros
    out = post_process_disparity(d, d_f)
    assert out[0, 0] == 0.0  # leftmost column from the flipped prediction only
    assert out[0, -1] == pytest.approx(1.0)  # rightmost from the plain prediction only
    assert out[0, w // 2] == pytest.approx(0.5 * d[0, w // 2], rel=1e-5)  # middle: the mean
    # A prediction that is mirror-consistent is left unchanged.
    sym = np.random.default_rng(0).random((3, 20, 40)).astype(np.float32)
    np.testing.assert_allclose(post_process_disparity(sym, np.flip(sym, -1)), sym, atol=1e-6)


def test_full_width_parameter_count():
    # The dissertation's / Monodepth's VGG model: ~31 M parameters.
    assert sum(p.numel() for p in MonodepthVGG(1.0).parameters()) == 31_600_072


@pytest.mark.parametrize("size", [(64, 192), (32, 96), (256, 512)])
def test_model_outputs_four_scales_of_two_disparities(size):
    h, w = size
    model = MonodepthVGG(0.125, init_disparity=0.04)
    with torch.no_grad():
        disps = model(torch.rand(2, 3, h, w))
    assert [tuple(d.shape) for d in disps] == [(2, 2, h >> s, w >> s) for s in range(4)]
    for d in disps:
        assert float(d.min()) > 0 and float(d.max()) < 0.3
        assert float(d.mean()) == pytest.approx(0.04, abs=0.01)  # heads start at init_disparity


def test_params_yaml_loads():
    p = load_params("params.yaml")
    assert isinstance(p, Params)
    assert set(p.variants) >= {"ssim", "msssim"}


@pytest.mark.parametrize(
    "patch, key",
    [
        ({"msssim": {"kernel_size": 4}}, "msssim.kernel_size"),
        ({"msssim": {"kernel_size": 999}}, "msssim.kernel_size"),
        ({"msssim": {"levels": 9}}, "msssim.levels"),
        ({"train": {"learning_rate": -1.0}}, "train.learning_rate"),
        ({"train": {"epochs": "ten"}}, "train.epochs"),
        ({"variants": ["ssim", "l2"]}, r"variants[1]"),
        ({"variants": ["ssim", "ssim"]}, "variants"),
        ({"variants": []}, "variants"),
        ({"train": {"seeds": [0, 0]}}, "train.seeds"),
        ({"train": {"seeds": [-1]}}, "train.seeds"),
        ({"train": {"seeds": 3}}, "train.seeds"),
        ({"msssim": {"weights": "random"}}, "msssim.weights"),
        ({"data": {"height": 70}}, "data.height"),
        ({"data": {"source": "nyu"}}, "data.source"),
        ({"loss": {"alpah": 0.8}}, "loss.alpah"),
        ({"ssim": {"kernel_size": 9}}, "ssim.kernel_size"),  # > the 8 px coarsest scale of 64 x 192
        ({"msssim": {"levels": 5}, "data": {"height": 64, "width": 64}}, "msssim.levels"),
        ({"train": {"batch_size": 0}}, "train.batch_size"),
        ({"train": {"amp": "fp16"}}, "train.amp"),
        ({"train": {"sync_every": -1}}, "train.sync_every"),
        ({"data": {"synthetic": {"gt_max_depth": -1}}}, "data.synthetic.gt_max_depth"),
        ({"eval": {"caps": [80, 0.0001]}}, "eval.caps"),
        ({"train": {"seed": 1}}, "train.seed"),  # renamed to train.seeds: an old params.yaml fails loudly
        ({"compare": {"reference": "l1"}}, "compare.reference"),
        ({"compare": {"confidence": 95}}, "compare.confidence"),
    ],
)
def test_bad_params_name_the_key(patch, key):
    with pytest.raises(ConfigError, match=re.escape(key)):
        params_from_dict(patch)


@pytest.mark.parametrize(
    "norm, heads", [("group", "independent"), ("none", "residual"), ("group", "residual")]
)
def test_network_options_keep_shapes_and_start_at_the_initial_disparity(norm, heads):
    model = MonodepthVGG(0.125, init_disparity=0.04, norm=norm, heads=heads)
    with torch.no_grad():
        disps = model(torch.rand(2, 3, 64, 192))
    assert [tuple(d.shape) for d in disps] == [(2, 2, 64 >> s, 192 >> s) for s in range(4)]
    for d in disps:  # residual heads add ~0 to the coarsest level, which starts at init_disparity
        assert float(d.mean()) == pytest.approx(0.04, abs=0.01)
    norms = [m for m in model.modules() if isinstance(m, torch.nn.GroupNorm)]
    assert len(norms) == (0 if norm == "none" else 7 * 2 + 7 * 2)  # every conv but the heads


def test_the_dissertation_network_is_still_the_default():
    plain = MonodepthVGG(1.0)
    assert plain.norm == "none" and not plain.residual
    assert not any(isinstance(m, torch.nn.GroupNorm) for m in plain.modules())
    with pytest.raises(ValueError, match="heads"):
        MonodepthVGG(0.125, heads="cascade")
    with pytest.raises(ValueError, match="norm"):
        MonodepthVGG(0.125, norm="batch")


def test_residual_heads_refine_the_upsampled_coarser_disparity():
    torch.manual_seed(0)
    model = MonodepthVGG(0.125, init_disparity=0.04, heads="residual")
    for head in model.heads[
        1:
    ]:  # finer heads predict no correction: each scale is the coarser one, upsampled
        torch.nn.init.zeros_(head.weight)
        torch.nn.init.zeros_(head.bias)
    torch.nn.init.normal_(model.heads[0].weight, std=0.5)  # a coarsest map that varies
    with torch.no_grad():
        disps = model(torch.rand(1, 3, 64, 192))
    logit = lambda d: torch.logit(d / 0.3)  # noqa: E731
    for fine, coarse in zip(disps[:-1], disps[1:], strict=True):
        up = torch.nn.functional.interpolate(
            logit(coarse), size=fine.shape[-2:], mode="bilinear", align_corners=False
        )
        torch.testing.assert_close(logit(fine), up, atol=1e-4, rtol=1e-4)
    assert float(disps[-1].std()) > 1e-3


def test_group_norm_network_treats_each_image_on_its_own():
    # GroupNorm normalises per image: a batch gives each image what it would get alone, so
    # batch size and data-parallel splits do not change the model.
    torch.manual_seed(0)
    model = MonodepthVGG(0.125, init_disparity=0.04, norm="group", heads="residual").eval()
    x = torch.rand(3, 3, 64, 192)
    with torch.no_grad():
        together = model(x)[0]
        alone = torch.cat([model(x[i : i + 1])[0] for i in range(3)])
    torch.testing.assert_close(together, alone, atol=1e-6, rtol=1e-5)


def test_saved_model_rebuilds_its_architecture(tmp_path):
    from msdepth.losses.objective import build_loss
    from msdepth.training.train import build_model, load_model, save_model

    raw = {"model": {"width_multiplier": 0.125, "norm": "group", "heads": "residual"}}
    params = params_from_dict(raw)
    torch.manual_seed(0)
    model = build_model(params).eval()
    save_model(tmp_path / "m.pt", model, build_loss(params, "ssim"), params, "ssim", 0)
    loaded, meta = load_model(tmp_path / "m.pt")
    assert (loaded.norm, loaded.residual, meta["norm"], meta["heads"]) == ("group", True, "group", "residual")
    x = torch.rand(1, 3, 64, 192)
    with torch.no_grad():
        torch.testing.assert_close(loaded(x)[0], model(x)[0])
    # A file written before these options holds the dissertation's network.
    state = torch.load(tmp_path / "m.pt", weights_only=True)
    plain = MonodepthVGG(0.125)
    state.update(model=plain.state_dict())
    del state["norm"], state["heads"]
    torch.save(state, tmp_path / "old.pt")
    old, _ = load_model(tmp_path / "old.pt")
    assert old.norm == "none" and not old.residual
