"""The registry of loss variants' configs: a variant's name -> the dataclass of its params section.

A variant is named after its ``params.yaml`` section, which is also its run's folder
(``models/<name>/seed<s>``). Each module of this package is one variant's config: a frozen
dataclass whose ``validate(key, params)`` raises a ConfigError naming the key, tied to the name by
:func:`register`. Its torch half, the appearance term, is the module of the same name in
:mod:`msdepth.losses.appearance` (a test checks that both registries name the same variants).

:mod:`msdepth.config.params`, which every stage imports to read its params, imports only this package:
so a stage that only reads params neither depends on the loss code (dvc.yaml) nor imports torch.
Hence these modules import only the standard library, ``..checks`` and ``..errors`` (``..config``
only for type hints: config imports this package, and checks that no variant is named like one of
its sections).
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Mapping, TypeVar

from msdepth.config.variants._registry import Registry

T = TypeVar("T", bound=type)

_CONFIGS = Registry(__name__, "variant")


def register(name: str) -> Callable[[T], T]:
    """Class decorator: register the decorated frozen dataclass as the config (params section
    ``name``) of variant ``name``."""

    def decorate(config: T) -> T:
        if not dataclasses.is_dataclass(config) or not callable(getattr(config, "validate", None)):
            raise TypeError(f"variant {name!r}: config must be a dataclass with validate(key, params)")
        _CONFIGS.add(name, config)
        return config

    return decorate


def configs() -> Mapping[str, type]:
    """Every registered variant's config class by name (sorted), after importing each module of
    this package once."""
    return _CONFIGS.entries()
