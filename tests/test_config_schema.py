"""The typed config's schema against params.yaml: one source for each default, a bound on every number.

params.yaml is what the pipeline runs, and the dataclass defaults of :mod:`msdepth.config.params` are
what a run without a params file gets: the two must hold the same values (issue 54). Every int and
float field declares its :class:`~msdepth.config.checks.Range`, which validation enforces (issue 56).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path
from typing import Annotated, Any, Iterator

import pytest
from conftest import ROOT, committed_file

from msdepth.config.checks import Range, _declared_range, check_ranges
from msdepth.config.params import MAX_THREADS, Params, load_params, params_from_dict, read_params_file
from msdepth.errors import ConfigError


def sections(params: Params | None = None) -> Iterator[tuple[str, Any]]:
    """``(key, config)`` of every section of ``params`` (default: the dataclass defaults), nested
    ones and every registered variant's included."""

    def walk(key: str, config: Any) -> Iterator[tuple[str, Any]]:
        yield key, config
        for f in dataclasses.fields(config):
            value = getattr(config, f.name)
            if dataclasses.is_dataclass(value):
                yield from walk(f"{key}.{f.name}", value)

    params = Params() if params is None else params
    for f in dataclasses.fields(Params):
        if dataclasses.is_dataclass(getattr(params, f.name)):
            yield from walk(f.name, getattr(params, f.name))
    for name, config in sorted(params.appearance.items()):
        yield from walk(name, config)


def leaf_fields(config: Any) -> Iterator[dataclasses.Field]:
    """The fields of ``config`` that hold a value, not a section."""
    for f in dataclasses.fields(config):
        if f.metadata.get("yaml", True) and not dataclasses.is_dataclass(getattr(config, f.name)):
            yield f


def number_type(tp: Any) -> type | None:
    """int or float when the hint ``tp`` is a number, a list of numbers or an optional one; else None."""
    origin = typing.get_origin(tp)
    if origin is Annotated or origin is tuple:
        return number_type(typing.get_args(tp)[0])
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        return number_type(inner[0]) if len(inner) == 1 else None
    return tp if tp in (int, float) else None


def numeric_fields() -> list[tuple[str, Any, str, type, Range | None]]:
    """``(section key, section default, field name, int or float, declared range)`` of every number."""
    found = []
    for key, config in sections():
        hints = typing.get_type_hints(type(config), include_extras=True)
        for f in leaf_fields(config):
            kind = number_type(hints[f.name])
            if kind is not None:
                found.append((key, config, f.name, kind, _declared_range(hints[f.name])))
    return found


def _lookup(raw: dict, key: str) -> tuple[bool, Any]:
    """``(present, value)`` of the dotted ``key`` in the parsed params.yaml ``raw``."""
    node: Any = raw
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return False, None
        node = node[part]
    return True, node


def _committed_params(tmp_path: Path) -> Path:
    """params.yaml as committed (git's HEAD) where this is a git checkout, else the workspace's: a
    user who ran command 1 with other settings (e.g. train.threads) has not made a second default."""
    data = committed_file(ROOT, "params.yaml")
    if data is None:
        return ROOT / "params.yaml"
    path = tmp_path / "params.yaml"
    path.write_bytes(data)
    return path


def test_every_dataclass_default_is_params_yaml_s_value(tmp_path: Path):
    committed = _committed_params(tmp_path)
    raw = read_params_file(committed)
    loaded = load_params(committed)  # typed: 600 in the file is the field's 600.0
    loaded_sections = dict(sections(loaded))
    differences = []
    for key, default in sections():
        for f in leaf_fields(default):
            present, _ = _lookup(raw, f"{key}.{f.name}")
            ours, theirs = getattr(default, f.name), getattr(loaded_sections[key], f.name)
            if not present:
                differences.append(f"{key}.{f.name}: {ours!r} in the dataclass, not in params.yaml")
            elif ours != theirs:
                differences.append(f"{key}.{f.name}: {ours!r} in the dataclass, {theirs!r} in params.yaml")
    if Params().variants != loaded.variants:
        differences.append(
            f"variants: {Params().variants} in the dataclass, {loaded.variants} in params.yaml"
        )
    assert not differences, "dataclass defaults differ from params.yaml:\n" + "\n".join(differences)


def test_every_number_of_the_config_declares_a_range():
    fields = numeric_fields()
    assert len(fields) > 50  # the walk reached every section
    unbounded = [f"{key}.{name}" for key, _, name, _, bound in fields if bound is None]
    assert not unbounded, f"int/float params without a Range: {unbounded}"


def _outside(bound: Range, kind: type) -> list[float]:
    """A value just below and one just above ``bound`` (an excluded end itself)."""
    step = 1 if kind is int else max(1.0, abs(bound.high)) * 1e-3
    low = bound.low if bound.low_open else bound.low - step
    high = bound.high if bound.high_open else bound.high + step
    return [kind(low), kind(high)]


BOUNDED = [entry for entry in numeric_fields() if entry[4] is not None]


@pytest.mark.parametrize(
    ("key", "config", "name", "kind", "bound"), BOUNDED, ids=[f"{e[0]}.{e[2]}" for e in BOUNDED]
)
def test_each_range_refuses_its_outside_and_keeps_its_ends(key, config, name, kind, bound):
    is_list = isinstance(getattr(config, name), tuple)
    for value in _outside(bound, kind):
        changed = dataclasses.replace(config, **{name: (value,) if is_list else value})
        with pytest.raises(ConfigError) as error:
            check_ranges(changed, key)
        where = f"{key}.{name}[0]" if is_list else f"{key}.{name}"
        assert str(error.value).startswith(f"{where}: must be in {bound}"), str(error.value)
    ends = [end for end, open_ in ((bound.low, bound.low_open), (bound.high, bound.high_open)) if not open_]
    for value in ends:
        check_ranges(dataclasses.replace(config, **{name: (kind(value),) if is_list else kind(value)}), key)


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        (
            {"train": {"threads": 10**6}},
            f"train.threads: must be in 1..{MAX_THREADS} (4 per CPU core, at least 4)",
        ),
        ({"optimum": {"threads": 10**6}}, f"optimum.threads: must be in 1..{MAX_THREADS}"),
        (
            {"compare": {"bootstrap_samples": 10**12}},
            "compare.bootstrap_samples: must be in 100..1000000, got",
        ),
        (
            {"optimum": {"learning_rate": 1.0e308}},
            "optimum.learning_rate: must be in [1e-09, 10] (Adam's step per update), got 1e+308",
        ),
        ({"mix": {"sigma": 1.0e9}}, "mix.sigma: must be in (0, 64], got"),  # a variant not in `variants`
        ({"eval": {"caps": [80, 1.0e9]}}, "eval.caps[1]: must be in (0, 10000] (metres), got"),
    ],
)
def test_out_of_range_params_are_one_line_naming_the_key(raw: dict, message: str):
    with pytest.raises(ConfigError) as error:
        params_from_dict(raw)
    assert str(error.value).startswith(message) and "\n" not in str(error.value), str(error.value)


def test_the_committed_thread_counts_validate_on_one_core():
    """MAX_THREADS is at least 4 whatever the core count: params.yaml's 2 threads hold on one core."""
    params = load_params(ROOT / "params.yaml")
    assert max(params.train.threads, params.optimum.threads) <= 4 <= MAX_THREADS


def test_a_range_reads_as_its_message_says():
    assert str(Range(1, 64)) == "1..64"
    assert str(Range(0, 0.3, low_open=True, high_open=True)) == "(0, 0.3)"
    assert str(Range(0, 1.0)) == "[0, 1]" and str(Range(0, 10, low_open=True)) == "(0, 10]"
    assert Range(0, 1, low_open=True).holds(1) and not Range(0, 1, low_open=True).holds(0)
