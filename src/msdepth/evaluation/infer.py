"""Disparity inference with Monodepth's flip post-processing."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd
import torch
from tqdm import tqdm

from msdepth.data import kitti
from msdepth.data.pairs import resize, to_tensor
from msdepth.networks.model_file import DepthNetwork


def post_process_disparity(
    disp: torch.Tensor | np.ndarray, disp_of_flipped: torch.Tensor | np.ndarray
) -> np.ndarray:
    """Blend the disparity of an image with that of its mirror image (Monodepth).

    ``disp`` is the left disparity of the image, ``disp_of_flipped`` the left disparity the
    network predicted for the horizontally flipped image (not flipped back), each (..., H, W).
    The left 5 % of columns come from the flipped prediction (its right edge saw no
    disocclusion), the right 5 % from the plain one, and the rest is their mean:
    ``r_mask*d + l_mask*flip(d_f) + (1 - l_mask - r_mask)*mean``.
    """
    d = np.asarray(disp, dtype=np.float32)
    d_f = np.flip(np.asarray(disp_of_flipped, dtype=np.float32), axis=-1)
    w = d.shape[-1]
    ramp = np.linspace(0, 1, w, dtype=np.float32)
    l_mask = 1.0 - np.clip(20 * (ramp - 0.05), 0, 1)
    r_mask = l_mask[::-1]
    mean = 0.5 * (d + d_f)
    return (r_mask * d + l_mask * d_f + (1.0 - l_mask - r_mask) * mean).astype(np.float32)


@torch.no_grad()
def predict_disparities(
    model: DepthNetwork,
    images: Sequence[Path],
    height: int,
    width: int,
    post_process: bool = True,
    batch_size: int = 8,
    device: str | torch.device = "cpu",
    progress: bool = True,
) -> np.ndarray:
    """Left disparities (fraction of width) at the network's input size, shape (N, height, width).

    Like Monodepth's ``disparities.npy``: conversion to pixels at each image's own GT size
    happens at evaluation (:func:`msdepth.geometry.depth.pixel_disparity`).
    """
    model.eval()
    out = np.empty((len(images), height, width), dtype=np.float32)
    for start in tqdm(range(0, len(images), batch_size), desc="inference", disable=not progress, leave=False):
        chunk = images[start : start + batch_size]
        batch = torch.stack([to_tensor(resize(kitti.read_image(p), height, width)) for p in chunk]).to(device)
        out[start : start + len(chunk)] = network_disparity(model, batch, post_process)
    return out


def index_disparities(model: DepthNetwork, meta: dict, index: pd.DataFrame, post_process: bool) -> np.ndarray:
    """:func:`predict_disparities` of the left image of every frame of an evaluation index, at the
    network's input size (``meta``: its model file's, :func:`msdepth.networks.model_file.load_model`)."""
    lefts = [Path(p) for p in index["left"]]
    return predict_disparities(model, lefts, meta["height"], meta["width"], post_process)


@torch.no_grad()
def network_disparity(model: DepthNetwork, batch: torch.Tensor, post_process: bool = True) -> np.ndarray:
    """Left disparity (fraction of width) of a (B, 3, h, w) batch at the network size, (B, h, w).

    With ``post_process``, the batch and its mirror image go through the network together and
    are blended by :func:`post_process_disparity`.
    """
    if post_process:
        disp = model(torch.cat([batch, torch.flip(batch, dims=[-1])]))[0][:, 0]
        n = batch.shape[0]
        return post_process_disparity(disp[:n].cpu().numpy(), disp[n:].cpu().numpy())
    return model(batch)[0][:, 0].cpu().numpy()
