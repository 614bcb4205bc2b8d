"""`model.architecture: resnet18` (Monodepth2's depth network) and `model.pretrained`: the network
behind the VGG network's interface, its checks, training in every mode, its model files."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from torch import nn

from msdepth import render
from msdepth.__main__ import main
from msdepth.config.params import params_from_dict
from msdepth.data import sequences
from msdepth.data.layout import MONO_SPLIT
from msdepth.errors import ConfigError, MsdepthError
from msdepth.networks.model_file import depth_network, save_model
from msdepth.networks.resnet import ResNetEncoder
from msdepth.networks.resnet_depth import DepthDecoder, ResNetMonodepth
from msdepth.networks.serialization import load_weights_file
from msdepth.networks.vgg import MonodepthVGG
from msdepth.training.train import (
    TrainOptions,
    TrainOutputs,
    _load_pretrained_encoders,
    build_model,
    build_pose_net,
    load_model,
    train_variant,
)

H, W = 64, 192  # ResNet-18 needs sides that are multiples of 32, at least 64
RENDER = {"seed": 5, "drives": 1, "train_pairs": 6, "eval_frames": 1, "height": H, "width": W}


def _params(model: dict | None = None, **train):
    return params_from_dict(
        {
            "data": {"height": H, "width": W, "synthetic": {**RENDER, "sequence_length": 5}},
            "model": {"architecture": "resnet18", "width_multiplier": 0.0625, **(model or {})},
            "train": {"epochs": 1, "batch_size": 2, "threads": 1, **train},
            "msssim": {"levels": 3},
        }
    )


def _torchvision_file(tmp_path: Path, seed: int) -> tuple[Path, dict[str, torch.Tensor]]:
    """A torchvision resnet18 state dict as a user downloads it (with its fc), from a random encoder."""
    torch.manual_seed(seed)
    state = dict(ResNetEncoder().state_dict())
    state["fc.weight"], state["fc.bias"] = torch.zeros(1000, 512), torch.zeros(1000)
    path = tmp_path / "resnet18.pth"
    torch.save(state, path)
    return path, state


def test_two_channels_of_monodepth2s_network_times_0_3() -> None:
    """Channel 0 of ResNetMonodepth is 0.3 x Monodepth2's one-channel network (its ResnetEncoder and
    DepthDecoder, tested against its transcription in test_pose.py) with the same weights."""
    torch.manual_seed(0)
    ours, decoder = ResNetMonodepth().eval(), DepthDecoder().eval()
    decoder.load_state_dict(
        {k: v[:1] if k.startswith("dispconvs") else v for k, v in ours.decoder.state_dict().items()}
    )
    single = nn.Sequential(ours.encoder, decoder)
    x = torch.rand(2, 3, H, W)
    with torch.no_grad():
        for scale, (a, b) in enumerate(zip(ours(x), single(x), strict=True)):
            assert a.shape == (2, 2, H >> scale, W >> scale) and b.shape == (2, 1, H >> scale, W >> scale)
            torch.testing.assert_close(a[:, :1], 0.3 * b, rtol=0, atol=1e-6)
            assert float(a.min()) > 0 and float(a.max()) < 0.3


def test_init_disparity_starts_every_output_there_and_none_keeps_monodepth2s() -> None:
    """model.init_disparity starts the ResNet network's outputs as the VGG heads' (every scale,
    both channels, near 0.04 of the width); without it Monodepth2's sigmoid(0) start, 0.15."""
    torch.manual_seed(0)
    x = torch.rand(2, 3, H, W)
    with torch.no_grad():
        started = ResNetMonodepth(0.25, init_disparity=0.04).eval()(x)
        plain = ResNetMonodepth(0.25).eval()(x)
    for scale in started:
        torch.testing.assert_close(scale, torch.full_like(scale, 0.04), rtol=0, atol=2e-3)
    assert all(0.1 < float(p.mean()) < 0.25 for p in plain)
    assert isinstance(depth_network("resnet18", 0.25, init_disparity=0.04), ResNetMonodepth)


def test_width_multiplier_scales_encoder_and_decoder() -> None:
    full = sum(p.numel() for p in ResNetMonodepth().parameters())
    quarter = sum(p.numel() for p in ResNetMonodepth(0.25).parameters())
    # Monodepth2's depth network (ResNet-18 without fc + DepthDecoder): 14,329,236 parameters; a
    # second output channel adds one 3x3 filter and bias per scale: (16 + 32 + 64 + 128) * 9 + 4.
    assert full == 14_329_236 + (16 + 32 + 64 + 128) * 9 + 4
    assert sum(p.numel() for m in (ResNetEncoder(), DepthDecoder()) for p in m.parameters()) == 14_329_236
    assert quarter < full / 10
    with pytest.raises(ValueError, match="multiples of 32"):
        ResNetMonodepth(0.25)(torch.rand(1, 3, 48, W))


def test_depth_network_builds_the_architecture_named() -> None:
    assert isinstance(depth_network("vgg", 0.0625), MonodepthVGG)
    assert isinstance(depth_network("resnet18", 0.0625), ResNetMonodepth)
    assert isinstance(build_model(_params()), ResNetMonodepth)
    assert isinstance(build_model(_params({"architecture": "vgg"})), MonodepthVGG)


@pytest.mark.parametrize(
    ("model", "train", "data", "message"),
    [
        ({}, {}, {"height": 48}, "data.height: model.architecture resnet18 needs a multiple of 32"),
        ({"architecture": "vgg", "pretrained": "x.pth"}, {}, {}, "model.pretrained: the run has no ResNet"),
        ({"pretrained": "x.pth"}, {}, {}, "model.width_multiplier: must be 1.0 with model.pretrained"),
        (
            {"width_multiplier": 1.0, "pretrained": "x.pth"},
            {"mode": "mono"},
            {},
            "model.pose_width_multiplier: must be 1.0 with model.pretrained",
        ),
        ({"width_multiplier": 1.0, "pretrained": "absent.pth"}, {}, {}, "model.pretrained: no such file"),
        ({"architecture": "resnet50"}, {}, {}, "model.architecture"),
    ],
)
def test_bad_settings_are_one_config_error(model: dict, train: dict, data: dict, message: str) -> None:
    raw = {
        "data": {"height": H, "width": W, **data},
        "model": {"architecture": "resnet18", **model},
        "train": train,
    }
    with pytest.raises(ConfigError, match=message):
        params_from_dict(raw)


def test_pretrained_loads_into_every_resnet_encoder_of_the_run(tmp_path: Path) -> None:
    path, state = _torchvision_file(tmp_path, seed=7)
    raw = {"width_multiplier": 1.0, "pose_width_multiplier": 1.0, "pretrained": str(path)}
    params = _params(raw, mode="mono")
    model, pose_net = build_model(params), build_pose_net(params)
    _load_pretrained_encoders(params.model.pretrained, model, pose_net)
    depth = model.encoder.state_dict()
    assert all(torch.equal(depth[k], state[k]) for k in depth)
    pose = pose_net.encoder.state_dict()
    assert torch.equal(pose["conv1.weight"], torch.cat([state["conv1.weight"]] * 2, dim=1) / 2)
    assert torch.equal(pose["layer4.1.conv2.weight"], state["layer4.1.conv2.weight"])
    # Building the networks never reads the file (only a fresh start loads it, test_pretrained.py):
    # initialised anew, not the file's weights.
    torch.manual_seed(8)
    scratch = build_model(params).encoder.state_dict()
    assert not torch.equal(scratch["layer1.0.conv1.weight"], state["layer1.0.conv1.weight"])


def test_stereo_training_writes_a_resnet18_model_file_that_loads(pairs, tmp_path: Path) -> None:
    params = _params()
    train_variant(
        params,
        "msssim",
        pairs,
        TrainOutputs(tmp_path / "m.pt", tmp_path / "ck.pt"),
        TrainOptions(progress=False),
    )
    model, meta = load_model(tmp_path / "m.pt")
    assert isinstance(model, ResNetMonodepth) and meta["architecture"] == "resnet18"
    x = torch.rand(1, 3, H, W)
    with torch.no_grad():
        out = model(x)
    assert [tuple(d.shape) for d in out] == [(1, 2, H >> s, W >> s) for s in range(4)]
    trained = load_weights_file(tmp_path / "m.pt", "cpu", what="model")["model"]
    untrained = build_model(params).state_dict()
    assert any(not torch.equal(trained[k], untrained[k]) for k in untrained if "weight" in k)


def test_monocular_training_with_resnet18(tmp_path: Path) -> None:
    root = tmp_path / "render"
    params = _params(mode="mono")
    render.generate(params.data.synthetic, root, progress=False, workers=1, lidar=False)
    entries = sequences._read_mono_split(root / MONO_SPLIT)
    samples = sequences._index_sequences(root / "raw", entries, stereo=False).samples
    outputs = TrainOutputs(tmp_path / "m.pt", tmp_path / "ck.pt")
    result = train_variant(params, "ssim", [], outputs, TrainOptions(progress=False, sequences=samples))
    assert result.steps > 0
    model, meta = load_model(tmp_path / "m.pt")
    assert isinstance(model, ResNetMonodepth) and meta["architecture"] == "resnet18"


def test_a_vgg_model_file_holds_no_architecture_entry(tmp_path: Path) -> None:
    """VGG files keep the bytes they had before the option (dvc.lock's hashes of the committed run)."""
    params = _params({"architecture": "vgg"})
    save_model(tmp_path / "m.pt", build_model(params), nn.Module(), params, "ssim", 0)
    assert "architecture" not in load_weights_file(tmp_path / "m.pt", "cpu", what="model")


@pytest.mark.parametrize(
    ("entries", "message"),
    [
        ({"architecture": "resnet50"}, "architecture must be one of"),
        ({"height": 48}, "multiples of 32"),
        ({"architecture": "vgg"}, "do not fit a vgg network"),
    ],
)
def test_a_model_file_that_misstates_its_network_is_one_error(
    tmp_path: Path, entries: dict, message: str
) -> None:
    params = _params()
    save_model(tmp_path / "m.pt", build_model(params), nn.Module(), params, "ssim", 0)
    state = load_weights_file(tmp_path / "m.pt", "cpu", what="model")
    torch.save({**state, **entries}, tmp_path / "bad.pt")
    with pytest.raises(MsdepthError, match=f"bad.pt: .*{message}"):
        load_model(tmp_path / "bad.pt")


@pytest.fixture(scope="module")
def resnet_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A resnet18 model file as save_model writes it (untrained weights)."""
    params = _params()
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("resnet") / "model.pt"
    save_model(path, build_model(params), nn.Module(), params, "ssim", 0)
    return path


def test_predict_runs_a_resnet18_model_and_refuses_other_sizes(
    resnet_model: Path, tmp_path: Path, capsys
) -> None:
    image = tmp_path / "frame.png"
    rgb = (np.random.default_rng(0).random((80, 250, 3)) * 255).astype(np.uint8)
    assert cv2.imwrite(str(image), rgb)
    args = ["predict", str(image), "--model", str(resnet_model), "--quiet"]
    assert main([*args, "--out", str(tmp_path / "out")]) == 0
    disp = cv2.imread(str(tmp_path / "out" / "frame_disp.png"))
    assert disp is not None and disp.shape[:2] == (80, 250)
    capsys.readouterr()
    assert main([*args, "--out", str(tmp_path / "bad"), "--height", "80"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "multiples of 32" in err[0] and str(resnet_model) in err[0]


def test_onnx_export_of_a_resnet18_model_matches_pytorch(resnet_model: Path, tmp_path: Path) -> None:
    ort = pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    out = tmp_path / "model.onnx"
    assert main(["export-onnx", "--model", str(resnet_model), "--out", str(out)]) == 0
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    x = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        expected = load_model(resnet_model)[0](x)[0].numpy()
    (got,) = session.run(None, {"image": x.numpy()})
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-5)
