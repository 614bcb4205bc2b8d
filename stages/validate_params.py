"""Stage ``validate_params``: check the whole params.yaml before any stage that could delete outputs.

DVC removes a stage's outputs just before it runs the stage, so a bad value caught by that stage
would cost its results. This stage reads every key (dvc.yaml: ``params: - params.yaml:``), so any
change to params.yaml re-runs it first, and every other stage depends on its output: a bad value
or an unknown key stops ``dvc repro`` here, before anything else runs or is removed.
"""

from __future__ import annotations

import sys

from msdepth.config.params import Params
from msdepth.pipeline.paths import CHECKED, run_stage, write_checked


def validate_params(params: Params) -> None:
    """Validate params.yaml (types, ranges, unknown keys) and write data/params_checked.txt.

    The checks are msdepth.config.params.load_params's, done on loading: an error is one line naming
    the key, and then nothing is written.
    """
    write_checked(CHECKED)


if __name__ == "__main__":
    sys.exit(run_stage(validate_params, *sys.argv[1:]))
