"""Writing model and checkpoint files reproducibly, and loading them without running code from them.

``torch.save`` writes a zip holding a pickle, and a plain ``torch.load`` runs whatever that
pickle names: a shared ``model.pt`` could call ``os.system``. The files msdepth writes hold only
tensors and plain data (dicts, lists, strings, numbers), so they are read with torch's
weights-only unpickler, which builds those and nothing else. A file that needs more is refused
with one line naming it; nothing falls back to an unrestricted load.

Weights-only still lets a file allocate without bound (``bytearray(3 GiB)`` from a 100-byte
pickle; a deflated zip record that expands 1000-fold), so before torch reads the file it is
checked to be what ``torch.save`` writes: a zip from its first byte (torch takes any other file
to its legacy loader), every record stored uncompressed (so nothing is larger than the file),
and a pickle that names only the handful of functions a state dict needs (:data:`PICKLE_GLOBALS`).

Part of :data:`msdepth.training.train.TRAINING_MODULES`: :func:`save_weights_file` decides the bytes
of the models the train stage outputs (and DVC hashes).
"""

from __future__ import annotations

import os
import pickle
import pickletools
import re
import zipfile
from pathlib import Path
from typing import Any

import torch

from msdepth.errors import MsdepthError
from msdepth.io import atomic_path


def save_weights_file(path: str | os.PathLike, state: dict[str, Any]) -> None:
    """``torch.save`` of ``state`` through a temp file and a rename: never a truncated file, and the
    same bytes for the same state (OSError, e.g. a full disk, propagates; ``path`` is untouched).
    A state holding a NaN or infinite float tensor is a MsdepthError, and nothing is written."""
    # Through an open file: torch.save names the zip's root folder after a path it is given (here
    # the random temp name), so equal weights would give different bytes (and DVC hashes) per run.
    bad = _nonfinite_tensors(state)
    if bad:
        raise MsdepthError(
            f"{path}: not written: {bad[0]} holds NaN or infinite values ({len(bad)} tensor(s) in all); "
            "a file of them would give NaN depth"
        )
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
    if not os.path.isfile(path):  # Path.is_file raises on a name too long (ENAMETOOLONG)
        raise MsdepthError(f"{path}: no such {what} file")
    # Checked before torch sees the file: its legacy (non-zip) loader is a second unpickling path.
    with open(path, "rb") as f:  # torch's own test (_is_zipfile); zipfile.is_zipfile looks at the end
        if f.read(4) != _ZIP_LOCAL_HEADER or not zipfile.is_zipfile(f):
            raise MsdepthError(
                f"{path}: refused to load: not a {what} file written by msdepth (no zip archive from its "
                f"first byte: truncated, corrupt, torch's legacy format or another); {remedy}"
            )
    problem = _zip_problem(path)
    if problem:
        raise MsdepthError(
            f"{path}: refused to load: {problem}, unlike every {what} file written by msdepth; {remedy}"
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
    if _nested_deeper(state, MAX_NESTING):  # before _nonfinite_tensors and its callers recurse into it
        raise MsdepthError(
            f"{path}: refused to load: its lists or dicts nest deeper than {MAX_NESTING} levels, unlike "
            f"every {what} file written by msdepth; {remedy}"
        )
    bad = _nonfinite_tensors(state)
    if bad:
        raise MsdepthError(
            f"{path}: refused to load: {bad[0]} holds NaN or infinite values ({len(bad)} tensor(s) in all), "
            f"which would give NaN depth; {remedy}"
        )
    return state


# msdepth's files nest a few levels (a checkpoint: optimizer, state, parameter index, name, tensor);
# the code that reads them recurses, so a file nested 5,000 deep ended in a RecursionError.
MAX_NESTING = 32


def _nested_deeper(state: Any, limit: int) -> bool:
    """Whether the dicts, lists and tuples of ``state`` nest more than ``limit`` levels deep (walked
    with a stack, not recursion)."""
    stack = [(state, 0)]
    while stack:
        value, depth = stack.pop()
        if isinstance(value, dict):
            children = list(value.values())
        elif isinstance(value, (list, tuple)):
            children = list(value)
        else:
            continue
        if depth >= limit:
            return True
        stack += [(child, depth + 1) for child in children]
    return False


# A checkpoint's optimizer state is not weights: Adam's second moments may overflow in bfloat16
# (inf), which Adam tolerates (the step is then 0), so only the other entries are checked.
NOT_WEIGHTS = ("optimizer",)


def _nonfinite_tensors(state: Any, prefix: str = "") -> list[str]:
    """The names (``model.conv1.weight``) of the floating-point tensors in ``state`` (nested dicts,
    lists and tuples; not its top-level :data:`NOT_WEIGHTS` entries) that hold a NaN or an infinity."""
    if isinstance(state, torch.Tensor):
        finite = not state.is_floating_point() or bool(torch.isfinite(state).all())
        return [] if finite else [prefix or "a tensor"]
    if isinstance(state, dict):
        items = state.items()
    elif isinstance(state, (list, tuple)):
        items = enumerate(state)
    else:
        return []
    found = []
    for key, value in items:
        if not prefix and key in NOT_WEIGHTS:
            continue
        found += _nonfinite_tensors(value, f"{prefix}.{key}" if prefix else str(key)[:80])
    return found


# What a torch.save'd dict of tensors names in its pickle (protocol 2's GLOBAL opcode): the dict
# type, the tensor rebuilders and the typed storages. Any other name, e.g. builtins.bytearray
# (which weights-only allows), is refused before unpickling.
PICKLE_GLOBALS = re.compile(
    r"collections OrderedDict|torch\._utils _rebuild_(tensor_v2|tensor_v3|parameter)"
    r"|torch [A-Za-z0-9]*Storage"
)
MAX_PICKLE_BYTES = 16 * 2**20  # msdepth's pickles hold names and shapes only: ~10 KB
_ZIP_LOCAL_HEADER = b"PK\x03\x04"  # torch.serialization._is_zipfile compares exactly these bytes


def _zip_problem(path: Path) -> str | None:
    """Why the zip ``path`` is not one as ``torch.save`` writes it, read without unpickling; None if it is."""
    with open(path, "rb") as f:
        if f.read(4) != _ZIP_LOCAL_HEADER:  # torch's own test; zipfile.is_zipfile looks at the end
            return (
                "not a zip archive from its first byte (truncated, corrupt, torch's legacy format or another)"
            )
    try:
        with zipfile.ZipFile(path) as archive:
            records = archive.infolist()
            packed = [r.filename for r in records if r.compress_type != zipfile.ZIP_STORED]
            if packed:
                return f"its zip record {packed[0]} is compressed (torch.save stores records as they are)"
            if any(r.file_size != r.compress_size for r in records):
                return "a zip record's size disagrees with its stored size"
            pickles = [r for r in records if r.filename.endswith("data.pkl")]  # none: torch says corrupt
            if any(r.file_size > MAX_PICKLE_BYTES for r in pickles):
                return f"its pickle is larger than {MAX_PICKLE_BYTES} bytes"
            names = set().union(*(_pickle_globals(archive.read(r)) for r in pickles))
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        return f"a damaged zip archive ({_first_line(exc)})"
    unexpected = sorted(n for n in names if not PICKLE_GLOBALS.fullmatch(n))
    if unexpected:
        named = ", ".join(n.replace(" ", ".") for n in unexpected[:5])
        return f"the file needs code to be unpickled (weights_only, and more than tensors: it names {named})"
    return None


def _pickle_globals(data: bytes) -> set[str]:
    """The 'module name' of every GLOBAL opcode; STACK_GLOBAL etc. (never written by torch.save's
    protocol 2) as a name that no allowlist holds."""
    names = set()
    for opcode, arg, _ in pickletools.genops(data):
        if opcode.name in ("GLOBAL", "INST"):
            names.add(str(arg))
        elif opcode.name in ("STACK_GLOBAL", "OBJ", "NEWOBJ", "NEWOBJ_EX", "EXT1", "EXT2", "EXT4"):
            names.add(f"(opcode {opcode.name})")
    return names


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
