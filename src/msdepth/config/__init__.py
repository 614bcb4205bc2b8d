"""The one typed config: params.yaml's schema and checks, and each loss variant's settings.

:func:`load_params` and :class:`Params` (from :mod:`msdepth.config.params`) are the package's
entry points, so ``msdepth.config.load_params`` reads params.yaml wherever it is named.
"""

from msdepth.config.params import Params, load_params

__all__ = ["Params", "load_params"]
