"""The registry of appearance terms: a loss variant's name -> its config section and its term.

A variant is one module of this package: a frozen dataclass of its ``params.yaml`` section
(whose ``validate(key, params)`` raises a ConfigError naming the key) and an
:class:`msdepth.losses.AppearanceTerm` built from it, tied together by :func:`register`. The
name is also the params section and the run's folder (``models/<name>/seed<s>``). Nothing
else names a variant: :mod:`msdepth.config` reads every registered section,
:func:`build_appearance` gives training its term, and the checkpoint fingerprint hashes the
section of whichever variant it trains. Adding a variant = a module here, its params section,
its docs.

This file imports nothing heavy; :func:`variants` imports the variant modules (and torch).
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Callable, Mapping, TypeVar

if TYPE_CHECKING:
    from ..config import Params
    from ..losses import AppearanceTerm

T = TypeVar("T", bound=type)


@dataclass(frozen=True)
class Registered:
    """One variant: its name (= params section), config dataclass and appearance term class."""

    name: str
    config: type  # frozen dataclass with ``validate(key, params)``; built as term(config, loss_cfg)
    term: type


_REGISTRY: dict[str, Registered] = {}
_discovered = False


def register(name: str, config: type) -> Callable[[T], T]:
    """Class decorator: register the decorated :class:`AppearanceTerm` as variant ``name``,
    configured by the params section ``name`` (dataclass ``config``)."""
    from ..config import Params

    if not dataclasses.is_dataclass(config) or not callable(getattr(config, "validate", None)):
        raise TypeError(f"appearance {name!r}: config must be a dataclass with validate(key, params)")
    if name in {f.name for f in dataclasses.fields(Params)}:
        raise ValueError(f"appearance {name!r}: the name of a params section that is not a variant")

    def decorate(term: T) -> T:
        known = _REGISTRY.get(name)
        if known is not None and known.term.__qualname__ != term.__qualname__:
            raise ValueError(f"appearance {name!r} is registered twice ({known.term} and {term})")
        _REGISTRY[name] = Registered(name, config, term)
        return term

    return decorate


def variants() -> Mapping[str, Registered]:
    """Every registered variant by name (sorted), after importing each module of this package once."""
    global _discovered
    if not _discovered:
        for module in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
            if not module.name.startswith("_"):
                importlib.import_module(f"{__name__}.{module.name}")
        _discovered = True
    return MappingProxyType(dict(sorted(_REGISTRY.items())))


def build_appearance(params: Params, name: str) -> AppearanceTerm:
    """The appearance term of variant ``name``, configured by its params section and ``params.loss``."""
    spec = variants()[params.variant(name)]
    return spec.term(params.appearance[name], params.loss)
