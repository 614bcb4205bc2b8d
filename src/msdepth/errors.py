"""The project's own error types: one clear message naming the file or key at fault."""

from __future__ import annotations


class MsdepthError(Exception):
    """Base class of every error this package raises on purpose."""


class DataError(MsdepthError):
    """An input file is missing, unreadable or of the wrong shape/type (the message names it)."""


class ConfigError(MsdepthError):
    """A parameter in params.yaml has the wrong type or is out of range (the message names the key)."""


class PixelLimitError(DataError):
    """An image's header declares more pixels than the limit of the command reading it."""


class OutputError(MsdepthError):
    """An output may not be written where asked: it would replace an input, the model or a file the
    command did not write, two inputs map to it, or the output folder is not usable (it names the path)."""
