"""The range checks of a params section, and how a value is shown in their messages (stdlib only).

Both :mod:`msdepth.config.params` and the loss variants' configs (:mod:`msdepth.config.variants`) check their
sections with these, so neither imports the other for them (and reading params imports no torch).
"""

from __future__ import annotations

import dataclasses
import math
import re
import reprlib
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Annotated, Any

from msdepth.errors import ConfigError

# A value echoed in a message is cut to this many characters: a params file can hold a value of any
# size (a long list, a deep tree), and a message is one line.
SHOWN_CHARS = 80

MAX_KERNEL_SIZE = 255  # px, an SSIM-type window (the variants': 3 to 11); each must also fit the image
MAX_SSIM_LEVELS = 5  # MS-SSIM's levels (Wang et al.'s 5 weights)

_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxtuple, _REPR.maxdict = 3, 6, 6, 4
_REPR.maxstring, _REPR.maxother, _REPR.maxlong = SHOWN_CHARS, SHOWN_CHARS, 40


def shown(value: object) -> str:
    """``repr(value)`` in at most about :data:`SHOWN_CHARS` characters, on one line, in time and
    memory bounded whatever the value: long strings, lists, mappings and integers are elided."""
    if isinstance(value, int) and value.bit_length() > 128:
        # repr of an integer over 4300 digits raises (sys.int_info.default_max_str_digits).
        return f"an integer of about {int(value.bit_length() * 0.30103) + 1} digits"
    text = _REPR.repr(value).replace("\n", "\\n")
    return text if len(text) <= SHOWN_CHARS else text[: SHOWN_CHARS - 3] + "..."


def check(cond: bool, key: str, message: str) -> None:
    """Raise a ConfigError ``"key: message"`` unless ``cond`` (for the range checks of a section)."""
    if not cond:
        raise ConfigError(f"{key}: {message}")


@dataclass(frozen=True)
class Range:
    """The range a numeric param, or each number of a list param, must lie in, declared on its
    field's type (``Annotated[int, Range(1, 64)]``) and enforced by :func:`check_ranges`:
    ``low``..``high``, an end excluded when ``low_open`` / ``high_open``; ``note`` says why."""

    low: float
    high: float
    low_open: bool = False
    high_open: bool = False
    note: str = ""

    def holds(self, value: float) -> bool:
        """Whether ``value`` lies in the range."""
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def __str__(self) -> str:
        ends = (self.low, self.high)
        if all(isinstance(end, int) for end in ends) and not (self.low_open or self.high_open):
            return f"{self.low}..{self.high}"
        return f"{'(' if self.low_open else '['}{self.low:g}, {self.high:g}{')' if self.high_open else ']'}"


def _declared_range(tp: Any) -> Range | None:
    """The :class:`Range` of a field's type hint (read with ``include_extras``): of
    ``Annotated[number, Range]``, or of its items in ``tuple[Annotated[number, Range], ...]``."""
    if typing.get_origin(tp) is tuple:
        tp = typing.get_args(tp)[0]
    if typing.get_origin(tp) is Annotated:
        return next((m for m in tp.__metadata__ if isinstance(m, Range)), None)
    return None


def check_ranges(config: Any, key: str) -> None:
    """Raise a ConfigError ``"key.name: must be in ..."`` for the first number of the dataclass
    ``config`` (nested sections included) outside the :class:`Range` its field declares."""
    hints = typing.get_type_hints(type(config), include_extras=True)
    for f in dataclasses.fields(config):
        value, name = getattr(config, f.name), f"{key}.{f.name}"
        if dataclasses.is_dataclass(value):
            check_ranges(value, name)
            continue
        bound = _declared_range(hints[f.name])
        if bound is None:
            continue
        items = enumerate(value) if isinstance(value, tuple) else [(None, value)]
        note = f" ({bound.note})" if bound.note else ""
        for i, number in items:
            where = name if i is None else f"{name}[{i}]"
            check(bound.holds(number), where, f"must be in {bound}{note}, got {shown(number)}")


def check_levels_fit(key: str, levels: int, height: int, width: int) -> None:
    """Raise a ConfigError on ``key.levels`` unless an MS-SSIM-type pyramid of ``levels`` levels
    keeps at least one pixel at the coarsest training scale (input ``height`` x ``width`` / 8).
    Windows use "same" padding, so a level only needs to exist."""
    check(1 <= levels <= MAX_SSIM_LEVELS, f"{key}.levels", f"must be in 1..{MAX_SSIM_LEVELS}, got {levels}")
    check(
        min(height, width) // 8 // 2 ** (levels - 1) >= 1,
        f"{key}.levels",
        f"{levels} levels do not fit the coarsest training scale ({height // 8}x{width // 8} px)",
    )


def has_per_pixel_cost(config: object) -> bool:
    """Whether a variant's config (:mod:`msdepth.config.variants`) says its term has a per-pixel
    form that a cost volume can be built from (its class's ``per_pixel_cost``; False if unsaid)."""
    return bool(getattr(config, "per_pixel_cost", False))


def check_per_pixel_costs(key: str, start: str, sections: Mapping[str, object]) -> None:
    """Raise a ConfigError on ``key`` (``optimum.start``) when the start is ``cost`` and a variant's
    config in ``sections`` (name -> config) has no per-pixel cost (:func:`has_per_pixel_cost`): SGM on
    its cost volume cannot be built."""
    if start != "cost":
        return
    without = [name for name, config in sections.items() if not has_per_pixel_cost(config)]
    check(
        not without,
        key,
        f"cost needs each variant's per-pixel cost and {without} have none: set it to sgbm or constant",
    )


# Every integer parameter fits a signed 64-bit integer (numpy, torch); every float one is finite.
INT_RANGE = (-(2**63), 2**63 - 1)
# YAML 1.1 (PyYAML) reads an exponent without a dot (1e-3, 3E+4) as text; YAML 1.2 and users: a number.
EXPONENT_FLOAT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def convert_scalar(value: Any, tp: Any, key: str) -> Any:
    """Check a YAML scalar against ``tp`` (bool, int, float or str); a ConfigError names ``key``."""
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true/false, got {shown(value)}")
        return value
    if tp in (int, float):
        value = (
            float(value)
            if tp is float and isinstance(value, str) and EXPONENT_FLOAT.fullmatch(value)
            else value
        )
        number = isinstance(value, int) or (tp is float and isinstance(value, float))
        if isinstance(value, bool) or not number:
            raise ConfigError(
                f"{key}: expected {'an integer' if tp is int else 'a number'}, got {shown(value)}"
            )
        if isinstance(value, int) and not INT_RANGE[0] <= value <= INT_RANGE[1]:
            raise ConfigError(f"{key}: {shown(value)} is out of range (a 64-bit integer)")
        if tp is float and not math.isfinite(value):
            raise ConfigError(f"{key}: expected a finite number, got {value}")
        return float(value) if tp is float else value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {shown(value)}")
        return value
    raise TypeError(f"unsupported config type {tp} at {key}")  # programming error
