"""The DVC stages' wiring, one module per stage: where each stage reads and writes, and what it calls.

``stages/<name>.py`` (the scripts dvc.yaml runs) import only :mod:`.common` and their own module
here, so that a stage's import closure, which dvc.yaml lists as its code deps
(``tests/test_dvc_deps.py`` checks it), holds only the code the stage runs. This file imports
nothing for the same reason.
"""
