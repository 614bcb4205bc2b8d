"""The input sides (px) each depth network runs and trains at: one rule per architecture (stdlib only).

The params checks, the model file's checks, ``msdepth predict`` and the ResNet network itself all
ask :func:`sides_problem` and :data:`TRAINING_SIDES`, so that the rule is written once; each keeps its
own message, built from the rule's numbers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable


@dataclass(frozen=True)
class SideRule:
    """Every side a multiple of ``multiple`` px and at least ``minimum`` px."""

    multiple: int
    minimum: int

    def fits(self, side: int) -> bool:
        """Whether one side of ``side`` px keeps the rule."""
        return bool(side % self.multiple == 0 and side >= self.minimum)

    def __str__(self) -> str:
        return f"multiples of {self.multiple}, at least {self.minimum}"


# What every network trains at (data.height, data.width and a model file's size): the 4 output
# scales (1, 1/2, 1/4, 1/8) are then exact halvings, as the loss compares them.
TRAINING_SIDES = SideRule(8, 32)

# What each network runs at. vgg: any size (its decoder interpolates to each skip's size).
# resnet18: the decoder's five doublings undo the encoder's five halvings only at multiples of 32,
# and the reflection padding of the 1/32 features needs 2 px.
NETWORK_SIDES = {"vgg": SideRule(1, 1), "resnet18": SideRule(32, 64)}


def sides_problem(architecture: str, sides: Iterable[int]) -> SideRule | None:
    """The rule of ``architecture``'s network (:data:`NETWORK_SIDES`) that an input of ``sides`` px
    breaks, None if every side keeps it. A KeyError for an architecture it does not know."""
    rule = NETWORK_SIDES[architecture]
    return None if all(rule.fits(side) for side in sides) else rule
