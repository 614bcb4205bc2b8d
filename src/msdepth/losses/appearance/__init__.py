"""The registry of appearance terms: a loss variant's name -> its
:class:`msdepth.losses.monodepth.AppearanceTerm`.

A variant is two modules of the same name: its config, the dataclass of its ``params.yaml``
section, in :mod:`msdepth.config.variants`, and its term here, registered by :func:`term` and built as
``Term(config, params.loss)`` (per scale, the photometric loss of the reconstruction against its
target). The configs are apart so that reading params (every stage) imports no torch and no loss
code; only training, which builds the term (:func:`build_appearance`), imports this package.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Mapping, TypeVar

from msdepth.config.variants import configs
from msdepth.config.variants._registry import Registry

if TYPE_CHECKING:
    from msdepth.config.params import Params
    from msdepth.losses.monodepth import AppearanceTerm

T = TypeVar("T", bound=type)

_TERMS = Registry(__name__, "appearance")


def term(name: str) -> Callable[[T], T]:
    """Class decorator: register the decorated :class:`AppearanceTerm` as the term of variant
    ``name``, whose config (:mod:`msdepth.config.variants`) it is built from."""
    if name not in configs():
        raise ValueError(f"appearance {name!r}: no variant config of that name in msdepth.config.variants")

    def decorate(cls: T) -> T:
        _TERMS.add(name, cls)
        return cls

    return decorate


def terms() -> Mapping[str, type]:
    """Every registered term class by variant name (sorted), after importing each module of this
    package once."""
    return _TERMS.entries()


def build_appearance(params: Params, name: str) -> AppearanceTerm:
    """The appearance term of variant ``name``, configured by its params section and ``params.loss``."""
    return terms()[params.variant(name)](params.appearance[name], params.loss)
