"""Stage ``fingerprints``: write data/fingerprints/<x>.txt, what each stage script's code does.

Every other stage depends on its script's fingerprint instead of its source files: the sha256 of
each file's syntax tree without docstrings (msdepth.pipeline.fingerprints), so a comment, a
docstring or a reformatting reruns nothing, and any change to what the code does reruns exactly
the stages that run it. The stage runs on every ``dvc repro`` (dvc.yaml: ``always_changed``; it
only parses the sources) and rewrites a file only when its bytes change. It reads no params.
"""

from __future__ import annotations

import sys

from msdepth.errors import run_main
from msdepth.pipeline.fingerprints import main

if __name__ == "__main__":
    # run_main, not run_stage: this stage runs before validate_params and reads no params.
    sys.exit(run_main("stages/fingerprints.py", lambda: main(sys.argv[1:], prog="stages/fingerprints.py")))
