"""Stage ``pretrained``: record model.pretrained's path and content hash in data/pretrained.json.

``train`` depends on the record, not on the weights file: DVC cannot list a dep whose path may be
``""`` (model.pretrained's default). The stage runs on every ``dvc repro`` (dvc.yaml:
``always_changed``; it only hashes the file) and rewrites the record only when its bytes change, so
replacing the weights under the same name re-runs ``train``, and nothing else does. Unset, the
record is a fixed one (``{"path": "", "sha256": null}``).
"""

from __future__ import annotations

import logging
import sys

from msdepth.config.params import Params
from msdepth.pipeline.paths import PRETRAINED, run_stage
from msdepth.pipeline.pretrained import write_record

log = logging.getLogger("msdepth")


def pretrained(params: Params) -> None:
    """Record model.pretrained's path and the sha256 of its content in data/pretrained.json (a
    fixed record when it is ""); the file is rewritten only when that changed."""
    written = write_record(params.model.pretrained, PRETRAINED)
    log.info(
        "pretrained: %s %s (%s)",
        PRETRAINED,
        "written" if written else "unchanged",
        params.model.pretrained or 'model.pretrained is "": from scratch',
    )


if __name__ == "__main__":
    sys.exit(run_stage(pretrained, *sys.argv[1:]))
