"""The registry of appearance terms: a loss variant's name -> its :class:`msdepth.losses.AppearanceTerm`.

A variant is two modules of the same name: its config, the dataclass of its ``params.yaml``
section, in :mod:`msdepth.variants`, and its term here, registered by :func:`term` and built as
``Term(config, params.loss)`` (per scale, the photometric loss of the reconstruction against its
target). The configs are apart so that reading params (every stage) imports no torch and no loss
code; only training, which builds the term (:func:`build_appearance`), imports this package.
"""

from __future__ import annotations

import importlib
import pkgutil
from types import MappingProxyType
from typing import TYPE_CHECKING, Callable, Mapping, TypeVar

from ..variants import configs

if TYPE_CHECKING:
    from ..config import Params
    from ..losses import AppearanceTerm

T = TypeVar("T", bound=type)

_REGISTRY: dict[str, type] = {}
_discovered = False


def term(name: str) -> Callable[[T], T]:
    """Class decorator: register the decorated :class:`AppearanceTerm` as the term of variant
    ``name``, whose config (:mod:`msdepth.variants`) it is built from."""
    if name not in configs():
        raise ValueError(f"appearance {name!r}: no variant config of that name in msdepth.variants")

    def decorate(cls: T) -> T:
        known = _REGISTRY.get(name)
        if known is not None and known.__qualname__ != cls.__qualname__:
            raise ValueError(f"appearance {name!r} is registered twice ({known} and {cls})")
        _REGISTRY[name] = cls
        return cls

    return decorate


def terms() -> Mapping[str, type]:
    """Every registered term class by variant name (sorted), after importing each module of this
    package once."""
    global _discovered
    if not _discovered:
        for module in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
            if not module.name.startswith("_"):
                importlib.import_module(f"{__name__}.{module.name}")
        _discovered = True
    return MappingProxyType(dict(sorted(_REGISTRY.items())))


def build_appearance(params: Params, name: str) -> AppearanceTerm:
    """The appearance term of variant ``name``, configured by its params section and ``params.loss``."""
    return terms()[params.variant(name)](params.appearance[name], params.loss)
