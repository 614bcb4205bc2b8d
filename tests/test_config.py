"""Hostile params files: each is refused by the ``validate_params`` stage in one line naming the key.

The cases are those of an adversarial probe (issue 27, item 9): keys YAML reads as a number, null or
boolean, an alias bomb, bytes that are not UTF-8, an integer too long to convert, a duplicate key,
and values that passed the checks but failed a later stage.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from conftest import run_script

from msdepth.config.checks import SHOWN_CHARS, shown
from msdepth.config.params import MAX_PARAMS_BYTES, load_params, params_from_dict
from msdepth.errors import ConfigError


def alias_bomb(levels: int) -> str:
    """A "billion laughs": ``levels`` lists of 9 aliases of the one before, 9**levels strings in all
    (levels=8: 490 bytes that expand to 43 million strings, echoed as a 351 MB line before)."""
    items = ['&a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    items += [f"&a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, levels)]
    return "train:\n  learning_rate:\n" + "".join(f"    - {item}\n" for item in items)


ALIAS = (
    "a YAML alias (of the value at line {}) is refused: aliases can expand without bound; write the value out"
)
SEEDS = "must be in 0..4294967295"

HOSTILE = [
    (b"1: x\n", "top level: key 1 is not a parameter name"),
    (b"data:\n  ~: x\n", "data: key None is not a parameter name"),
    (b"train:\n  true: 1\n", "train: key True is not a parameter name"),
    (b"ssim: {3: 5}\n", "ssim: key 3 is not a parameter name"),
    (b"train: {epochs: 3}\n# caf\xe9\n", "not UTF-8 text (byte 0xe9 on line 2)"),
    (
        b"train:\n  epochs: " + b"9" * 5001 + b"\n",
        "train.epochs: an integer written with 5001 characters is out of range (line 2)",
    ),
    (
        b"train: {epochs: 99999999999999999999}\n",
        "train.epochs: 99999999999999999999 is out of range (a 64-bit integer)",
    ),
    (b"compare: {seed: -5}\n", f"compare.seed: {SEEDS}, got -5"),
    (b"data: {synthetic: {seed: -1}}\n", f"data.synthetic.seed: {SEEDS}, got -1"),
    (b"train: {seeds: [4294967296]}\n", f"train.seeds: {SEEDS}, got [4294967296]"),
    (b"model: {width_multiplier: .inf}\n", "model.width_multiplier: expected a finite number, got inf"),
    (
        b"model: {width_multiplier: 8.0}\n",
        "model.width_multiplier: must be <= 4.0 (1.0 = the dissertation's network), got 8.0",
    ),
    (b"data: {height: 100000}\n", "data.height: must be <= 4096 (px), got 100000"),
    (b"data: {synthetic: {width: 100000}}\n", "data.synthetic.width: must be <= 4096 (px), got 100000"),
    (b"eval: {caps: [.inf]}\n", "eval.caps[0]: expected a finite number, got inf"),
    (b"loss: {alpha: .nan}\n", "loss.alpha: expected a finite number, got nan"),
    (b"train: {dist_timeout_s: 1.0e+300}\n", "train.dist_timeout_s: must be <= 86400 (s)"),
    (b"train:\n  epochs: 3\n  epochs: 4\n", "train.epochs: duplicate key (lines 2 and 3): keep one"),
    (b"loss: {alpha: &a 0.5, lr_weight: *a}\n", "loss.lr_weight: " + ALIAS.format(1)),
    (alias_bomb(4).encode(), "train.learning_rate[1][0]: " + ALIAS.format(3)),
    (
        b"x: &x {height: 64}\ndata:\n  <<: *x\n",
        "data: YAML merge keys (<<, line 3) are refused: write the keys out",
    ),
    (b"data: !!set {a, b}\n", "data: YAML tag 'tag:yaml.org,2002:set' is not a params value (line 1)"),
    (b"train: " + b"[" * 40 + b"\n", "not valid YAML: line 1, column 23: nested deeper than 16 levels"),
    (b"train: [1, 2\n", "not valid YAML: line 2, column 1: expected ',' or ']', but got '<stream end>'"),
    (b"? [a]\n: 1\n", "top level: a key must be a name, not a collection (line 1)"),
    (b"0\n", "params: expected a mapping at the top level"),
]


@pytest.mark.parametrize(("text", "message"), HOSTILE, ids=[repr(c[0][:24]) for c in HOSTILE])
def test_hostile_params_are_one_line_naming_the_key_at_validate_params(
    tmp_path: Path, monkeypatch, capsys, text: bytes, message: str
):
    from conftest import stage

    from msdepth.pipeline.paths import run_stage

    validate_params = stage("validate_params").validate_params

    monkeypatch.chdir(tmp_path)
    (tmp_path / "params.yaml").write_bytes(text)
    assert run_stage(validate_params) == 1
    assert capsys.readouterr().err == f"error: params.yaml: {message}\n"
    assert [p.name for p in tmp_path.iterdir()] == ["params.yaml"]


def test_a_long_value_is_echoed_cut_to_one_short_line(tmp_path: Path):
    for value in ("x" * 100_000, list(range(100_000)), {"k": [[[[1]]]] * 1000}, 10**5000):
        with pytest.raises(ConfigError) as error:
            params_from_dict({"train": {"learning_rate": value}})
        assert str(error.value).startswith("train.learning_rate: ")
        assert len(str(error.value)) < 160 and "\n" not in str(error.value)
    assert shown("abc") == "'abc'" and shown([1, 2]) == "[1, 2]"  # short values in full
    assert len(shown("x" * 1000)) == SHOWN_CHARS
    assert shown(10**5000) == "an integer of about 5001 digits"


def test_an_alias_bomb_is_refused_in_bounded_memory(tmp_path: Path):
    """In a child limited to 400 MB of address space: the 490-byte bomb took 700 MB when the
    refusal echoed the expanded value."""
    (tmp_path / "params.yaml").write_text(alias_bomb(8))
    (tmp_path / "child.py").write_text(
        "import resource\nresource.setrlimit(resource.RLIMIT_AS, (400 << 20, 400 << 20))\n"
        "from msdepth.config.params import load_params\nfrom msdepth.errors import ConfigError\n"
        "try:\n    load_params('params.yaml')\nexcept ConfigError as exc:\n    print(exc)\n"
    )
    proc = run_script(str(tmp_path / "child.py"), cwd=tmp_path)  # an absolute path stays itself
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout == f"params.yaml: train.learning_rate[1][0]: {ALIAS.format(3)}\n"


def test_unreadable_and_oversized_params_files(tmp_path: Path):
    (tmp_path / "folder.yaml").mkdir()
    with pytest.raises(ConfigError, match=r"folder\.yaml: a folder, not a file$"):
        load_params(tmp_path / "folder.yaml")
    (tmp_path / "big.yaml").write_bytes(b"#" * (MAX_PARAMS_BYTES + 1))
    with pytest.raises(ConfigError, match=r"big\.yaml: file: larger than 1 MiB: not a params file$"):
        load_params(tmp_path / "big.yaml")
    (tmp_path / "empty.yaml").write_bytes(b"# nothing set: every default\n")
    assert load_params(tmp_path / "empty.yaml") == params_from_dict({})


def test_the_new_ranges_accept_their_bounds():
    params = params_from_dict(
        {
            "data": {"height": 4096, "width": 4096, "synthetic": {"seed": 2**32 - 1, "height": 4096}},
            "model": {"width_multiplier": 4},
            "train": {"seeds": [0, 2**32 - 1], "dist_timeout_s": 86400},
            "compare": {"seed": 2**32 - 1},
        }
    )
    assert params.model.width_multiplier == 4.0 and params.compare.seed == 2**32 - 1


def test_a_variant_named_like_a_params_section_is_refused(monkeypatch):
    """msdepth.config.variants.register no longer imports the config (that made a cycle): config checks."""
    from msdepth.config import params as config
    from msdepth.config.variants.ssim import SSIMConfig

    monkeypatch.setattr(config, "variant_configs", lambda: {"ssim": SSIMConfig, "train": SSIMConfig})
    with pytest.raises(ValueError, match=r"variant\(s\) \['train'\]: the name of a params section"):
        params_from_dict({})


def test_an_exponent_without_a_dot_is_a_number() -> None:
    """Issue 68: PyYAML (YAML 1.1) reads ``3e-4`` as text, so ``train.learning_rate: 3e-4`` and
    ``--set optimum.learning_rate=1e-3`` failed with "expected a number, got '1e-3'"."""
    raw = yaml.safe_load(
        "train: {learning_rate: 3e-4}\noptimum: {learning_rate: 1E-3, smoothness_weight: +1e1}"
    )
    assert raw["train"]["learning_rate"] == "3e-4"  # the YAML 1.1 reading the conversion corrects
    params = params_from_dict(raw)
    assert params.train.learning_rate == 3e-4 and params.optimum.learning_rate == 1e-3
    assert params.optimum.smoothness_weight == 10.0
    for text in ("1e", "e-3", "1e-3x", "0x1p-3"):
        with pytest.raises(ConfigError, match="expected a number"):
            params_from_dict({"train": {"learning_rate": text}})
    with pytest.raises(ConfigError, match="expected an integer"):
        params_from_dict({"train": {"seeds": ["1e3"]}})  # integers stay strict
