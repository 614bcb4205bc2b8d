"""Monodepth's training objective of a loss variant, built from the params: what training and the
losses' own optimum minimise (so the optimum needs no training code)."""

from __future__ import annotations

from msdepth.config.params import Params
from msdepth.losses.appearance import build_appearance
from msdepth.losses.monodepth import MonodepthLoss


def build_loss(params: Params, variant: str) -> MonodepthLoss:
    """The training loss of ``variant``, with the appearance term registered under that name."""
    return MonodepthLoss(params.loss, build_appearance(params, variant))
