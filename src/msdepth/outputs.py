"""The output policy: every command that writes into a user's folder (predict, optimum, export-onnx,
export-folder, the studies) claims each output path through an :class:`OutputPolicy` before writing
it. It decides what the command may write there: never an input, and no existing file it did not
write itself (its manifest lists those it did). The files themselves are written by
:mod:`msdepth.io`'s atomic writers, whose renames the policy records (:func:`msdepth.io.on_written`).
"""

from __future__ import annotations

import atexit
import json
import os
import stat
import sys
import threading
from pathlib import Path, PurePosixPath

from msdepth.errors import DataError, MsdepthError, OutputError
from msdepth.io import atomic_path, atomic_temps, on_written, temp_final_name
from msdepth.readers import read_bounded

MANIFEST_PREFIX = ".msdepth-"  # the manifest of command C is "<output folder>/.msdepth-C"
# A manifest lists file names, one a line: ~40 bytes each, so this is over a million outputs, read
# whole in well under a second; anything larger is not a manifest the policy wrote.
MAX_MANIFEST_BYTES = 64 << 20


def _manifest_line(name: str) -> str:
    """One manifest line for ``name``, a file the command wrote completely: a JSON string in ASCII,
    so any character of a file name (a newline, U+2028, a byte that is not UTF-8 as Python's
    surrogate escape) stays on its one line."""
    return json.dumps(name, ensure_ascii=True) + "\n"


def _pending_line(name: str) -> str:
    """The manifest line of ``name`` claimed and not yet written: ``{"pending": name}``. Never
    trusted as the command's own file (a run killed before writing it leaves it), it only lets the
    next run remove that write's temp file; the end of the run drops it (:meth:`OutputPolicy.settle`)."""
    return json.dumps({"pending": name}, ensure_ascii=True) + "\n"


def _manifest_bytes(path: Path) -> bytes | None:
    """The manifest's bytes (None if there is none), read only from a regular file of bounded size
    and never through a symbolic link (:func:`read_bounded`)."""
    if not os.path.lexists(path):
        return None
    try:
        return read_bounded(
            path, "output manifest", MAX_MANIFEST_BYTES, allow_empty=True, follow_symlinks=False
        )
    except DataError as exc:  # an output-policy refusal: the file is in the way, not bad input
        raise OutputError(f"{exc}; it is not a manifest msdepth wrote: remove it") from None


def _manifest_entry(line: str) -> tuple[str, bool] | None:
    """``(name, written)`` of one manifest line, None if it is not one."""
    if line[0] in '"{':
        try:
            value = json.loads(line)
        except (ValueError, RecursionError):
            return None
        if isinstance(value, str):
            name, written = value, True
        elif isinstance(value, dict) and list(value) == ["pending"] and isinstance(value["pending"], str):
            name, written = value["pending"], False
        else:
            return None
    else:  # a plain line: a name as the manifests of earlier versions wrote it
        name, written = line, True
    relative = PurePosixPath(name)
    if not name or "\x00" in name or relative.is_absolute() or ".." in relative.parts:
        return None
    return name, written


def _manifest_entries(path: str | os.PathLike) -> list[tuple[str, bool]]:
    """``(name, written)`` per manifest line, in file order (split on ``\\n`` only); a missing
    manifest has none. OutputError (one line) for a manifest that is a symlink, not a regular file,
    too large, or has a line that is not a manifest line (:func:`_manifest_line`, :func:`_pending_line`
    or a plain name), so a file put there is never taken for a list of the command's own files."""
    return _parse_manifest(Path(path), _manifest_bytes(Path(path)) or b"")


def _parse_manifest(path: Path, data: bytes) -> list[tuple[str, bool]]:
    entries = []
    for number, raw in enumerate(data.split(b"\n"), 1):
        if raw:
            entry = _manifest_entry(raw.decode("utf-8", errors="surrogateescape"))
            if entry is None:
                raise OutputError(f"{path}: line {number} is not an output manifest line; remove the file")
            entries.append(entry)
    return entries


def _read_manifest(path: str | os.PathLike) -> set[str]:
    """The names a manifest lists as written (not those only pending); see :func:`_manifest_entries`."""
    return {name for name, written in _manifest_entries(path) if written}


def resolved(path: str | os.PathLike) -> Path:
    """``Path(path).resolve()``; OutputError (one line) for a symlink loop in it (a RuntimeError, or
    an OSError on newer Pythons, from resolve)."""
    try:
        return Path(path).resolve()
    except (RuntimeError, OSError) as exc:
        raise OutputError(f"{path}: a symbolic link loop in this path ({exc})") from None


def _nearest_existing(path: Path) -> Path:
    while not path.exists() and path.parent != path:
        path = path.parent
    return path


# Names claimed and not yet written, by resolved path: atomic_path records each in its policy's
# manifest once it is renamed into place. _LIVE: the policies whose run has not been settled.
_LOCK = threading.Lock()
_AWAITED: dict[Path, tuple["OutputPolicy", str]] = {}
_LIVE: dict[int, "OutputPolicy"] = {}


def _written(path: Path) -> None:
    """Record ``path``, just renamed into place, in the manifest of the policy that claimed it."""
    if not _AWAITED:
        return
    try:
        key = Path(path).resolve()
    except (RuntimeError, OSError):
        return
    with _LOCK:
        entry = _AWAITED.pop(key, None)
    if entry is not None:
        entry[0]._record(entry[1])


def settle_outputs() -> None:
    """Settle every policy of this process (:meth:`OutputPolicy.settle`); run at exit. An error is
    one line on stderr: the run's outputs are written, only the manifest keeps pending lines."""
    for policy in list(_LIVE.values()):
        try:
            policy.settle()
        except (MsdepthError, OSError) as exc:
            print(f"error: {exc}", file=sys.stderr)


atexit.register(settle_outputs)
on_written(_written)


class OutputPolicy:
    """What ``msdepth <command>`` may write under ``out_dir``: never an input, the model or the
    manifest, no existing file the command did not write itself (those it wrote are listed in
    ``out_dir/.msdepth-<command>``), and no path twice in one run (two inputs, one output).

    The manifest lists a name only once its file is complete: a claim records it as pending, the
    rename of :func:`atomic_path` as written, and :meth:`settle` (at the end of the run) drops the
    pending ones never written and the names whose files are gone. ``inputs``: files never to
    replace; ``input_dirs``: folders the output folder may not be or hold. Raises OutputError (one
    line) when ``out_dir`` is the filesystem root, an input folder, holds one or is not a folder, or
    its manifest is not one.
    """

    def __init__(
        self,
        out_dir: str | os.PathLike,
        command: str,
        inputs: tuple[str | os.PathLike, ...] = (),
        input_dirs: tuple[str | os.PathLike, ...] = (),
    ) -> None:
        self.out_dir, self.command = Path(out_dir), command
        self.manifest = self.out_dir / f"{MANIFEST_PREFIX}{command}"
        self.protected = {resolved(p): Path(p) for p in inputs}
        self.claimed: dict[Path, str] = {}  # resolved output -> the input it is the output of
        self.pending: dict[str, Path] = {}  # name -> resolved path, claimed and not yet written
        self.created = False  # whether this run created the manifest
        _check_output_folder(self.out_dir)
        out_resolved = resolved(self.out_dir)
        self._check_folder(out_resolved, input_dirs)
        entries = _manifest_entries(self.manifest)
        self.ours = {name for name, written in entries if written}
        # A run killed mid-write left the temp of an output it had listed (written or pending):
        # remove those only.
        self._remove_temps({name for name, _ in entries}, out_resolved)

    def _check_folder(self, out_resolved: Path, input_dirs: tuple[str | os.PathLike, ...]) -> None:
        """OutputError (one line) when the output folder is the filesystem root, an input folder or
        a folder holding one: checked before any input is listed, so that ``--out /`` is refused at
        once (its inputs, all inside it, were left out as outputs: "no images", after the listing)."""
        if out_resolved == Path(out_resolved.anchor):
            raise OutputError(
                f"{self.out_dir}: the filesystem root, not an output folder; choose a folder for the outputs"
            )
        for folder in input_dirs:
            if not Path(folder).is_dir():
                continue
            folder_resolved = resolved(folder)
            if out_resolved == folder_resolved:
                raise OutputError(
                    f"{self.out_dir}: the output folder is the input folder {folder}, whose files the "
                    "outputs could replace and a later run would read as inputs; choose another output folder"
                )
            if folder_resolved.is_relative_to(out_resolved):
                raise OutputError(
                    f"{self.out_dir}: the output folder holds the input folder {folder}, whose files would "
                    "be left out as outputs; choose an output folder outside it"
                )

    def _name(self, path: Path) -> str:
        return path.relative_to(self.out_dir).as_posix()

    def _remove_temps(self, names: set[str], out_resolved: Path) -> None:
        """Remove the temps (:func:`atomic_temps`) of ``names``, listing only the folders that hold them."""
        folders: dict[Path, set[str]] = {}
        for name in names:
            path = self.out_dir / name
            folders.setdefault(path.parent, set()).add(path.name)
        for folder, finals in folders.items():
            try:
                if not folder.is_dir() or not folder.resolve().is_relative_to(out_resolved):
                    continue
                temps = [p for p in folder.iterdir() if temp_final_name(p.name) in finals]
            except (RuntimeError, OSError):
                continue
            for p in temps:
                if p.is_file() and not p.is_symlink():
                    p.unlink(missing_ok=True)

    def protect(self, inputs: list[Path]) -> None:
        """Add input files that no output may replace."""
        self.protected.update((resolved(p), Path(p)) for p in inputs)

    def prepare(self) -> None:
        """Create the output folder; OutputError (one line) if it cannot be created or written."""
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(
                f"{self.out_dir}: cannot create the output folder ({exc.strerror or exc})"
            ) from None
        if not os.access(self.out_dir, os.W_OK | os.X_OK):
            raise OutputError(f"{self.out_dir}: the output folder is not writable")

    def claim(self, paths: list[Path], source: str | os.PathLike) -> None:
        """Check that every path, an output of ``source``, may be written, and list the new ones in
        the manifest as pending (each is listed as written once :func:`atomic_path` renames it into
        place); OutputError naming the first that may not, with nothing written."""
        paths = [Path(p) for p in paths]
        for path in paths:
            self._check(path, str(source))
        new = {}
        for path in paths:
            key, name = resolved(path), self._name(path)
            self.claimed[key] = str(source)
            if name not in self.ours and name not in self.pending:
                new[name] = key
        if new:
            self.prepare()
            self._append("".join(_pending_line(name) for name in new))
            with _LOCK:
                self.pending.update(new)
                _AWAITED.update((key, (self, name)) for name, key in new.items())
        _LIVE[id(self)] = self  # settled at the end of the run (settle_outputs)

    def _append(self, text: str) -> None:
        """Append ``text`` to the manifest, a regular file (never through a symlink)."""
        flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK
        existed = os.path.lexists(self.manifest)
        try:
            fd = os.open(self.manifest, flags, 0o666)
        except OSError as exc:
            raise OutputError(
                f"{self.manifest}: cannot write this output manifest ({exc.strerror or exc})"
            ) from None
        with os.fdopen(fd, "ab") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                raise OutputError(f"{self.manifest}: the output manifest is not a regular file; remove it")
            f.write(text.encode("ascii"))
        self.created = self.created or not existed

    def _record(self, name: str) -> None:
        """List ``name``, now written completely, as the command's own."""
        with _LOCK:
            if self.pending.pop(name, None) is None:
                return
        self.ours.add(name)
        try:
            self._append(_manifest_line(name))
        except OutputError:  # settle() records it by its file, which exists
            self.pending[name] = resolved(self.out_dir / name)

    def settle(self) -> None:
        """End the run's record: a pending name whose file now exists (one a subprocess wrote) is
        listed as written, the others are dropped, and so are names whose files are gone; the
        manifest is rewritten with one line per name, in the order they were first claimed."""
        with _LOCK:
            pending, self.pending = self.pending, {}
            for key in pending.values():
                if _AWAITED.get(key, (None,))[0] is self:
                    del _AWAITED[key]
            _LIVE.pop(id(self), None)
        data = _manifest_bytes(self.manifest)
        if data is None:  # never created, or the folder is gone
            return
        entries = _parse_manifest(self.manifest, data)  # read again: another policy may share it
        written = {name for name, ok in entries if ok} | set(pending)
        # Claim order; a pending line another policy's settle dropped meanwhile goes last.
        names = [n for n in dict.fromkeys([*(n for n, _ in entries), *pending]) if n in written]
        text = "".join(_manifest_line(n) for n in names if os.path.lexists(self.out_dir / n))
        if not text and self.created:
            self.manifest.unlink()
        elif text.encode("ascii") != data:
            with atomic_path(self.manifest) as tmp:
                tmp.write_text(text, encoding="ascii")

    def _check(self, path: Path, source: str) -> None:
        key = resolved(path)
        if key in self.protected:
            raise OutputError(f"{path}: an output would replace the input {self.protected[key]}")
        if key == resolved(self.manifest) or not key.parent.is_relative_to(resolved(self.out_dir)):
            raise OutputError(f"{path}: not a path msdepth {self.command} may write (outside {self.out_dir})")
        if key in self.claimed and self.claimed[key] != source:
            raise OutputError(f"{source}: same output name as {self.claimed[key]} ({path}); rename one")
        if path.is_dir():
            raise OutputError(f"{path}: a folder where msdepth {self.command} writes a file")
        name = self._name(path)
        if (path.exists() or path.is_symlink()) and name not in self.ours and name not in self.pending:
            raise OutputError(
                f"{path}: exists and was not written by msdepth {self.command} (not listed in "
                f"{self.manifest}); move it or choose another --out"
            )


def _check_output_folder(out_dir: str | os.PathLike) -> None:
    """OutputError (one line) when ``out_dir`` exists and is not a folder, or lies under a file."""
    out_dir = Path(out_dir)
    existing = _nearest_existing(out_dir)
    if existing == out_dir and not out_dir.is_dir():
        raise OutputError(f"{out_dir}: exists and is not a folder; the output must be a folder")
    if existing != out_dir and not existing.is_dir():
        raise OutputError(f"{out_dir}: cannot create the output folder under the file {existing}")


def output_file_policy(
    out: str | os.PathLike, command: str, inputs: tuple[str | os.PathLike, ...] = ()
) -> OutputPolicy:
    """The policy of a command that writes the one file ``out`` (export-onnx), ``out`` checked (claim
    it before writing): OutputError (one line) if ``out`` is a folder, an input, or a file the
    command did not write."""
    out = Path(out)
    if any(resolved(out) == resolved(p) for p in inputs):  # before "a folder": an input folder is an input
        raise OutputError(f"{out}: an input; --out names the file to write")
    if out.is_dir():
        raise OutputError(f"{out}: a folder; --out names the file to write")
    policy = OutputPolicy(out.parent, command, inputs)
    policy._check(out, str(inputs[0]) if inputs else str(out))
    policy.prepare()
    for stale in atomic_temps(out):  # left by a writer of ``out`` killed mid-write (only that form)
        stale.unlink()
    return policy


def claim_output_file(out: str | os.PathLike | None, command: str, source: str | os.PathLike) -> bool:
    """Claim the one file ``out`` that a study writes, before its minutes of work: True when ``out``
    is None or may be written (listed in the folder's manifest); False after one line on stderr when
    it may not (a folder, an input, or a file the command did not write), for the caller to exit 1."""
    if out is None:
        return True
    try:
        output_file_policy(out, command).claim([Path(out)], source)
    except OutputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return False
    return True
