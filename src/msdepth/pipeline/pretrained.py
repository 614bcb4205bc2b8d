"""The record of ``model.pretrained`` that the ``pretrained`` stage writes and ``train`` depends on.

DVC cannot list a dep whose path may be empty, and ``model.pretrained`` is ``""`` by default, so
DVC tracks the weights file through this record instead (:data:`msdepth.pipeline.paths.PRETRAINED`):
the path and the sha256 of the file's content, or a fixed record when it is unset. The stage runs on
every ``dvc repro`` (dvc.yaml: ``always_changed``) and rewrites the record only when its bytes
change, so DVC re-runs ``train`` exactly when the weights' content (or path) changed. The train
stage reads the hash back for the checkpoint fingerprint: a resumed run never reads the weights.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from msdepth.errors import DataError
from msdepth.io import write_text
from msdepth.readers import file_sha256, read_json_file, read_text_file

SHA256 = re.compile(r"[0-9a-f]{64}")


def _pretrained_record(pretrained: str) -> dict[str, str | None]:
    """``{"path": pretrained, "sha256": its content's hex digest}``; ``{"path": "", "sha256": None}``
    when unset. A DataError names a file that is missing, a folder or unreadable."""
    if not pretrained:
        return {"path": "", "sha256": None}
    try:
        return {"path": pretrained, "sha256": file_sha256(pretrained, "weights")}
    except DataError as exc:
        raise DataError(f"model.pretrained: {exc}") from None


def write_record(pretrained: str, out: Path) -> bool:
    """Write ``pretrained``'s record to ``out`` unless ``out`` holds those bytes already (its mtime
    then stays too); returns whether it wrote."""
    text = json.dumps(_pretrained_record(pretrained), indent=2) + "\n"
    if out.is_file() and read_text_file(out, "pretrained record") == text:
        return False
    write_text(out, text)
    return True


def recorded_sha256(pretrained: str, record: Path) -> str | None:
    """The content hash that ``record`` holds for model.pretrained ``pretrained``; None when it is
    unset (``record`` is then not read). A DataError names a record that is missing, unreadable or
    of another path: the ``pretrained`` stage has not run since model.pretrained changed."""
    if not pretrained:
        return None
    remedy = "run `dvc repro pretrained` (it records model.pretrained's content hash)"
    try:
        if not record.exists():
            raise DataError(f"{record}: missing; {remedy}")
        data = read_json_file(record, "pretrained record")
    except DataError as exc:
        raise DataError(f"{exc}; {remedy}" if remedy not in str(exc) else str(exc)) from None
    if not isinstance(data, dict) or data.get("path") != pretrained:
        found = data.get("path") if isinstance(data, dict) else data
        raise DataError(f"{record}: records {found!r}, not model.pretrained {pretrained!r}; {remedy}")
    if not isinstance(data.get("sha256"), str) or not SHA256.fullmatch(data["sha256"]):
        raise DataError(f"{record}: no sha256 hex digest for {pretrained!r}; {remedy}")
    return data["sha256"]
