"""``params.yaml`` read as plain data, refusing what a params file never needs (stdlib and PyYAML only).

:func:`parse` is ``yaml.safe_load`` with bounds: no aliases (a few hundred bytes of nested aliases
expand to gigabytes: "billion laughs") nor merge keys (``<<``), no duplicate key (YAML would keep
the last one silently), no integer too long to convert, no nesting deeper than :data:`MAX_DEPTH`
and no collection tags (``!!set``, ``!!omap``). Every refusal is one ConfigError naming the key,
or the line and column where there is no key yet. Types and ranges are checked afterwards, by
:mod:`msdepth.config.params`.
"""

from __future__ import annotations

import os
from typing import Any

import yaml

from msdepth.config.checks import SHOWN_CHARS, check, shown
from msdepth.errors import ConfigError, DataError
from msdepth.readers import read_bounded

MAX_DEPTH = 16  # params.yaml nests 3 levels (data.kitti.drives[0]); deeper is not a params file
MAX_INT_CHARS = 32  # any params integer fits 64 bits (19 digits); Python refuses over 4300 digits
# A data set's small YAML files (a stereo folder's camera and classes files) hold a few numbers and
# names: anything this large is not one of them.
MAX_DATA_FILE_BYTES = 64 * 1024

_PLAIN_TAGS = {"tag:yaml.org,2002:map", "tag:yaml.org,2002:seq"}


class _BoundedLoader(yaml.SafeLoader):
    """SafeLoader whose composer stops at :data:`MAX_DEPTH` levels (it recurses per level)."""

    depth = 0

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node:
        self.depth += 1
        try:
            if self.depth > MAX_DEPTH:
                mark = self.peek_event().start_mark
                raise yaml.composer.ComposerError(None, None, f"nested deeper than {MAX_DEPTH} levels", mark)
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1


def _one_line(exc: yaml.YAMLError) -> str:
    """A YAML error as one line: where (line, column) and what, without the source excerpt."""
    if isinstance(exc, yaml.MarkedYAMLError) and exc.problem_mark is not None:
        mark = exc.problem_mark
        what = " ".join(str(exc.problem or exc.context).split())
        return f"line {mark.line + 1}, column {mark.column + 1}: {what[:200]}"
    return " ".join(str(exc).split())[:300]


def parse(text: str) -> Any:
    """The data of YAML ``text`` (mappings, lists and scalars), or a ConfigError (one line)."""
    try:
        # the reader checks the characters when it is built: a control character raises there
        loader = _BoundedLoader(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"not valid YAML: {_one_line(exc)}") from None
    try:
        node = loader.get_single_node()
        return None if node is None else _Builder(loader).build(node, "")
    except yaml.YAMLError as exc:
        raise ConfigError(f"not valid YAML: {_one_line(exc)}") from None
    finally:
        loader.dispose()


def read_data_file(path: str | os.PathLike, what: str, missing: str) -> Any:
    """The data of a data set's small YAML file ``path`` (:func:`parse`'s bounds, at most
    :data:`MAX_DATA_FILE_BYTES`), or one DataError naming it: ``what`` it is (``camera file``),
    ``missing`` what to say when it does not exist."""
    if not os.path.lexists(path):
        raise DataError(f"{path}: {missing}")
    data = read_bounded(path, what.removesuffix(" file"), MAX_DATA_FILE_BYTES, allow_empty=True)
    try:
        return parse(data.decode("utf-8"))
    except (UnicodeDecodeError, ConfigError) as exc:
        raise DataError(f"{path}: not a readable YAML {what} ({' '.join(str(exc).split())})") from None


class _Builder:
    """Builds the data of a composed node tree, refusing aliases, duplicate keys and long integers."""

    def __init__(self, loader: yaml.SafeLoader) -> None:
        self.loader = loader
        self.seen: set[int] = set()  # ids of the nodes built: a node met twice is an alias

    def build(self, node: yaml.Node, key: str) -> Any:
        where = key or "top level"
        line = f"line {node.start_mark.line + 1}"
        check(
            id(node) not in self.seen,
            where,
            f"a YAML alias (of the value at {line}) is refused: aliases can expand without bound; "
            "write the value out",
        )
        self.seen.add(id(node))
        if isinstance(node, yaml.ScalarNode):
            check(
                node.tag != "tag:yaml.org,2002:int" or len(node.value) <= MAX_INT_CHARS,
                where,
                f"an integer written with {len(node.value)} characters is out of range ({line})",
            )
            return self.loader.construct_object(node, deep=True)
        check(node.tag in _PLAIN_TAGS, where, f"YAML tag {shown(node.tag)} is not a params value ({line})")
        if isinstance(node, yaml.SequenceNode):
            return [self.build(item, f"{key}[{i}]") for i, item in enumerate(node.value)]
        return self._mapping(node, key)

    def _mapping(self, node: yaml.MappingNode, key: str) -> dict:
        data: dict = {}
        lines: dict = {}  # key -> its line
        for key_node, value_node in node.value:
            line = key_node.start_mark.line + 1
            where = key or "top level"
            check(
                isinstance(key_node, yaml.ScalarNode),
                where,
                f"a key must be a name, not a collection (line {line})",
            )
            merge = key_node.tag == "tag:yaml.org,2002:merge"
            check(not merge, where, f"YAML merge keys (<<, line {line}) are refused: write the keys out")
            name = self.build(key_node, where)
            # A key that is not a string (1, ~, true) is refused by msdepth.config.params, naming it.
            label = name if isinstance(name, str) and len(name) <= SHOWN_CHARS else shown(name)
            path = (f"{key}." if key else "") + label
            check(name not in lines, path, f"duplicate key (lines {lines.get(name)} and {line}): keep one")
            lines[name] = line
            data[name] = self.build(value_node, path)
        return data
