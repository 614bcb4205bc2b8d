"""The input-side rules of msdepth.config.network_sizes at their edges, and the params messages that
name the training rule (the other callers: test_architecture.py, test_model_file_bounds.py, test_pose.py)."""

from __future__ import annotations

import re

import pytest

from msdepth.config.network_sizes import NETWORK_SIDES, TRAINING_SIDES, SideRule, sides_problem
from msdepth.config.params import params_from_dict
from msdepth.errors import ConfigError


@pytest.mark.parametrize(
    ("side", "fits"),
    [(0, False), (24, False), (31, False), (32, True), (36, False), (40, True), (4096, True)],
)
def test_training_sides_are_multiples_of_8_at_least_32(side: int, fits: bool) -> None:
    assert TRAINING_SIDES.fits(side) is fits


@pytest.mark.parametrize(
    ("sides", "broken"),
    [
        ((64, 192), False),
        ((96, 128), False),
        ((63, 192), True),
        ((64, 200), True),
        ((32, 192), True),  # a multiple of 32 under 64
        ((48, 192), True),  # a training size that resnet18 cannot run at
        ((0, 64), True),
        ((-64, 64), True),
    ],
)
def test_resnet18_runs_at_multiples_of_32_at_least_64(sides: tuple[int, int], broken: bool) -> None:
    rule = sides_problem("resnet18", sides)
    assert (rule is not None) is broken
    if broken:
        assert rule == SideRule(32, 64) and str(rule) == "multiples of 32, at least 64"


@pytest.mark.parametrize("sides", [(1, 1), (24, 24), (37, 53), (64, 192)])
def test_vgg_runs_at_any_size(sides: tuple[int, int]) -> None:
    """Its decoder interpolates to each skip's size; its rule is the training one (TRAINING_SIDES)."""
    assert sides_problem("vgg", sides) is None


def test_every_resnet18_size_is_a_training_size() -> None:
    """So data.height and data.width can keep the training rule and then the network's."""
    rule = NETWORK_SIDES["resnet18"]
    assert all(TRAINING_SIDES.fits(side) for side in range(1, 4097) if rule.fits(side))


def test_an_unknown_architecture_is_a_key_error() -> None:
    with pytest.raises(KeyError):
        sides_problem("vgg16", (64, 64))


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"height": 36}, "data.height: must be a multiple of 8 and >= 32, got 36"),
        ({"width": 24}, "data.width: must be a multiple of 8 and >= 32, got 24"),
    ],
)
def test_params_name_the_training_rule(data: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(message)):
        params_from_dict({"data": data})
