"""Writing model and checkpoint files reproducibly, and loading them without running code from them.

``torch.save`` writes a zip holding a pickle, and a plain ``torch.load`` runs whatever that
pickle names: a shared ``model.pt`` could call ``os.system``. The files msdepth writes hold only
tensors and plain data (dicts, lists, strings, numbers), so they are read with torch's
weights-only unpickler, which builds those and nothing else. A file that needs more is refused
with one line naming it; nothing falls back to an unrestricted load.

Part of ``train.TRAINING_MODULES``: :func:`save_weights_file` decides the bytes of the models
the train stage outputs (and DVC hashes).
"""

from __future__ import annotations

import os
import pickle
import re
import zipfile
from pathlib import Path
from typing import Any

import torch

from .errors import MsdepthError
from .io import atomic_path


def save_weights_file(path: str | os.PathLike, state: dict[str, Any]) -> None:
    """``torch.save`` of ``state`` through a temp file and a rename: never a truncated file, and the
    same bytes for the same state (OSError, e.g. a full disk, propagates; ``path`` is untouched)."""
    # Through an open file: torch.save names the zip's root folder after a path it is given (here
    # the random temp name), so equal weights would give different bytes (and DVC hashes) per run.
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        torch.save(state, f)


def load_weights_file(
    path: str | os.PathLike,
    map_location: str | torch.device = "cpu",
    what: str = "model",
    remedy: str = "retrain it with `dvc repro`",
) -> dict[str, Any]:
    """The dict that ``torch.save`` wrote to ``path``, read weights-only (tensors and plain data).

    ``what`` names the kind of file and ``remedy`` what to do about a bad one, for the message.
    Raises MsdepthError naming the file when it is missing, not a torch zip (truncated, or the
    legacy pickle format, which msdepth never writes), corrupt, needs code to be unpickled, or
    holds something other than a dict.
    """
    path = Path(path)
    if not path.is_file():
        raise MsdepthError(f"{path}: no such {what} file")
    # Checked before torch sees the file: its legacy (non-zip) loader is a second unpickling path.
    if not zipfile.is_zipfile(path):
        raise MsdepthError(
            f"{path}: refused to load: not a {what} file written by msdepth (no zip archive: truncated, "
            f"corrupt or another format); {remedy}"
        )
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as exc:
        raise MsdepthError(
            f"{path}: refused to load: {_why_refused(path, exc)}, which a {what} file "
            f"written by msdepth never does; {remedy}"
        ) from None
    except Exception as exc:  # noqa: BLE001 - a damaged zip fails in many ways, all with long messages
        raise MsdepthError(
            f"{path}: cannot read the {what} file, it is corrupt ({_first_line(exc)}); {remedy}"
        ) from None
    if not isinstance(state, dict):
        raise MsdepthError(
            f"{path}: not a {what} file written by msdepth (it holds a "
            f"{type(state).__name__}, not a dict); {remedy}"
        )
    return state


def _why_refused(path: Path, exc: pickle.UnpicklingError) -> str:
    """What the weights-only unpickler objected to: the code the pickle names, where torch can list
    it without running it, else torch's own reason (e.g. an unsupported pickle opcode)."""
    try:
        names = torch.serialization.get_unsafe_globals_in_checkpoint(path)  # a scan, not an unpickling
    except Exception:  # noqa: BLE001 - older torch, or a pickle the scanner cannot parse either
        names = []
    if names:
        return f"the file needs code to be unpickled (weights_only; it names {', '.join(names)})"
    match = re.search(r"WeightsUnpickler error:\s*(.+)", str(exc))
    reason = match.group(1).strip() if match else _first_line(exc)
    return f"the file's pickle is not plain data (weights_only: {reason})"


def _first_line(exc: BaseException) -> str:
    """The first sentence of ``exc``'s message: torch's go on for lines of advice."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return lines[0].split(". ")[0].rstrip(".") if lines else type(exc).__name__
