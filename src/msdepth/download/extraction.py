"""A verified archive unpacked, atomically and safely.

:func:`extract` unpacks into a temp folder beside the destination, moves it into place and writes a
completion marker last. A member that would replace a folder by a file (or a file by a folder) that
is already there, or a file another archive wrote, is refused. Before anything is unpacked, every
member is checked (:func:`check_members`): no path outside the destination, no dot-name at the top
(where completion markers live), no symlink or device, and the declared sizes must fit the disk and
stay within :data:`MAX_EXPANSION` times the archive (a zip bomb is refused undecompressed)."""

from __future__ import annotations

import errno
import glob
import os
import re
import shutil
import stat
import tempfile
import threading
import zipfile
import zlib
from pathlib import Path

from msdepth.download.sizes import file_size, human_size
from msdepth.errors import DataError
from msdepth.io import write_json
from msdepth.readers import read_json_file

JPEG_QUALITY = 92  # Monodepth's conversion (ImageMagick -quality 92, 4:2:0 chroma like OpenCV's)
# Declared uncompressed bytes per archive byte above which an archive is refused as a zip bomb.
# KITTI's archives are PNG images (already deflated: ~1x), velodyne float32 scans and a few text
# files: ~1-3x. Deflate itself tops out near 1030x, reached by highly repetitive data (zeros), so
# 100x leaves honest archives a 30x margin and stops the cheap bombs; the disk-space check bounds
# anything below it. zipfile never writes more than a member's declared size (it cuts the output
# there and checks the CRC), so the declared sizes are what extraction can write.
MAX_EXPANSION = 100


def completion_marker(zip_path: Path, dest_dir: Path) -> Path:
    """The marker :func:`extract` writes last, once ``zip_path`` is wholly in ``dest_dir``."""
    return dest_dir / f".{zip_path.name}.complete"


def pending_record(zip_path: Path, dest_dir: Path) -> Path:
    """The record of the files an extraction is moving into place, written before the first move
    and replaced by the completion marker after the last: a run killed midway still owns them."""
    return dest_dir / f".{zip_path.name}.pending"


def _file_owners(dest_dir: Path) -> dict[str, str]:
    """Which archive wrote each file under ``dest_dir`` (relative POSIX path -> archive name), from
    the ``files`` of its completion markers and pending records. Markers written before the list
    was kept own nothing: their files are treated as files no archive wrote."""
    owners: dict[str, str] = {}
    records = [*dest_dir.glob(".*.zip.complete"), *dest_dir.glob(".*.zip.pending")]
    for record in sorted(records):
        try:
            data = read_json_file(record, "download record")
        except DataError:
            continue  # unreadable: owns nothing, so its files are refused rather than replaced
        files = data.get("files") if isinstance(data, dict) else None
        archive = record.name[1:].rsplit(".", 1)[0]
        for name in files if isinstance(files, list) else []:
            if isinstance(name, str):
                owners.setdefault(name, archive)
    return owners


def _replacement(zip_path: Path, member: str, target: Path, owners: dict[str, str]) -> str | None:
    """Why ``member`` may not replace the existing ``target``, or None: another archive wrote it, or
    no archive did (a user's file, a folder source's); this archive's own file may be replaced."""
    owner = owners.get(member)
    if owner == zip_path.name:
        return None
    whose = f"written by {owner}" if owner else "a file no KITTI archive wrote here"
    return f"member {member!r} would replace {target} ({whose})"


def _check_replacements(zf: zipfile.ZipFile, zip_path: Path, dest_dir: Path, jpeg: bool = False) -> None:
    """Refuse, before anything is extracted, an archive whose member would replace a file under
    ``dest_dir`` that this archive did not write (:func:`_file_owners`); with ``jpeg`` the JPEG a PNG
    member becomes is checked too. :func:`_publish` checks the extracted tree again, under the lock."""
    if not dest_dir.is_dir():
        return
    owners = _file_owners(dest_dir)
    for info in zf.infolist():
        if info.is_dir():
            continue
        names = [info.filename]
        if jpeg and info.filename.lower().endswith(".png"):
            names.append(info.filename[:-4] + ".jpg")
        for name in names:
            target = dest_dir / name
            problem = target.is_file() and _replacement(zip_path, name, target, owners)
            if problem:
                raise DataError(f"{zip_path}: {problem}; refusing to extract, nothing was changed")


def check_members(zf: zipfile.ZipFile, zip_path: Path) -> int:
    """Refuse an archive with a member that must not be unpacked; return the declared total size.

    Refused: a path outside the destination (``..``, absolute, a drive letter or a leading
    backslash: zip-slip), a dot-name at the top (it could forge another archive's completion
    marker, ``.<archive>.complete``, or meet a temp folder), a symbolic link, device, fifo or
    socket (the Unix mode in the high bits of ``external_attr``), and declared sizes above
    :data:`MAX_EXPANSION` times the archive's.
    """
    total = 0
    for info in zf.infolist():
        name = info.filename
        parts = re.split(r"[\\/]", name)
        if name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name) or ".." in parts:
            raise DataError(
                f"{zip_path}: member {name!r} points outside the extraction folder; refusing to extract"
            )
        top = next((p for p in parts if p not in ("", ".")), "")  # zipfile drops "" and "." parts
        if top.startswith("."):
            raise DataError(
                f"{zip_path}: member {name!r} is a top-level dot-file (completion markers and temp "
                "folders are named so); refusing to extract"
            )
        kind = stat.S_IFMT(info.external_attr >> 16)
        if kind not in (0, stat.S_IFREG, stat.S_IFDIR):  # 0: no Unix mode (e.g. written on Windows)
            what = "a symbolic link" if kind == stat.S_IFLNK else "a device, fifo or socket"
            raise DataError(f"{zip_path}: member {name!r} is {what}; refusing to extract")
        total += info.file_size
    size = file_size(zip_path)
    if total > MAX_EXPANSION * max(size, 1):
        raise DataError(
            f"{zip_path}: members declare {human_size(total)} uncompressed, {total / max(size, 1):.0f}x the "
            f"archive's {human_size(size)} (more than {MAX_EXPANSION}x: a zip bomb?); refusing to extract"
        )
    return total


def _check_free_space(zip_path: Path, dest_dir: Path, needed: int) -> None:
    """Refuse to start an extraction that cannot fit: the declared sizes against the free space."""
    probe = dest_dir
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    free = shutil.disk_usage(probe).free
    if needed > free:
        raise DataError(
            f"{zip_path}: needs {human_size(needed)} to extract but {probe} has {human_size(free)} free; "
            "refusing to start"
        )


def _to_jpeg(root: Path, quality: int) -> None:
    """Replace every 8-bit PNG under ``root`` with a JPEG of ``quality``, as Monodepth did.

    16-bit PNGs (depth or disparity maps) are left alone: JPEG would destroy their values.
    """
    import cv2  # only needed for the optional conversion

    from msdepth.data.imagefile import decode, read_file

    for png in sorted(root.rglob("*.png")):
        try:  # the one image reader: size and header bounded before the file is read and decoded
            image = decode(read_file(png), cv2.IMREAD_UNCHANGED)
        except (OSError, DataError) as exc:
            raise DataError(f"{png}: {getattr(exc, 'strerror', None) or exc}") from None
        if image.dtype != "uint8":
            continue
        if not cv2.imwrite(str(png.with_suffix(".jpg")), image, [cv2.IMWRITE_JPEG_QUALITY, quality]):
            raise DataError(f"{png}: OpenCV could not write its JPEG")
        png.unlink()


# One extraction at a time moves its tree into place, so that the check for collisions and the
# moves see the same tree: two same-day archives finishing together both found no day folder and
# both renamed theirs there (ENOTEMPTY / EISDIR for the second, 2 of 40 trials).
_MOVE_LOCK = threading.Lock()


def _publish(zip_path: Path, tmp: Path, dest_dir: Path) -> list[str]:
    """Move the extracted tree ``tmp`` into ``dest_dir`` and return its files (relative POSIX
    paths), unless a member would replace a folder with a file or a file with a folder there, or a
    file this archive did not write (:func:`_replacement`): refused whole, before any move."""
    files = sorted(p.relative_to(tmp).as_posix() for p in tmp.rglob("*") if not p.is_dir())
    with _MOVE_LOCK:
        collision = _collision(tmp, dest_dir, tmp)
        owners = _file_owners(dest_dir)
        replaced = (
            _replacement(zip_path, f, dest_dir / f, owners) for f in files if (dest_dir / f).is_file()
        )
        problem = collision or next((r for r in replaced if r), None)
        if problem:
            raise DataError(f"{zip_path}: {problem}; refusing to extract, nothing was changed")
        write_json(pending_record(zip_path, dest_dir), {"archive": zip_path.name, "files": files})
        _move_into(tmp, dest_dir)
    return files


def _collision(src: Path, dst: Path, root: Path) -> str | None:
    """The first entry of ``src`` whose kind (file or folder) differs from what ``dst`` holds in
    its place, described from ``root``; None if there is none."""
    for entry in sorted(src.iterdir()):
        target = dst / entry.name
        if not (target.exists() or target.is_symlink()):
            continue
        member = entry.relative_to(root).as_posix()
        if entry.is_dir() and target.is_dir():
            found = _collision(entry, target, root)
            if found:
                return found
        elif entry.is_dir():
            return f"member {member!r} is a folder but {target} is a file already"
        elif target.is_dir():
            return f"member {member!r} is a file but {target} is a folder already"
    return None


def _move_into(src: Path, dst: Path) -> None:
    """Move the tree ``src`` into ``dst``: a folder new to ``dst`` appears by one atomic rename;
    one that exists already (a day folder shared by several archives) is merged into, also one
    that appeared since it was looked at. A file replaces the file of the same name (the same
    archive extracted again)."""
    for entry in sorted(src.iterdir()):
        target = dst / entry.name
        if entry.is_dir():
            if not target.is_dir() and _renamed(entry, target):
                continue
            _move_into(entry, target)
        else:
            os.replace(entry, target)


def _renamed(src: Path, dst: Path) -> bool:
    """Rename the folder ``src`` to ``dst``; False if ``dst`` is a folder with something in it."""
    try:
        os.rename(src, dst)
    except OSError as exc:
        if exc.errno in (errno.ENOTEMPTY, errno.EEXIST):
            return False
        raise
    return True


def extract(
    zip_path: str | os.PathLike,
    dest_dir: str | os.PathLike,
    *,
    jpeg: bool = False,
    jpeg_quality: int = JPEG_QUALITY,
) -> bool:
    """Unpack ``zip_path`` into ``dest_dir`` atomically; False if it was already unpacked.

    The members go to a temp folder beside the destination first (same file system, so the final
    move is a rename); the completion marker ``.<archive>.complete`` is written last, so a
    half-extracted drive is never taken as complete and is simply redone. With ``jpeg`` the PNGs
    are converted to JPEG (``jpeg_quality``) before anything is moved into place.

    Nothing at all is written (not even ``dest_dir``) for an archive that :func:`check_members`
    or :func:`_check_replacements` refuses or whose declared size exceeds the free space at
    ``dest_dir``, and nothing is moved into place for one with a member that would replace a
    folder by a file, a file by a folder, or a file this archive did not write (:func:`_publish`):
    that is another archive's, whose marker would still say complete, or the user's. The marker
    lists the files the archive wrote (:func:`_file_owners`).
    """
    zip_path, dest_dir = Path(zip_path), Path(dest_dir)
    marker = completion_marker(zip_path, dest_dir)
    if marker.exists():
        return False
    try:
        zf = zipfile.ZipFile(zip_path)
    except (zipfile.BadZipFile, OSError) as exc:
        raise DataError(f"{zip_path}: not a readable zip archive ({exc})") from None
    with zf:
        _check_free_space(zip_path, dest_dir, check_members(zf, zip_path))
        _check_replacements(zf, zip_path, dest_dir, jpeg)
        tmp = None
        try:
            dest_dir.mkdir(parents=True, exist_ok=True)
            for stale in dest_dir.glob(f".{glob.escape(zip_path.name)}.*.tmp"):
                shutil.rmtree(stale, ignore_errors=True)  # left by a killed run
            tmp = Path(tempfile.mkdtemp(prefix=f".{zip_path.name}.", suffix=".tmp", dir=dest_dir))
            members = zf.infolist()
            for info in members:
                try:
                    zf.extract(info, tmp)
                except (zipfile.BadZipFile, zlib.error, EOFError) as exc:
                    raise DataError(f"{zip_path}: member {info.filename} is corrupt ({exc})") from None
            if jpeg:
                _to_jpeg(tmp, jpeg_quality)
            files = _publish(zip_path, tmp, dest_dir)
            record = {"archive": zip_path.name, "members": len(members), "jpeg": jpeg, "files": files}
            write_json(marker, record)
            pending_record(zip_path, dest_dir).unlink(missing_ok=True)
        except OSError as exc:  # disk full, permissions: name the archive, not just a member path
            raise DataError(f"{zip_path}: extraction into {dest_dir} failed ({exc})") from None
        finally:
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)
    return True
