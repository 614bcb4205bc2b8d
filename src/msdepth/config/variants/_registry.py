"""One name -> class registry per package, filled by that package's own modules (stdlib only).

Both halves of a loss variant are registered by name: its config (:mod:`msdepth.config.variants`) and
its appearance term (:mod:`msdepth.losses.appearance`). Each package's modules register themselves on
import; the first lookup imports every module of the package (but ``_private`` ones), so a new
variant needs no list to be edited. Kept in this light package: reading params imports it.
"""

from __future__ import annotations

import importlib
import pkgutil
from types import MappingProxyType
from typing import Mapping


class Registry:
    """``name -> class`` for the modules of package ``package``; ``what`` names an entry in errors."""

    def __init__(self, package: str, what: str) -> None:
        self.package, self.what = package, what
        self._entries: dict[str, type] = {}
        self._discovered = False

    def add(self, name: str, cls: type) -> None:
        """Register ``cls`` as ``name``; a second class under the same name is an error (the same
        class again, e.g. a module re-imported, is not)."""
        known = self._entries.get(name)
        if known is not None and known.__qualname__ != cls.__qualname__:
            raise ValueError(f"{self.what} {name!r} is registered twice ({known} and {cls})")
        self._entries[name] = cls

    def entries(self) -> Mapping[str, type]:
        """Every registered class by name (sorted), after importing each module of the package once."""
        if not self._discovered:
            package = importlib.import_module(self.package)
            for module in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
                if not module.name.startswith("_"):
                    importlib.import_module(f"{self.package}.{module.name}")
            self._discovered = True
        return MappingProxyType(dict(sorted(self._entries.items())))
