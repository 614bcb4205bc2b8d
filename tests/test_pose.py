"""Tests of the ResNet-18 encoder, its pretrained loading and the pose network's output convention."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from torch import nn

from msdepth.errors import MsdepthError
from msdepth.geometry.camera import transformation_from_parameters
from msdepth.networks.common import MAX_DISPARITY
from msdepth.networks.pose import PoseDecoder, PoseNet, relative_pose
from msdepth.networks.resnet import CHANNELS, ResNetEncoder, load_pretrained
from msdepth.networks.resnet_depth import DepthDecoder, ResNetMonodepth

# torchvision's resnet18 has 11,689,512 parameters, of which its classifier fc holds 512·1000 + 1000.
RESNET18_WITHOUT_FC = 11_689_512 - 513_000


def _frames(seed: int, b: int = 2, h: int = 64, w: int = 96) -> torch.Tensor:
    return torch.rand(b, 3, h, w, generator=torch.Generator().manual_seed(seed))


def test_encoder_is_resnet18_with_monodepth2_features() -> None:
    torch.manual_seed(0)
    encoder = ResNetEncoder()
    assert sum(p.numel() for p in encoder.parameters()) == RESNET18_WITHOUT_FC
    features = encoder(_frames(1, h=64, w=192))
    assert [tuple(f.shape[1:]) for f in features] == [
        (c, 64 >> s, 192 >> s) for c, s in zip(CHANNELS, range(1, 6), strict=True)
    ]
    # torchvision's names, so its state dicts load.
    names = set(encoder.state_dict())
    assert {
        "conv1.weight",
        "bn1.running_mean",
        "layer1.0.conv2.weight",
        "layer2.0.downsample.0.weight",
    } <= names
    assert "layer1.0.downsample.0.weight" not in names


def _torchvision_like_file(tmp_path: Path, seed: int) -> tuple[Path, ResNetEncoder]:
    """A file as torchvision's resnet18 state dict would be (with its fc), from a random encoder."""
    torch.manual_seed(seed)
    source = ResNetEncoder()
    for m in source.modules():  # non-trivial BatchNorm statistics, so their loading is checked too
        if isinstance(m, nn.BatchNorm2d):
            m.running_mean.uniform_(-0.1, 0.1)
            m.running_var.uniform_(0.5, 1.5)
    state = dict(source.state_dict())
    state["fc.weight"], state["fc.bias"] = torch.zeros(1000, 512), torch.zeros(1000)
    path = tmp_path / "resnet18.pth"
    torch.save(state, path)
    return path, source.eval()


def test_load_pretrained_single_image(tmp_path: Path) -> None:
    path, source = _torchvision_like_file(tmp_path, seed=3)
    torch.manual_seed(4)
    encoder = ResNetEncoder()
    load_pretrained(encoder, path)
    x = _frames(5)
    for ours, ref in zip(encoder.eval()(x), source(x), strict=True):
        assert torch.equal(ours, ref)


def test_load_pretrained_two_images_repeats_conv1(tmp_path: Path) -> None:
    # Monodepth2: conv1 repeated per image and divided by 2, so identical frames give the features
    # of the single-image network.
    path, source = _torchvision_like_file(tmp_path, seed=6)
    encoder = ResNetEncoder(input_images=2)
    load_pretrained(encoder, path)
    x = _frames(7)
    ours, ref = encoder.eval()(torch.cat((x, x), 1)), source(x)
    for a, b in zip(ours, ref, strict=True):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-4 * b.abs().max().item()), (a - b).abs().max()


def test_load_pretrained_refuses_other_files(tmp_path: Path) -> None:
    path = tmp_path / "other.pth"
    torch.save({"conv1.weight": torch.zeros(64, 3, 7, 7)}, path)
    with pytest.raises(MsdepthError, match=r"other\.pth: not a torchvision resnet18 state dict \(missing"):
        load_pretrained(ResNetEncoder(), path)
    with pytest.raises(MsdepthError, match="absent.pth"):
        load_pretrained(ResNetEncoder(), tmp_path / "absent.pth")


def md2_pose_decoder_forward(convs: dict, input_features: list, frames: int) -> tuple:
    """Monodepth2's ``PoseDecoder.forward``, transcribed (its convs keyed as there)."""
    relu = nn.ReLU()
    last_features = [f[-1] for f in input_features]
    cat_features = torch.cat([relu(convs["squeeze"](f)) for f in last_features], 1)
    out = cat_features
    for i in range(3):
        out = convs[("pose", i)](out)
        if i != 2:
            out = relu(out)
    out = out.mean(3).mean(2)
    out = 0.01 * out.view(-1, frames, 1, 6)
    return out[..., :3], out[..., 3:]


def test_pose_decoder_matches_monodepth2() -> None:
    torch.manual_seed(8)
    decoder = PoseDecoder()
    features = [torch.randn(2, 512, 2, 3, generator=torch.Generator().manual_seed(9))]
    convs = {"squeeze": decoder.squeeze, ("pose", 0): decoder.pose0, ("pose", 1): decoder.pose1}
    convs[("pose", 2)] = decoder.pose2
    ref_a, ref_t = md2_pose_decoder_forward(convs, [features], 2)
    axis_angle, translation = decoder(features[-1])
    assert torch.allclose(axis_angle, ref_a[:, :, 0], atol=1e-7)
    assert torch.allclose(translation, ref_t[:, :, 0], atol=1e-7)


def test_pose_decoder_output_is_scaled_by_a_hundredth() -> None:
    decoder = PoseDecoder()
    nn.init.zeros_(decoder.pose2.weight)
    with torch.no_grad():
        decoder.pose2.bias.copy_(torch.arange(12.0))
    axis_angle, translation = decoder(torch.randn(1, 512, 2, 3))
    assert torch.allclose(axis_angle[0, 0], torch.tensor([0.0, 0.01, 0.02]))
    assert torch.allclose(translation[0, 1], torch.tensor([0.09, 0.10, 0.11]))


class _FixedPose(nn.Module):
    """A stand-in pose network: fixed output, records the order it saw the frames in."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[tuple[float, float]] = []
        self.axis_angle = torch.tensor([[0.01, -0.02, 0.03]])
        self.translation = torch.tensor([[0.1, 0.0, 0.5]])

    def forward(self, first: torch.Tensor, second: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        self.seen.append((first.flatten()[0].item(), second.flatten()[0].item()))
        return self.axis_angle, self.translation


def test_relative_pose_frame_order_and_inversion() -> None:
    net = _FixedPose()
    target, source = torch.zeros(1, 3, 4, 4), torch.ones(1, 3, 4, 4)
    forward = relative_pose(net, target, source, +1)
    backward = relative_pose(net, target, source, -1)
    assert net.seen == [(0.0, 1.0), (1.0, 0.0)]  # always earlier frame first
    assert torch.allclose(forward, transformation_from_parameters(net.axis_angle, net.translation))
    assert torch.allclose(backward, torch.linalg.inv(forward), atol=1e-5)
    with pytest.raises(ValueError, match="offset 0"):
        relative_pose(net, target, source, 0)


def test_posenet_shapes_and_near_identity_start() -> None:
    torch.manual_seed(10)
    net = PoseNet()
    axis_angle, translation = net(_frames(11, b=2), _frames(12, b=2))
    assert axis_angle.shape == translation.shape == (2, 3)
    # ×0.01 keeps the initial poses small.
    assert axis_angle.abs().max() < 0.1 and translation.abs().max() < 0.1
    with pytest.raises(ValueError, match="two \\(B, 3, H, W\\) frames"):
        net(_frames(1), _frames(1, b=1))


# ----------------------------------------------------------------------------- depth decoder


def md2_depth_decoder_forward(convs: dict, input_features: list) -> dict:
    """Monodepth2's ``DepthDecoder.forward`` (use_skips, scales 0..3), transcribed."""
    outputs = {}
    x = input_features[-1]
    for i in range(4, -1, -1):
        x = convs[("upconv", i, 0)](x)
        x = [torch.nn.functional.interpolate(x, scale_factor=2, mode="nearest")]
        if i > 0:
            x += [input_features[i - 1]]
        x = torch.cat(x, 1)
        x = convs[("upconv", i, 1)](x)
        if i in range(4):
            outputs[("disp", i)] = torch.sigmoid(convs[("dispconv", i)](x))
    return outputs


def test_depth_decoder_matches_monodepth2() -> None:
    """ResNetMonodepth's maps are 0.3 x Monodepth2's DepthDecoder (two output channels) on its encoder."""
    torch.manual_seed(13)
    net = ResNetMonodepth()
    image = _frames(14, h=64, w=96)
    features = net.encoder(image)
    convs = {("dispconv", s): net.decoder.dispconvs[s] for s in range(4)}
    for i in range(5):
        convs[("upconv", i, 0)], convs[("upconv", i, 1)] = net.decoder.upconvs0[i], net.decoder.upconvs1[i]
    ref = md2_depth_decoder_forward(convs, features)
    ours = net(image)
    assert [tuple(d.shape) for d in ours] == [(2, 2, 64 >> s, 96 >> s) for s in range(4)]
    for s in range(4):
        assert torch.equal(ours[s], MAX_DISPARITY * ref[("disp", s)])
    # Monodepth2's channel counts: 3,152,724 decoder parameters beside ResNet-18's encoder.
    assert sum(p.numel() for p in DepthDecoder().parameters()) == DECODER_PARAMETERS == 3_152_724
    for h, w in ((48, 96), (32, 96)):
        with pytest.raises(ValueError, match="multiples of 32 and >= 64"):
            net(_frames(1, h=h, w=w))


def _decoder_parameters() -> int:
    """Monodepth2's decoder, counted by hand: 3x3 convs (+ bias) of each block."""
    enc, dec = (64, 64, 128, 256, 512), (16, 32, 64, 128, 256)
    total = 0
    for i in range(5):
        c_in = enc[-1] if i == 4 else dec[i + 1]
        total += 9 * c_in * dec[i] + dec[i]
        c_in = dec[i] + (enc[i - 1] if i > 0 else 0)
        total += 9 * c_in * dec[i] + dec[i]
    return total + sum(9 * dec[s] + 1 for s in range(4))


DECODER_PARAMETERS = _decoder_parameters()


def test_pose_network_width() -> None:
    # 1.0 is Monodepth2's: torchvision's resnet18 without fc (11,176,512 parameters), conv1 taking
    # 6 channels (+64·3·7·7), and its PoseDecoder (squeeze 512->256, two 3x3 256->256, 256->12).
    full = PoseNet(1.0)
    decoder = (512 * 256 + 256) + 2 * (256 * 256 * 9 + 256) + (256 * 12 + 12)
    assert sum(p.numel() for p in full.parameters()) == 11_176_512 + 64 * 3 * 7 * 7 + decoder
    narrow = PoseNet(0.25)
    assert narrow.encoder.channels == (16, 16, 32, 64, 128) and narrow.decoder.squeeze.out_channels == 64
    frames = torch.rand(2, 3, 64, 96)
    assert [t.shape for t in narrow(frames, frames)] == [(2, 3), (2, 3)]


def test_pose_width_is_a_checked_param_left_out_of_old_fingerprints() -> None:
    from msdepth.config.params import ConfigError, ModelConfig, fingerprint_fields, params_from_dict

    assert params_from_dict({}).model.pose_width_multiplier == 0.25
    assert "pose_width_multiplier" not in fingerprint_fields(ModelConfig())
    with pytest.raises(ConfigError, match="model.pose_width_multiplier: must be <= 4.0"):
        params_from_dict({"model": {"pose_width_multiplier": 8}})
