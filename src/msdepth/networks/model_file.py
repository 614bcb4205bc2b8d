"""The depth network a model file holds: built by architecture (:func:`depth_network`: the VGG of
:mod:`msdepth.networks.vgg` or the ResNet of :mod:`msdepth.networks.resnet_depth`), written with
what it takes to rebuild it (:func:`save_model`) and read back checked (:func:`load_model`).

The bytes and the weights-only reading are :mod:`msdepth.networks.serialization`'s; this module
decides what a model file holds.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import torch
from torch import Tensor, nn

from msdepth.config.network_sizes import TRAINING_SIDES, sides_problem
from msdepth.errors import MsdepthError
from msdepth.networks.resnet_depth import ResNetMonodepth
from msdepth.networks.serialization import load_weights_file, save_weights_file
from msdepth.networks.vgg import HEADS, NORMS, Heads, MonodepthVGG, Norm

if TYPE_CHECKING:
    from msdepth.config.params import Params


ARCHITECTURES = ("vgg", "resnet18")
DepthNetwork = MonodepthVGG | ResNetMonodepth  # both: image -> 4 maps (B, 2, h, w), finest first


def depth_network(
    architecture: str,
    width_multiplier: float,
    norm: Norm = "none",
    heads: Heads = "independent",
    init_disparity: float | None = None,
) -> DepthNetwork:
    """The depth network of ``model.architecture``: vgg (``norm``, ``heads`` and ``init_disparity``
    are its options) or resnet18 (Monodepth2's, its outputs started at ``init_disparity``)."""
    if architecture == "resnet18":
        return ResNetMonodepth(width_multiplier, init_disparity)
    return MonodepthVGG(width_multiplier, init_disparity=init_disparity, norm=norm, heads=heads)


# ----------------------------------------------------------------------------- files


def save_model(
    path: str | os.PathLike,
    model: DepthNetwork,
    criterion: nn.Module,
    params: Params,
    variant: str,
    seed: int,
) -> None:
    """Final weights (the network's and the loss's, e.g. learned level weights) plus what is needed
    to rebuild and run the network, written atomically and reproducibly."""
    state = {
        "model": model.state_dict(),
        "criterion": criterion.state_dict(),
        "width_multiplier": params.model.width_multiplier,
        "norm": params.model.norm,
        "heads": params.model.heads,
        "height": params.image_size[0],  # the size it infers at (train.crop_scale x the training crop)
        "width": params.image_size[1],
        "variant": variant,
        "seed": seed,
    }
    if params.model.architecture != "vgg":  # a VGG model's file keeps the bytes it had before
        state["architecture"] = params.model.architecture
    save_weights_file(path, state)


# What save_model writes: a file with any other top-level key was not written by msdepth.
MODEL_KEYS = (
    *("model", "criterion", "width_multiplier", "norm", "heads", "height", "width", "variant", "seed"),
    "architecture",
)
MAX_INPUT_SIDE = 4096  # px; a model file's height and width (20000 x 20000 took 4.8 GB to run)
MAX_WIDTH_MULTIPLIER = 16.0


def _metadata_problem(state: dict) -> str | None:
    """Why a model file's top-level entries are not what :func:`save_model` writes; None if they are."""
    unknown = sorted(str(k) for k in state if k not in MODEL_KEYS)
    missing = [k for k in ("model", "width_multiplier", "height", "width") if k not in state]
    if unknown or missing:
        return f"{'unknown entry' if unknown else 'no'} {', '.join((unknown or missing)[:5])}"
    multiplier, norm, heads = (
        state["width_multiplier"],
        state.get("norm", "none"),
        state.get("heads", "independent"),
    )
    if not (
        isinstance(multiplier, (int, float))
        and not isinstance(multiplier, bool)
        and 0 < multiplier <= MAX_WIDTH_MULTIPLIER
    ):
        return f"width_multiplier must be a number in (0, {MAX_WIDTH_MULTIPLIER:g}], got {multiplier!r}"
    rule = TRAINING_SIDES  # a model file's size is its training size
    for key in ("height", "width"):
        value = state[key]
        if not (
            isinstance(value, int)
            and not isinstance(value, bool)
            and rule.fits(value)
            and value <= MAX_INPUT_SIDE
        ):
            return (
                f"{key} must be a multiple of {rule.multiple} from {rule.minimum} to {MAX_INPUT_SIDE} px, "
                f"got {value!r}"
            )
    if norm not in NORMS or heads not in HEADS:
        return f"norm must be one of {NORMS} and heads one of {HEADS}, got {norm!r} and {heads!r}"
    architecture = state.get("architecture", "vgg")
    if architecture not in ARCHITECTURES:
        return f"architecture must be one of {ARCHITECTURES}, got {architecture!r}"
    sides = (state["height"], state["width"])
    rule = sides_problem(architecture, sides)
    if rule is not None:
        return f"a {architecture} network needs sides that are {rule}, got {sides}"
    weights = state["model"]
    if not isinstance(weights, dict) or not all(isinstance(v, Tensor) for v in weights.values()):
        return "its 'model' entry is not a state dict of tensors"
    return None


def _state_dict_problem(model: nn.Module, weights: dict) -> str | None:
    """Which keys or shapes of ``weights`` differ from ``model``'s (e.g. a meta-device model)."""
    expected = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    found = {str(k): tuple(v.shape) for k, v in weights.items()}
    missing = [k for k in expected if k not in found]
    extra = [k for k in found if k not in expected]
    shapes = [
        f"{k} {found[k]} (expected {expected[k]})" for k in expected if k in found and found[k] != expected[k]
    ]
    parts = [
        f"{label} {', '.join(items[:3])}{f' and {len(items) - 3} more' if len(items) > 3 else ''}"
        for label, items in (("missing", missing), ("unexpected", extra), ("shape of", shapes))
        if items
    ]
    return "; ".join(parts) or None


def load_model(path: str | os.PathLike, device: str | torch.device = "cpu") -> tuple[DepthNetwork, dict]:
    """Rebuild the network saved by :func:`save_model`; returns (model in eval mode, metadata).

    The file is read weights-only (:func:`msdepth.networks.serialization.load_weights_file`): one that
    needs code to load is refused, so a shared model cannot run anything. Its metadata must be
    what save_model writes (types, ranges, no other key) and its weights must have the shapes of
    the network the metadata describes, checked on the meta device before anything is allocated;
    otherwise MsdepthError names the file and what differs."""
    path = Path(path)
    if not path.exists():
        raise MsdepthError(f"{path}: no trained model (run the train stage first)")
    state = load_weights_file(path, device, what="model")
    problem = _metadata_problem(state)
    if problem:
        raise MsdepthError(f"{path}: not a model file written by msdepth ({problem})")
    # Files written before the norm, heads and architecture options hold the dissertation's network.
    options = {
        "architecture": state.get("architecture", "vgg"),
        "width_multiplier": state["width_multiplier"],
        "norm": state.get("norm", "none"),
        "heads": state.get("heads", "independent"),
    }
    with torch.device("meta"):
        problem = _state_dict_problem(depth_network(**options), state["model"])
    if problem:
        raise MsdepthError(
            f"{path}: its weights do not fit a {options['architecture']} network of width_multiplier="
            f"{state['width_multiplier']}: {problem}"
        )
    model = depth_network(**options)
    model.load_state_dict(state["model"])
    meta = {k: v for k, v in state.items() if k not in ("model", "criterion")}
    return model.to(device).eval(), meta
