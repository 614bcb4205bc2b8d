"""The range checks of a params section, and how a value is shown in their messages (stdlib only).

Both :mod:`msdepth.config.params` and the loss variants' configs (:mod:`msdepth.config.variants`) check their
sections with these, so neither imports the other for them (and reading params imports no torch).
"""

from __future__ import annotations

import reprlib
from collections.abc import Mapping

from msdepth.errors import ConfigError

# A value echoed in a message is cut to this many characters: a params file can hold a value of any
# size (a long list, a deep tree), and a message is one line.
SHOWN_CHARS = 80

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


def check_levels_fit(key: str, levels: int, height: int, width: int) -> None:
    """Raise a ConfigError on ``key.levels`` unless an MS-SSIM-type pyramid of ``levels`` levels
    keeps at least one pixel at the coarsest training scale (input ``height`` x ``width`` / 8).
    Windows use "same" padding, so a level only needs to exist."""
    check(1 <= levels <= 5, f"{key}.levels", f"must be in 1..5, got {levels}")
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
