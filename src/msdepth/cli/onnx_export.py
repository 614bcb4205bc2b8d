"""Export the depth network to ONNX.

The graph takes ``image``: float32 (B, 3, H, W), RGB in [0, 1] (batch, height and width are
dynamic unless exported static), and returns ``disparity``: float32 (B, 2, H, W), the finest
of the network's 4 scales; channel 0 is the left-view disparity as a fraction of the input
width (multiply by W for pixels), channel 1 the right view's. Flip post-processing is not in
the graph: run a batch of the image and its mirror and blend them as
:func:`msdepth.evaluation.infer.post_process_disparity` does.

It uses torch's TorchScript-based exporter (``dynamo=False``): it needs only the ``onnx``
package, traces this network in under a second and keeps H and W dynamic, whereas the
torch.export-based one also needs ``onnxscript`` and is ~20x slower here. The TorchScript
exporter is deprecated since torch 2.9 (still present in 2.13).
"""

from __future__ import annotations

import importlib.util
import os
import warnings
from pathlib import Path

import torch
from torch import Tensor, nn

from msdepth.cli.predict import load_trained
from msdepth.errors import MsdepthError
from msdepth.io import atomic_path
from msdepth.networks.model_file import MAX_INPUT_SIDE, DepthNetwork
from msdepth.outputs import output_file_policy

INPUT_NAME = "image"
OUTPUT_NAME = "disparity"
DEFAULT_OPSET = 17
# Resize with computed sizes (the decoder's upsampling) needs opset 11; the TorchScript exporter
# stops at 20. Checked here, because the exporter dumps its whole IR graph on a bad opset.
OPSET_RANGE = (11, 20)


class FinestDisparity(nn.Module):
    """The network's finest-scale output only, (B, 2, H, W)."""

    def __init__(self, model: DepthNetwork) -> None:
        super().__init__()
        self.model = model

    def forward(self, image: Tensor) -> Tensor:
        return self.model(image)[0]


def export_onnx(
    model_path: str | os.PathLike,
    out_path: str | os.PathLike,
    height: int | None = None,
    width: int | None = None,
    opset: int | None = None,
    dynamic: bool = True,
) -> dict:
    """Export a trained model (``save_model`` file) to ONNX at ``out_path``, atomically.

    ``height``/``width`` (default: the model's training size) set the tracing input, which is
    also the fixed input size when ``dynamic`` is False; ``opset`` defaults to DEFAULT_OPSET.
    Returns the model's metadata, also stored in the ONNX file as ``msdepth.*`` properties.
    ``out_path`` may not be the model, a folder or a file export-onnx did not write (OutputError).
    """
    policy = output_file_policy(out_path, "export-onnx", (model_path,))
    if importlib.util.find_spec("onnx") is None:
        raise MsdepthError("ONNX export needs the 'onnx' package: pip install 'msdepth[onnx]'")
    model, meta = load_trained(model_path, "cpu")
    h = int(meta["height"]) if height is None else height
    w = int(meta["width"]) if width is None else width
    if h <= 0 or w <= 0 or max(h, w) > MAX_INPUT_SIDE:
        raise MsdepthError(f"ONNX export: input size must be 1 to {MAX_INPUT_SIDE} px a side, got {h}x{w}")
    opset = DEFAULT_OPSET if opset is None else opset
    if not OPSET_RANGE[0] <= opset <= OPSET_RANGE[1]:
        raise MsdepthError(f"ONNX export: opset must be in {OPSET_RANGE[0]}..{OPSET_RANGE[1]}, got {opset}")
    axes = {0: "batch", 2: "height", 3: "width"}
    policy.claim([Path(out_path)], model_path)
    with atomic_path(Path(out_path), suffix=".onnx") as tmp:
        with warnings.catch_warnings():
            # The exporter's own deprecation notices (see the module docstring), not the user's concern.
            warnings.filterwarnings("ignore", ".*legacy TorchScript-based ONNX export", DeprecationWarning)
            warnings.filterwarnings("ignore", category=DeprecationWarning, module=r"torch\.onnx")
            try:
                torch.onnx.export(
                    FinestDisparity(model).eval(),
                    (torch.rand(1, 3, h, w),),
                    str(tmp),
                    dynamo=False,
                    input_names=[INPUT_NAME],
                    output_names=[OUTPUT_NAME],
                    dynamic_axes={INPUT_NAME: axes, OUTPUT_NAME: axes} if dynamic else None,
                    opset_version=opset,
                )
            except Exception as exc:  # exporter errors are long and name no file
                first_line = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
                raise MsdepthError(f"{out_path}: ONNX export failed ({first_line})") from exc
        _add_properties(tmp, meta, h, w)
    return meta


def _add_properties(path: Path, meta: dict, h: int, w: int) -> None:
    """Check the exported graph at ``path`` and store the model's metadata in it (``msdepth.*``)."""
    import onnx

    proto = onnx.load(str(path))
    onnx.checker.check_model(proto)
    info = {
        "variant": str(meta.get("variant", "")),
        "width_multiplier": str(meta.get("width_multiplier", "")),
        "height": str(h),
        "width": str(w),
        "output": "finest-scale disparity (B, 2, H, W): channel 0 = left, fraction of width",
    }
    onnx.helper.set_model_props(proto, {f"msdepth.{k}": v for k, v in info.items()})
    onnx.save(proto, str(path))
