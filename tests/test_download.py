"""KITTI download engine against a local HTTP server that misbehaves on purpose.

The server (127.0.0.1, port 0, one thread per request) serves small zips built here in KITTI's
raw layout and logs, per request, the Range asked for and the bytes it actually sent, so the
tests can prove a resume fetched only the rest of the file. No test touches the internet.
"""

from __future__ import annotations

import dataclasses
import email.message
import hashlib
import io as stdio
import json
import os
import re
import shutil
import socket
import stat
import struct
import threading
import time
import urllib.request
import zipfile
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import run_script

from msdepth import io as dl_io
from msdepth.config.params import Params, params_from_dict
from msdepth.download import extraction, fetching, lists, sizes, transfer, verification
from msdepth.errors import DataError

SHIPPED_LIST = Path(__file__).resolve().parents[1] / "data_lists" / "kitti_archives_to_download.txt"
# The local server speaks plain http, which the downloader refuses unless told otherwise.
FAST = transfer.FetchOptions(retries=3, backoff=0.01, timeout=5, progress=False, allow_http=True)
DRY = dataclasses.replace(FAST, dry_run=True)


def drive_zip(date: str, drive: int, frames: int = 3, seed: int = 0) -> bytes:
    """A fake synced drive in KITTI's raw layout (stored, random PNGs: ~30 KB, incompressible)."""
    rng = np.random.default_rng(seed)
    sync = f"{date}_drive_{drive:04d}_sync"
    buf = stdio.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as zf:
        for camera in ("image_02", "image_03"):
            for i in range(frames):
                ok, png = cv2.imencode(".png", rng.integers(0, 256, (24, 40, 3), dtype=np.uint8))
                assert ok
                zf.writestr(f"{date}/{sync}/{camera}/data/{i:010d}.png", png.tobytes())
            zf.writestr(f"{date}/{sync}/{camera}/timestamps.txt", "2011-09-26 13:02:25.964389445\n" * frames)
    return buf.getvalue()


def calib_zip(date: str) -> bytes:
    buf = stdio.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr(
            f"{date}/calib_cam_to_cam.txt", "P_rect_02: 721.5 0 609.6 44.9 0 721.5 172.9 0.2 0 0 1 0.003\n"
        )
    return buf.getvalue()


class _Handler(BaseHTTPRequestHandler):
    server: "_Server"

    def log_message(self, *args) -> None:  # keep pytest output clean
        pass

    def do_HEAD(self) -> None:
        self._serve(head=True)

    def do_GET(self) -> None:
        self._serve(head=False)

    def _serve(self, head: bool) -> None:
        srv = self.server
        name = self.path.rsplit("/", 1)[-1]
        entry = {"name": name, "method": self.command, "range": self.headers.get("Range"), "sent": 0}
        entry["done"] = threading.Event()
        with srv.lock:
            earlier_gets = sum(e["name"] == name and e["method"] == "GET" for e in srv.log)
            srv.log.append(entry)
        try:
            self._answer(head, entry, first=earlier_gets == 0)
        finally:
            # The client may hold every byte before this thread records "sent": gets() waits.
            entry["done"].set()

    def _answer(self, head: bool, entry: dict, first: bool) -> None:
        srv, name = self.server, entry["name"]
        mode = srv.modes.get(name, "normal")
        if name in srv.redirects:
            self.send_response(302)
            self.send_header("Location", srv.redirects[name])
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        if name not in srv.files or mode == "404":
            self.send_error(404)
            return
        if mode == "always_500" or (mode == "503_once" and first and not head):
            self.send_error(500 if mode == "always_500" else 503)
            return
        data = srv.files[name]
        start = 0
        match = re.fullmatch(r"bytes=(\d+)-", entry["range"] or "")
        if match and mode != "no_range":
            start = int(match.group(1))
            if start >= len(data):
                self.send_response(416)
                self.send_header("Content-Range", f"bytes */{len(data)}")
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
        body = data[start:]
        self.send_response(206 if start else 200)
        length = _LENGTHS.get(mode, lambda body, head: str(len(body)))(body, head)
        if length is not None:
            self.send_header("Content-Length", length)
        if start:
            self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
        if mode != "no_range":
            self.send_header("Accept-Ranges", "bytes")
        self.end_headers()
        if head:
            return
        if (mode in ("reset_once", "truncate_once", "stall_once") and first) or mode == "always_reset":
            self._cut(mode, body, entry)
        elif mode in ("drip", "overlong"):
            self._misbehave(mode, body, entry)
        else:
            self.wfile.write(body)
            entry["sent"] = len(body)

    def _cut(self, mode: str, body: bytes, entry: dict) -> None:
        """Half the body (none for "always_reset"), then a reset, a clean close or a stall."""
        half = 0 if mode == "always_reset" else len(body) // 2
        self.wfile.write(body[:half])
        entry["sent"] = half
        # Let the client take in what was sent before the connection dies; "stall" outlasts
        # the client's read timeout.
        time.sleep(1.0 if mode == "stall_once" else 0.1)
        if mode not in ("truncate_once", "stall_once"):
            # Linger 0: close() sends a TCP RST ("connection reset by peer"), not a clean FIN.
            self.connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            self.connection.close()
        self.close_connection = True

    def _misbehave(self, mode: str, body: bytes, entry: dict) -> None:
        """ "drip": one byte every 10 ms; "overlong": the body, then 4 MiB more than HEAD said."""
        if mode == "drip":
            for i in range(len(body)):
                self.wfile.write(body[i : i + 1])
                self.wfile.flush()
                entry["sent"] = i + 1
                time.sleep(0.01)
            return
        self.wfile.write(body)
        for _ in range(64):
            self.wfile.write(bytes(1 << 16))
            entry["sent"] += 1 << 16


# Content-Length per mode (None: no header): a number that is no byte count, none at all, or a
# GET streamed without one after a HEAD that declared the size.
_LENGTHS = {
    "bad_length": lambda body, head: "\u00b2",
    "no_length": lambda body, head: None,
    "overlong": lambda body, head: str(len(body)) if head else None,
}


class _Server(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self) -> None:
        super().__init__(("127.0.0.1", 0), _Handler)
        self.files: dict[str, bytes] = {}
        self.modes: dict[str, str] = {}
        self.redirects: dict[str, str] = {}  # name -> Location of a 302
        self.log: list[dict] = []
        self.lock = threading.Lock()

    def handle_error(self, request, client_address) -> None:  # the aborted sockets are on purpose
        pass

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.server_address[1]}/avg-kitti/"

    def url(self, name: str) -> str:
        return self.base_url + "raw_data/" + name

    def gets(self, name: str) -> list[dict]:
        """The GETs of `name`, once each handler has finished (and so recorded what it sent)."""
        found = [e for e in self.log if e["name"] == name and e["method"] == "GET"]
        assert all(e["done"].wait(10) for e in found), "a handler did not finish in 10 s"
        return found


@pytest.fixture
def server():
    srv = _Server()
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield srv
    srv.shutdown()
    srv.server_close()


DRIVE = "2011_09_26_drive_0001_sync.zip"


def _serve_drive(server: _Server, mode: str = "normal", name: str = DRIVE, seed: int = 0) -> bytes:
    data = drive_zip(name[:10], int(name[17:21]), seed=seed)
    server.files[name], server.modes[name] = data, mode
    return data


# --------------------------------------------------------------------------- lists


def test_shipped_list_parses_to_66_relative_archive_paths() -> None:
    names = lists.parse_archive_list(SHIPPED_LIST)
    assert len(names) == 66
    assert all(n.startswith("raw_data/") and n.endswith(".zip") for n in names)
    files = [lists.archive_filename(n) for n in names]
    assert sum(f.endswith("_calib.zip") for f in files) == 5
    assert sum(f.endswith("_sync.zip") for f in files) == 61
    assert names[1] == "raw_data/2011_09_26_drive_0001/2011_09_26_drive_0001_sync.zip"


def test_bad_list_content_names_the_file_and_line(tmp_path: Path) -> None:
    good = tmp_path / "ok.txt"
    good.write_text("# a comment\n\nraw_data/2011_09_26_calib.zip\n  https://example.org/x/y.zip  \n")
    assert lists.parse_archive_list(good) == ["raw_data/2011_09_26_calib.zip", "https://example.org/x/y.zip"]
    for text, pattern in [
        ("raw_data/a.zip\nnot an archive.tar\n", r"bad\.txt:2: expected one URL"),
        ("raw_data/a.zip\nother/a.zip\n", r"bad\.txt:2: archive a\.zip is listed twice"),
        ("# only comments\n\n", r"bad\.txt: no archives listed"),
    ]:
        bad = tmp_path / "bad.txt"
        bad.write_text(text)
        with pytest.raises(DataError, match=pattern):
            lists.parse_archive_list(bad)
    with pytest.raises(DataError, match="missing.txt: no such archive list file"):
        lists.parse_archive_list(tmp_path / "missing.txt")


def test_unknown_url_scheme_is_a_data_error_naming_the_url(tmp_path: Path) -> None:
    for url in ("ftp-ish://x/a.zip", "raw_data/a.zip", "file:///etc/passwd", "ftp://x/a.zip"):
        refused = re.escape(url) + r": not an https URL \(or http\); refusing to fetch it"
        with pytest.raises(DataError, match=refused):
            transfer.download(url, tmp_path / "a.zip", FAST)
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- https only


def test_plain_http_is_refused_without_allow_http(server: _Server, tmp_path: Path, capsys) -> None:
    """Nothing is requested and nothing written: not by download, fetch_all, its dry run or HEAD."""
    _serve_drive(server)
    strict = dataclasses.replace(FAST, allow_http=False)
    refused = re.escape(server.url(DRIVE)) + r": plain http is refused .*data\.kitti\.allow_http: true"
    with pytest.raises(DataError, match=refused):
        transfer.download(server.url(DRIVE), tmp_path / "zips" / DRIVE, strict)
    with pytest.raises(DataError, match=refused):
        transfer.remote_size(server.url(DRIVE), strict)
    zips, raw = tmp_path / "zips", tmp_path / "raw"
    for dry_run in (False, True):
        with pytest.raises(DataError, match=refused):
            options = dataclasses.replace(strict, dry_run=dry_run)
            fetching.fetch_all(server.base_url, [f"raw_data/{DRIVE}"], zips, raw, options)
    # An https base does not let an absolute http entry of the list through either.
    with pytest.raises(DataError, match=refused):
        fetching.fetch_all("https://example.org/", [server.url(DRIVE)], zips, raw, strict)
    assert server.log == [] and list(tmp_path.iterdir()) == []
    assert transfer.download(server.url(DRIVE), tmp_path / DRIVE, FAST).exists()  # allowed: fetched


def test_base_url_scheme_is_checked_with_the_config(tmp_path: Path) -> None:
    from msdepth.config.params import params_from_dict
    from msdepth.errors import ConfigError

    def kitti(**keys):
        return params_from_dict({"data": {"kitti": keys}}).data.kitti

    assert kitti().base_url.startswith("https://") and kitti().allow_http is False
    plain = r"data\.kitti\.base_url: plain http is refused unless data\.kitti\.allow_http"
    with pytest.raises(ConfigError, match=plain):
        kitti(base_url="http://mirror.local/kitti/")
    assert kitti(base_url="http://mirror.local/kitti/", allow_http=True).allow_http is True
    with pytest.raises(ConfigError, match=r"data\.kitti\.base_url: must be an https URL, got 'ftp://x/'"):
        kitti(base_url="ftp://x/", allow_http=True)
    with pytest.raises(ConfigError, match=r"data\.kitti\.allow_http: expected true/false"):
        kitti(allow_http="yes")


def _redirect(handler: transfer.NoDowngradeRedirect, old: str, new: str):
    fp = stdio.BytesIO(b"")
    headers = email.message.Message()
    headers["Location"] = new
    return handler.redirect_request(urllib.request.Request(old), fp, 302, "Found", headers, new), fp


def test_redirect_from_https_to_http_is_refused() -> None:
    handler = transfer.NoDowngradeRedirect()
    refused = (
        "https://a.org/x.zip: redirected to http://b.org/x.zip, which is not https; refusing the downgrade"
    )
    with pytest.raises(DataError, match=re.escape(refused)):
        _redirect(handler, "https://a.org/x.zip", "http://b.org/x.zip")
    allowed = [
        ("https://a.org/x.zip", "https://cdn.b.org/x.zip"),
        ("http://a.org/x.zip", "http://b.org/x.zip"),
        ("http://a.org/x.zip", "https://b.org/x.zip"),
    ]
    for old, new in allowed:
        request, _ = _redirect(handler, old, new)
        assert request.full_url == new


def test_redirects_go_through_the_no_downgrade_handler(server: _Server, tmp_path: Path, monkeypatch) -> None:
    """End to end over the local (http, allowed) server: the redirect is followed, by that handler."""
    data = _serve_drive(server)
    server.redirects["moved.zip"] = server.url(DRIVE)
    seen, real = [], transfer.NoDowngradeRedirect.redirect_request

    def spy(self, req, fp, code, msg, headers, newurl):
        seen.append((req.full_url, newurl))
        return real(self, req, fp, code, msg, headers, newurl)

    monkeypatch.setattr(transfer.NoDowngradeRedirect, "redirect_request", spy)
    assert transfer.download(server.url("moved.zip"), tmp_path / DRIVE, FAST).read_bytes() == data
    assert seen == [(server.url("moved.zip"), server.url(DRIVE))]


def test_select_all_first_n_and_named_drives_add_their_calibration() -> None:
    names = lists.parse_archive_list(SHIPPED_LIST)
    assert lists._select_archives(names, None) == names == lists._select_archives(names, "all")
    first2 = [lists.archive_filename(n) for n in lists._select_archives(names, 2)]
    assert first2 == [
        "2011_09_26_calib.zip",
        "2011_09_26_drive_0001_sync.zip",
        "2011_09_26_drive_0002_sync.zip",
    ]
    picked = [
        lists.archive_filename(n)
        for n in lists._select_archives(names, ["2011_09_28_drive_0001", "2011_10_03_drive_0027_sync.zip"])
    ]
    assert picked == [
        "2011_09_28_calib.zip",
        "2011_09_28_drive_0001_sync.zip",
        "2011_10_03_calib.zip",
        "2011_10_03_drive_0027_sync.zip",
    ]
    assert lists._select_archives(names, 0) == []
    with pytest.raises(DataError, match="not in the archive list: 2011_09_26_drive_9999"):
        lists._select_archives(names, ["2011_09_26_drive_9999"])
    with pytest.raises(DataError, match=">= 0"):
        lists._select_archives(names, -1)


def _pairs(drives: list[str]) -> str:
    """Split lines (``left right``) of one frame of each drive, as Godard's and Eigen's lists name them."""
    return "".join(
        f"{d[:10]}/{d}_sync/image_02/data/0000000000.jpg {d[:10]}/{d}_sync/image_03/data/0000000000.jpg\n"
        for d in drives
    )


def _benchmark(drives: list[str]) -> str:
    """Monodepth2's eigen_benchmark lines (``<date>/<drive>_sync <frame> l``)."""
    return "".join(f"{d[:10]}/{d}_sync {i} l\n" for i, d in enumerate(drives))


def test_the_splits_drives_in_list_order_with_their_days_calibration(tmp_path: Path) -> None:
    names = lists.parse_archive_list(SHIPPED_LIST)
    train, eigen, bench = tmp_path / "train.txt", tmp_path / "eigen.txt", tmp_path / "bench.txt"
    train.write_text(_pairs(["2011_10_03_drive_0027", "2011_09_26_drive_0002", "2011_10_03_drive_0027"]))
    eigen.write_text("\n" + _pairs(["2011_09_26_drive_0002", "2011_09_28_drive_0001"]))
    bench.write_text(_benchmark(["2011_09_26_drive_0009", "2011_09_26_drive_0009"]))
    assert lists._split_drives(train) == ["2011_10_03_drive_0027", "2011_09_26_drive_0002"]
    assert lists._split_drives(bench) == ["2011_09_26_drive_0009"]

    def files(selection: lists.Selection) -> list[str]:
        return [lists.archive_filename(n) for n in selection.archives]

    both = lists.select_needed(names, {"the train split": train, "eigen": eigen})
    assert files(both) == [
        "2011_09_26_calib.zip",
        "2011_09_26_drive_0002_sync.zip",
        "2011_09_28_calib.zip",
        "2011_09_28_drive_0001_sync.zip",
        "2011_10_03_calib.zip",
        "2011_10_03_drive_0027_sync.zip",
    ]
    assert both.describe() == (
        "KITTI raw: 3 drives named by the train split and eigen (of 61 in the archive list) "
        "+ 3 calibration archives"
    )
    assert files(lists.select_needed(names, {"eigen_benchmark": bench})) == [
        "2011_09_26_calib.zip",
        "2011_09_26_drive_0009_sync.zip",
    ]
    # drive_count: the first N of the needed drives; drives: those of them the splits need.
    first = lists.select_needed(names, {"the train split": train, "eigen": eigen}, 1)
    assert files(first) == ["2011_09_26_calib.zip", "2011_09_26_drive_0002_sync.zip"]
    assert first.describe() == (
        "KITTI raw: the first 1 of the 3 drives named by the train split and eigen "
        "(data.kitti.drive_count; 61 in the archive list) + 1 calibration archive"
    )
    named = lists.select_needed(
        names, {"eigen": eigen}, ["2011_09_28_drive_0001", "2011_09_26_drive_0001_sync"]
    )
    assert files(named) == ["2011_09_28_calib.zip", "2011_09_28_drive_0001_sync.zip"]
    assert named.unneeded == ("2011_09_26_drive_0001",)
    assert named.describe().endswith(
        "; in data.kitti.drives but named by no split, so not fetched: 2011_09_26_drive_0001"
    )
    assert lists.select_needed(names, {"eigen": eigen}, 0).archives == []
    with pytest.raises(DataError, match="archive subset: not in the archive list: 2011_09_26_drive_9999"):
        lists.select_needed(names, {"eigen": eigen}, ["2011_09_26_drive_9999"])
    with pytest.raises(DataError, match=">= 0"):
        lists.select_needed(names, {"eigen": eigen}, -1)


def test_the_shipped_splits_need_46_of_the_61_drives() -> None:
    folder = SHIPPED_LIST.parent
    names = lists.parse_archive_list(SHIPPED_LIST)
    default = {"the train split": folder / "kitti_train_files.txt", "eigen": folder / "eigen_test_files.txt"}
    selection = lists.select_needed(names, default)
    assert len(selection.archives) == 51 and selection.calibrations == 5
    assert selection.describe() == (
        "KITTI raw: 46 drives named by the train split and eigen (of 61 in the archive list) "
        "+ 5 calibration archives"
    )
    bench = lists.select_needed(names, {"eigen_benchmark": folder / "eigen_benchmark_test_files.txt"})
    eigen = lists.select_needed(names, {"eigen": folder / "eigen_test_files.txt"})
    assert bench.archives == eigen.archives and bench.drives == 28
    # Monodepth2's eigen_zhou split (train.mode mono | mono_stereo) names 32 drives, 15 of them
    # in neither list: with it every drive of the archive list is fetched.
    zhou = {**default, "the monocular split": folder / "eigen_zhou_train_files.txt"}
    assert lists.select_needed(names, zhou).drives == 61
    assert lists.select_needed(names, {"m": folder / "eigen_zhou_train_files.txt"}).drives == 32


def test_the_monocular_modes_fetch_the_monocular_splits_drives(monkeypatch: pytest.MonkeyPatch) -> None:
    from msdepth.download.kitti import _needed_splits

    monkeypatch.chdir(SHIPPED_LIST.parents[1])
    stereo = params_from_dict({"data": {"source": "kitti"}})
    assert "the monocular split" not in _needed_splits(stereo)
    for mode in ("mono", "mono_stereo"):
        mono = params_from_dict({"data": {"source": "kitti"}, "train": {"mode": mode}})
        assert _needed_splits(mono)["the monocular split"] == Path("data_lists/eigen_zhou_train_files.txt")


def test_a_split_naming_drives_not_in_the_archive_list_is_one_line(tmp_path: Path) -> None:
    names = lists.parse_archive_list(SHIPPED_LIST)
    split = tmp_path / "eigen.txt"
    split.write_text(_pairs(["2011_09_26_drive_0001"] + [f"2011_09_26_drive_09{i:02d}" for i in range(5)]))
    with pytest.raises(DataError) as err:
        lists.select_needed(names, {"the train split": split}, archive_list="lists/a.txt")
    assert str(err.value) == (
        f"{split} (the train split): names 5 drive(s) not in lists/a.txt: 2011_09_26_drive_0900, "
        "2011_09_26_drive_0901, 2011_09_26_drive_0902 and 2 more"
    )
    for text, message in [
        (None, "no such split file"),
        (
            _pairs(["2011_09_26_drive_0001"]) + "training/image_2/000000_10.jpg x.jpg\n",
            ":2: names no raw drive",
        ),
        ("\n\n", "split file lists no frame"),
    ]:
        split.unlink(missing_ok=True)
        if text is not None:
            split.write_text(text)
        with pytest.raises(DataError, match=re.escape(f"{split}") + ".*" + re.escape(message)):
            lists.select_needed(names, {"eigen": split})


# --------------------------------------------------------------------------- download


def test_normal_download_is_byte_identical_and_leaves_no_part(server: _Server, tmp_path: Path) -> None:
    data = _serve_drive(server)
    dest = transfer.download(server.url(DRIVE), tmp_path / DRIVE, FAST)
    assert dest.read_bytes() == data
    assert not (tmp_path / (DRIVE + ".part")).exists()
    assert [e["range"] for e in server.gets(DRIVE)] == [None]


@pytest.mark.parametrize("mode", ["reset_once", "truncate_once", "stall_once"])
def test_reset_truncated_or_stalled_transfer_resumes_with_a_range_request(
    server: _Server, tmp_path: Path, mode: str
) -> None:
    data = _serve_drive(server, mode)
    dest = transfer.download(server.url(DRIVE), tmp_path / DRIVE, dataclasses.replace(FAST, timeout=0.3))
    assert dest.read_bytes() == data
    first, second = server.gets(DRIVE)
    assert first["range"] is None and 0 < first["sent"] < len(data)
    # The retry asked for exactly the bytes it lacked, and the server sent only those.
    assert second["range"] == f"bytes={first['sent']}-"
    assert second["sent"] == len(data) - first["sent"] < len(data)
    print(f"{mode}: size {len(data)}, 1st request sent {first['sent']}, resume sent {second['sent']}")


def test_404_fails_at_once_naming_the_url(server: _Server, tmp_path: Path) -> None:
    _serve_drive(server, "404")
    url = server.url(DRIVE)
    with pytest.raises(DataError, match=re.escape(url) + ": HTTP 404"):
        transfer.download(url, tmp_path / DRIVE, FAST)
    assert len(server.gets(DRIVE)) == 1  # no retries on a 4xx
    assert list(tmp_path.iterdir()) == []


def test_5xx_is_retried_and_gives_up_after_the_retries(server: _Server, tmp_path: Path) -> None:
    data = _serve_drive(server, "503_once")
    assert transfer.download(server.url(DRIVE), tmp_path / DRIVE, FAST).read_bytes() == data
    assert len(server.gets(DRIVE)) == 2
    server.modes[DRIVE], server.log[:] = "always_500", []
    with pytest.raises(DataError, match=r"download failed after 3 retries: HTTP 500"):
        transfer.download(server.url(DRIVE), tmp_path / "again.zip", FAST)
    assert len(server.gets(DRIVE)) == 1 + FAST.retries


def test_resets_that_make_no_progress_give_up(server: _Server, tmp_path: Path) -> None:
    _serve_drive(server, "always_reset")  # headers, then a reset before any byte of the body
    with pytest.raises(
        DataError,
        match=re.escape(server.url(DRIVE)) + ": download failed after 3 retries: ConnectionResetError",
    ):
        transfer.download(server.url(DRIVE), tmp_path / DRIVE, FAST)
    assert len(server.gets(DRIVE)) == 1 + FAST.retries
    assert not (tmp_path / DRIVE).exists()


def test_server_without_range_support_discards_the_partial_file(server: _Server, tmp_path: Path) -> None:
    data = _serve_drive(server, "no_range")
    part = tmp_path / (DRIVE + ".part")
    part.write_bytes(b"\xff" * (len(data) // 2))  # a stale partial download of someone else's bytes
    dest = transfer.download(server.url(DRIVE), tmp_path / DRIVE, FAST)
    assert dest.read_bytes() == data  # not garbage + full body appended
    (get,) = server.gets(DRIVE)
    assert get["range"] == f"bytes={len(data) // 2}-" and get["sent"] == len(data)


def test_a_whole_part_left_by_a_killed_run_is_finished_without_refetching(
    server: _Server, tmp_path: Path
) -> None:
    data = _serve_drive(server)
    (tmp_path / (DRIVE + ".part")).write_bytes(data)  # killed between the last write and the rename
    assert transfer.download(server.url(DRIVE), tmp_path / DRIVE, FAST).read_bytes() == data
    assert [e["sent"] for e in server.gets(DRIVE)] == [0]  # answered 416, nothing sent


# --------------------------------------------------------------------------- verification


def test_verify_zip_names_the_bad_member_and_the_file(tmp_path: Path) -> None:
    good = tmp_path / "good.zip"
    good.write_bytes(drive_zip("2011_09_26", 1))
    verification._verify_zip(good)
    data = bytearray(good.read_bytes())
    with zipfile.ZipFile(good) as zf:
        info = zf.infolist()[1]
    # Flip bytes inside the second member's data: same length, wrong CRC.
    offset = info.header_offset + 30 + len(info.filename.encode()) + 10
    data[offset : offset + 4] = bytes(b ^ 0xFF for b in data[offset : offset + 4])
    bad = tmp_path / "bad.zip"
    bad.write_bytes(bytes(data))
    with pytest.raises(DataError, match=re.escape(f"{bad}: member {info.filename} is corrupt")):
        verification._verify_zip(bad)
    notzip = tmp_path / "notzip.zip"
    notzip.write_bytes(b"<html>rate limited</html>")
    with pytest.raises(DataError, match="notzip.zip: not a readable zip archive"):
        verification._verify_zip(notzip)


def _corrupt(data: bytes) -> bytes:
    out = bytearray(data)
    mid = len(out) // 2
    out[mid : mid + 8] = bytes(b ^ 0xFF for b in out[mid : mid + 8])
    return bytes(out)


def test_manifest_recorded_on_first_success_and_later_tamper_detected(
    server: _Server, tmp_path: Path
) -> None:
    data = _serve_drive(server)
    dl_dir, raw = tmp_path / "zips", tmp_path / "raw"
    names = [f"raw_data/2011_09_26_drive_0001/{DRIVE}"]
    report = fetching.fetch_all(server.base_url, names, dl_dir, raw, dataclasses.replace(FAST, jobs=1))
    assert (
        report["fetched"] == [DRIVE]
        and report["extracted"] == [DRIVE]
        and report["bytes_downloaded"] == len(data)
    )
    manifest = json.loads((dl_dir / "manifest.json").read_text())["archives"]
    assert manifest[DRIVE]["sha256"] == hashlib.sha256(data).hexdigest()
    assert manifest[DRIVE]["size"] == len(data)

    # Second run: verified against the manifest, nothing downloaded or extracted again.
    report = fetching.fetch_all(server.base_url, names, dl_dir, raw, dataclasses.replace(FAST, jobs=1))
    assert report["skipped"] == [DRIVE] and report["fetched"] == report["extracted"] == []
    assert report["bytes_downloaded"] == 0 and len(server.gets(DRIVE)) == 1

    # Tamper with the archive (same length): detected, named, moved aside, record dropped.
    (dl_dir / DRIVE).write_bytes(_corrupt(data))
    with pytest.raises(
        fetching.DownloadError, match=f"{DRIVE}: size .* sha256 .* differ from manifest.json"
    ) as err:
        fetching.fetch_all(server.base_url, names, dl_dir, raw, dataclasses.replace(FAST, jobs=1))
    assert list(err.value.report["failed"]) == [DRIVE]
    assert (dl_dir / (DRIVE + ".corrupt")).exists() and not (dl_dir / DRIVE).exists()
    assert DRIVE not in json.loads((dl_dir / "manifest.json").read_text())["archives"]

    # Third run fetches it again and records it again.
    report = fetching.fetch_all(server.base_url, names, dl_dir, raw, dataclasses.replace(FAST, jobs=1))
    assert report["fetched"] == [DRIVE] and (dl_dir / DRIVE).read_bytes() == data
    assert (
        json.loads((dl_dir / "manifest.json").read_text())["archives"][DRIVE]["sha256"]
        == hashlib.sha256(data).hexdigest()
    )


def test_corrupted_download_is_reported_failed_and_moved_aside(server: _Server, tmp_path: Path) -> None:
    data = _serve_drive(server)
    server.files[DRIVE] = _corrupt(data)  # right length, wrong bytes: the size check cannot see it
    with pytest.raises(fetching.DownloadError, match=f"{DRIVE}: member .* is corrupt") as err:
        fetching.fetch_all(server.base_url, [f"raw_data/{DRIVE}"], tmp_path / "zips", tmp_path / "raw", FAST)
    assert list(err.value.report["failed"]) == [DRIVE]
    assert (tmp_path / "zips" / (DRIVE + ".corrupt")).exists() and not (tmp_path / "zips" / DRIVE).exists()
    assert not (tmp_path / "raw").exists() or not any((tmp_path / "raw").iterdir())


# --------------------------------------------------------------------------- extraction


def test_failed_extraction_leaves_no_marker_and_no_half_drive(tmp_path: Path, monkeypatch) -> None:
    archive = tmp_path / DRIVE
    archive.write_bytes(drive_zip("2011_09_26", 1))
    raw = tmp_path / "raw"
    drive_dir = raw / "2011_09_26" / "2011_09_26_drive_0001_sync"
    real_extract, calls = zipfile.ZipFile.extract, []

    def fail_on_third(self, member, path=None, pwd=None):
        calls.append(member)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        return real_extract(self, member, path, pwd)

    monkeypatch.setattr(zipfile.ZipFile, "extract", fail_on_third)
    with pytest.raises(DataError, match=f"{DRIVE}: extraction into .* failed .*No space left"):
        extraction.extract(archive, raw)
    assert not drive_dir.exists()
    assert not (raw / f".{DRIVE}.complete").exists()
    assert [p.name for p in raw.iterdir()] == []  # temp folder removed too

    monkeypatch.setattr(zipfile.ZipFile, "extract", real_extract)
    (raw / f".{DRIVE}.abcd.tmp").mkdir()  # as left by a run killed mid-extraction
    assert extraction.extract(archive, raw) is True
    assert len(list((drive_dir / "image_02" / "data").glob("*.png"))) == 3
    assert (raw / f".{DRIVE}.complete").exists()
    assert sorted(p.name for p in raw.iterdir()) == [f".{DRIVE}.complete", "2011_09_26"]
    assert extraction.extract(archive, raw) is False  # marker present: skipped


def test_drive_and_calibration_archives_share_the_day_folder(tmp_path: Path) -> None:
    (tmp_path / "c.zip").write_bytes(calib_zip("2011_09_26"))
    (tmp_path / "d.zip").write_bytes(drive_zip("2011_09_26", 1))
    raw = tmp_path / "raw"
    assert extraction.extract(tmp_path / "d.zip", raw) and extraction.extract(tmp_path / "c.zip", raw)
    assert sorted(p.name for p in (raw / "2011_09_26").iterdir()) == [
        "2011_09_26_drive_0001_sync",
        "calib_cam_to_cam.txt",
    ]


@pytest.mark.parametrize(
    "member",
    [
        "../evil.txt",
        "2011_09_26/../../evil.txt",
        "/tmp/evil.txt",
        "\\evil.txt",
        "..\\evil.txt",
        "C:/evil.txt",
        "c:\\evil.txt",
        "//server/share/evil.txt",
    ],
)
def test_zip_slip_member_is_rejected(tmp_path: Path, member: str) -> None:
    archive = tmp_path / "slip.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        zf.writestr("2011_09_26/ok.txt", "fine")
        zf.writestr(member, "gotcha")
    raw = tmp_path / "a" / "raw"
    with pytest.raises(DataError, match=re.escape(f"member {member!r} points outside")):
        extraction.extract(archive, raw)
    assert not (tmp_path / "a" / "evil.txt").exists() and not (tmp_path / "evil.txt").exists()
    assert not raw.exists()  # refused before anything was written
    with pytest.raises(DataError, match=re.escape(f"member {member!r} points outside")):
        verification._verify_zip(archive)


def _special_zip(path: Path, kind: int, target: str = "/etc/passwd") -> Path:
    """A zip with a regular file and a member whose Unix mode (external_attr) is ``kind``."""
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("2011_09_26/ok.txt", "fine")
        info = zipfile.ZipInfo("2011_09_26/special")
        info.create_system = 3  # Unix
        info.external_attr = (kind | 0o777) << 16
        zf.writestr(info, target)
    return path


@pytest.mark.parametrize(
    ("kind", "what"),
    [
        (stat.S_IFLNK, "a symbolic link"),
        (stat.S_IFIFO, "a device, fifo or socket"),
        (stat.S_IFCHR, "a device, fifo or socket"),
        (stat.S_IFBLK, "a device, fifo or socket"),
        (stat.S_IFSOCK, "a device, fifo or socket"),
    ],
)
def test_symlink_and_device_members_are_refused(tmp_path: Path, kind: int, what: str) -> None:
    archive = _special_zip(tmp_path / "special.zip", kind)
    raw = tmp_path / "raw"
    message = re.escape(f"{archive}: member '2011_09_26/special' is {what}; refusing to extract")
    with pytest.raises(DataError, match=message):
        extraction.extract(archive, raw)
    assert not raw.exists()
    with pytest.raises(DataError, match=message):
        verification._verify_zip(archive)


def test_members_without_a_unix_mode_or_with_a_plain_one_are_extracted(tmp_path: Path) -> None:
    """Zips written on Windows carry no mode (0), Unix ones a regular-file or folder mode."""
    archive = tmp_path / "ok.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for name, mode in (("d/", stat.S_IFDIR | 0o755), ("d/a.txt", stat.S_IFREG | 0o644), ("d/b.txt", 0)):
            info = zipfile.ZipInfo(name)
            info.external_attr = mode << 16
            zf.writestr(info, "" if name.endswith("/") else "x")
    assert extraction.extract(archive, tmp_path / "raw")
    assert sorted(p.name for p in (tmp_path / "raw" / "d").iterdir()) == ["a.txt", "b.txt"]


def bomb_zip(path: Path, megabytes: int = 10) -> Path:
    """A member of ``megabytes`` MB of zeros: deflate packs it about 1000:1."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("2011_09_26/calib.txt", "P_rect_02: 721.5\n")
        zf.writestr("2011_09_26/zeros.bin", bytes(megabytes << 20))
    return path


def test_zip_bomb_is_refused_before_anything_is_written(tmp_path: Path) -> None:
    archive = bomb_zip(tmp_path / "bomb.zip")
    ratio = (10 << 20) / archive.stat().st_size
    assert ratio > 10 * extraction.MAX_EXPANSION  # ~1000x
    raw = tmp_path / "raw"
    pattern = re.escape(f"{archive}: members declare 10.0 MiB uncompressed, ")
    pattern += r"\d+x the archive's .* \(more than 100x"
    with pytest.raises(DataError, match=pattern + ": a zip bomb\\?\\); refusing to extract"):
        extraction.extract(archive, raw)
    assert not raw.exists()
    with pytest.raises(DataError, match=pattern):
        verification._verify_zip(archive)  # refused without decompressing it


def test_expansion_up_to_the_bound_is_extracted(tmp_path: Path) -> None:
    """Text that deflates ~5x (more than any KITTI archive) is far below the bound."""
    archive = tmp_path / "text.zip"
    rng = np.random.default_rng(0)
    lines = "".join(f"{x:.6e} " for x in rng.normal(size=20_000))
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("2011_09_26/numbers.txt", lines)
    assert 1 < len(lines) / archive.stat().st_size < extraction.MAX_EXPANSION
    assert extraction.extract(archive, tmp_path / "raw")


def test_archive_larger_than_the_free_space_is_refused_before_writing(tmp_path: Path, monkeypatch) -> None:
    archive = tmp_path / DRIVE
    archive.write_bytes(drive_zip("2011_09_26", 1))
    with zipfile.ZipFile(archive) as zf:
        declared = sum(i.file_size for i in zf.infolist())
    real = shutil.disk_usage
    asked = []

    def little_space(path):
        asked.append(Path(path))
        return real(path)._replace(free=declared - 1)

    monkeypatch.setattr(extraction.shutil, "disk_usage", little_space)
    raw = tmp_path / "not" / "yet" / "raw"
    with pytest.raises(
        DataError,
        match=re.escape(f"{archive}: needs ")
        + r".* to extract but "
        + re.escape(f"{tmp_path} has ")
        + r".* free; refusing to start",
    ):
        extraction.extract(archive, raw)
    assert asked == [tmp_path] and not (tmp_path / "not").exists()  # the nearest existing folder
    monkeypatch.setattr(extraction.shutil, "disk_usage", lambda path: real(path)._replace(free=declared))
    assert extraction.extract(archive, raw)


def test_served_zip_bomb_is_reported_and_never_extracted(server: _Server, tmp_path: Path) -> None:
    server.files[DRIVE] = bomb_zip(tmp_path / "bomb.zip").read_bytes()
    with pytest.raises(fetching.DownloadError, match=f"{DRIVE}: members declare .* a zip bomb") as err:
        fetching.fetch_all(server.base_url, [f"raw_data/{DRIVE}"], tmp_path / "zips", tmp_path / "raw", FAST)
    assert list(err.value.report["failed"]) == [DRIVE] and "moved to" in err.value.report["failed"][DRIVE]
    assert not (tmp_path / "raw").exists()


def test_jpeg_conversion_replaces_pngs(tmp_path: Path) -> None:
    archive = tmp_path / DRIVE
    archive.write_bytes(drive_zip("2011_09_26", 1))
    raw = tmp_path / "raw"
    extraction.extract(archive, raw, jpeg=True, jpeg_quality=92)
    data = raw / "2011_09_26" / "2011_09_26_drive_0001_sync" / "image_02" / "data"
    assert sorted(p.name for p in data.iterdir()) == [f"{i:010d}.jpg" for i in range(3)]
    assert cv2.imread(str(data / "0000000000.jpg")).shape == (24, 40, 3)


# --------------------------------------------------------------------------- fetch_all


def test_dry_run_reports_total_size_and_downloads_nothing(server: _Server, tmp_path: Path, capsys) -> None:
    a = _serve_drive(server, name="2011_09_26_drive_0001_sync.zip", seed=1)
    b = _serve_drive(server, name="2011_09_26_drive_0002_sync.zip", seed=2)
    names = [f"raw_data/{n}" for n in server.files]
    report = fetching.fetch_all(server.base_url, names, tmp_path / "zips", tmp_path / "raw", DRY)
    assert report["total_bytes"] == len(a) + len(b)
    assert report["to_fetch"] == {n: len(d) for n, d in server.files.items()}
    assert {e["method"] for e in server.log} == {"HEAD"}
    assert not (tmp_path / "zips").exists() and not (tmp_path / "raw").exists()
    assert "would fetch 2 archive(s)" in capsys.readouterr().out


def test_parallel_fetch_reports_exactly_the_failing_archive(server: _Server, tmp_path: Path) -> None:
    server.files["2011_09_26_calib.zip"] = calib_zip("2011_09_26")
    ok = _serve_drive(server, "reset_once", name="2011_09_26_drive_0001_sync.zip", seed=1)
    _serve_drive(server, "404", name="2011_09_26_drive_0002_sync.zip", seed=2)
    names = [f"raw_data/{n}" for n in server.files]
    with pytest.raises(fetching.DownloadError, match=r"1 of 3 archive\(s\) failed") as err:
        fetching.fetch_all(
            server.base_url, names, tmp_path / "zips", tmp_path / "raw", dataclasses.replace(FAST, jobs=3)
        )
    report = err.value.report
    assert list(report["failed"]) == ["2011_09_26_drive_0002_sync.zip"]
    assert "HTTP 404" in report["failed"]["2011_09_26_drive_0002_sync.zip"]
    assert (
        report["fetched"] == report["extracted"] == ["2011_09_26_calib.zip", "2011_09_26_drive_0001_sync.zip"]
    )
    assert (tmp_path / "zips" / "2011_09_26_drive_0001_sync.zip").read_bytes() == ok
    assert (tmp_path / "raw" / "2011_09_26" / "calib_cam_to_cam.txt").exists()
    assert (
        tmp_path / "raw" / "2011_09_26" / "2011_09_26_drive_0001_sync" / "image_03" / "timestamps.txt"
    ).exists()


def test_extracted_archive_deleted_to_save_space_is_not_fetched_again(
    server: _Server, tmp_path: Path
) -> None:
    _serve_drive(server)
    names = [f"raw_data/{DRIVE}"]
    fetching.fetch_all(server.base_url, names, tmp_path / "zips", tmp_path / "raw", FAST)
    (tmp_path / "zips" / DRIVE).unlink()
    report = fetching.fetch_all(server.base_url, names, tmp_path / "zips", tmp_path / "raw", FAST)
    assert report["skipped"] == [DRIVE] and len(server.gets(DRIVE)) == 1


def _tree(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` with its bytes, and every folder (as b"<dir>")."""
    return {
        p.relative_to(root).as_posix(): (p.read_bytes() if p.is_file() else b"<dir>")
        for p in sorted(root.rglob("*"))
    }


def test_dry_run_states_every_archive_and_writes_nothing(server: _Server, tmp_path: Path, capsys) -> None:
    """One archive extracted (its zip deleted since), one downloaded, one half downloaded, one
    missing: HEAD requests for the last two only, their sizes and the rest to fetch in the total."""
    names = [f"2011_09_26_drive_000{i}_sync.zip" for i in range(1, 5)]
    data = {n: _serve_drive(server, name=n, seed=i) for i, n in enumerate(names)}
    zips, raw = tmp_path / "zips", tmp_path / "raw"
    zips.mkdir()
    raw.mkdir()
    (raw / f".{names[0]}.complete").write_text("{}")
    (zips / names[1]).write_bytes(data[names[1]])
    (zips / (names[2] + ".part")).write_bytes(data[names[2]][:1000])
    before = _tree(tmp_path)
    report = fetching.fetch_all(
        server.base_url, [f"raw_data/{n}" for n in names], zips, raw, DRY, label="KITTI raw"
    )
    assert _tree(tmp_path) == before
    assert sorted((e["method"], e["name"]) for e in server.log) == [("HEAD", names[2]), ("HEAD", names[3])]
    assert report["complete"] == [names[0]] and report["downloaded"] == [names[1]]
    assert report["to_fetch"] == {names[2]: len(data[names[2]]), names[3]: len(data[names[3]])}
    assert report["resume"] == {names[2]: 1000}
    assert report["total_bytes"] == len(data[names[2]]) - 1000 + len(data[names[3]])
    lines = capsys.readouterr().out.splitlines()
    human = sizes.human_size
    assert lines == [
        f"  {names[0]:<34} complete (downloaded and extracted)",
        f"  {names[1]:<34} downloaded; would be verified and extracted",
        f"  {names[2]:<34} to fetch {human(len(data[names[2]]) - 1000)} of {human(len(data[names[2]]))} "
        "(1000 B in its .part)",
        f"  {names[3]:<34} to fetch, {human(len(data[names[3]]))}",
        f"KITTI raw: would fetch 2 archive(s), {human(report['total_bytes'])}; 1 already complete, "
        "1 downloaded and not yet extracted",
    ]
    assert fetching.dry_run_total([report, report]).startswith("dry run, in all: would fetch 4 archive(s), ")


def _closed_port() -> int:
    """A local port that nothing listens on (connections to it are refused)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.mark.parametrize("dry_run", [True, False])
def test_connection_refused_stops_at_once_and_writes_nothing(tmp_path: Path, dry_run: bool) -> None:
    """Retried like a reset, 66 archives would take minutes; it stops at the first refusal."""
    base = f"http://127.0.0.1:{_closed_port()}/avg-kitti/"
    names = [f"raw_data/2011_09_26_drive_{i:04d}_sync.zip" for i in range(1, 67)]
    started = time.monotonic()
    with pytest.raises(transfer.NetworkUnreachable) as err:
        fetching.fetch_all(
            base,
            names,
            tmp_path / "zips",
            tmp_path / "raw",
            dataclasses.replace(FAST, dry_run=dry_run, backoff=1),
        )
    assert time.monotonic() - started < 5
    message = str(err.value)
    assert "\n" not in message and "cannot reach 127.0.0.1 (ConnectionRefusedError" in message
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("dry_run", [True, False])
def test_failed_name_resolution_is_asked_once(tmp_path: Path, monkeypatch, dry_run: bool) -> None:
    calls = []

    def no_dns(host, *args, **kwargs):
        calls.append(host)
        raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")

    monkeypatch.setattr(socket, "getaddrinfo", no_dns)
    names = [f"raw_data/2011_09_26_drive_{i:04d}_sync.zip" for i in range(1, 4)]
    with pytest.raises(
        transfer.NetworkUnreachable, match=r"cannot reach kitti\.invalid \(gaierror: .*not known\)"
    ):
        fetching.fetch_all(
            "https://kitti.invalid/",
            names,
            tmp_path / "zips",
            tmp_path / "raw",
            dataclasses.replace(FAST, dry_run=dry_run, jobs=1),
        )
    assert calls == ["kitti.invalid"] and list(tmp_path.iterdir()) == []


def test_unreachable_host_mid_run_stops_the_archives_not_started(server: _Server, tmp_path: Path) -> None:
    """The network goes away after the probe: the first archive's failure stops the others."""
    _serve_drive(server)
    names = [f"raw_data/{DRIVE}"] + [f"raw_data/2011_09_26_drive_{i:04d}_sync.zip" for i in range(2, 9)]
    real, answered = transfer._open, []

    def goes_away(url, timeout, **kwargs):
        if answered:  # after the probe's HEAD
            raise transfer.NetworkUnreachable(f"{url}: cannot reach the host")
        answered.append(url)
        return real(url, timeout, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(transfer, "_open", goes_away)
        with pytest.raises(transfer.NetworkUnreachable, match=r"stopped with 0 of 8 archive\(s\) complete$"):
            fetching.fetch_all(
                server.base_url, names, tmp_path / "zips", tmp_path / "raw", dataclasses.replace(FAST, jobs=1)
            )
    assert server.gets(DRIVE) == []


# --------------------------------------------------------------------------- the stage


def _kitti_project(
    tmp_path: Path,
    base_url: str,
    drives: int | list[str] = 2,
    *,
    train: list[str] | None = None,
    eigen: list[str] | None = None,
    benchmark: list[str] | None = None,
    extra_sets: list[str] | None = None,
) -> Path:
    """A working directory for stages/prepare_data.py: params.yaml for KITTI from ``base_url``.

    The archive list holds ``drives`` (a count of 2011_09_26 drives, or drive names) after their
    days' calibration archives; the train split names ``train`` (default: every listed drive),
    the Eigen list ``eigen`` (default: the first), the benchmark list ``benchmark`` (if given).
    """
    import yaml

    if isinstance(drives, int):
        drives = [f"2011_09_26_drive_{i:04d}" for i in range(1, drives + 1)]
    listed = []
    for day in sorted({d[:10] for d in drives}):
        listed += [f"raw_data/{day}_calib.zip"] + [
            f"raw_data/{d}/{d}_sync.zip" for d in drives if d[:10] == day
        ]
    (tmp_path / "archives.txt").write_text("".join(f"{n}\n" for n in listed))
    (tmp_path / "train.txt").write_text(_pairs(drives if train is None else train))
    (tmp_path / "eigen.txt").write_text(_pairs(drives[:1] if eigen is None else eigen))
    kitti = {
        "base_url": base_url,
        "allow_http": True,
        "archive_list": "archives.txt",
        "train_split": "train.txt",
        "eigen_split": "eigen.txt",
    }
    if benchmark is not None:
        (tmp_path / "bench.txt").write_text(_benchmark(benchmark))
        kitti["eigen_benchmark_split"] = "bench.txt"
    params: dict = {"data": {"source": "kitti", "root": "data/kitti", "kitti": kitti}}
    if extra_sets is not None:
        params["eval"] = {"extra_sets": extra_sets}
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))
    return tmp_path


def _stage(cwd: Path, *args: str) -> tuple[int, str, str, float]:
    """stages/prepare_data.py in ``cwd``: its exit status, stdout, stderr and seconds."""
    started = time.monotonic()
    proc = run_script("stages/prepare_data.py", *args, cwd=cwd)
    return proc.returncode, proc.stdout, proc.stderr, time.monotonic() - started


def test_stage_dry_run_prints_each_archive_and_the_totals(server: _Server, tmp_path: Path) -> None:
    server.files["2011_09_26_calib.zip"] = calib = calib_zip("2011_09_26")
    d1 = _serve_drive(server, name="2011_09_26_drive_0001_sync.zip", seed=1)
    d2 = _serve_drive(server, name="2011_09_26_drive_0002_sync.zip", seed=2)
    server.files["data_scene_flow.zip"] = scene = calib_zip("2015_00_00")
    work = _kitti_project(tmp_path, server.base_url)
    before = _tree(work)
    rc, out, err, _ = _stage(work, "--dry-run")
    assert rc == 0, err
    assert _tree(work) == before  # no data/, no data/downloads/
    assert {e["method"] for e in server.log} == {"HEAD"} and len(server.log) == 4
    lines = out.splitlines()
    assert lines[0] == (
        "KITTI raw: 2 drives named by the train split and eigen (of 2 in the archive list) "
        "+ 1 calibration archive"
    )
    assert lines[1] == f"  {'2011_09_26_calib.zip':<34} to fetch, {sizes.human_size(len(calib))}"
    raw = sizes.human_size(len(calib) + len(d1) + len(d2))
    assert lines[4] == f"KITTI raw: would fetch 3 archive(s), {raw}; 0 already complete"
    assert (
        lines[6]
        == f"KITTI 2015: would fetch 1 archive(s), {sizes.human_size(len(scene))}; 0 already complete"
    )
    total = sizes.human_size(len(calib) + len(d1) + len(d2) + len(scene))
    assert lines[7:] == [
        f"dry run, in all: would fetch 4 archive(s), {total}; 0 already complete; nothing was written"
    ]
    print(out)


@pytest.mark.parametrize("dry_run", [True, False])
def test_stage_without_network_says_so_in_one_line(tmp_path: Path, dry_run: bool) -> None:
    work = _kitti_project(tmp_path, f"http://127.0.0.1:{_closed_port()}/avg-kitti/", drives=61)
    rc, out, err, seconds = _stage(work, *(["--dry-run"] if dry_run else []))
    assert rc == 1 and seconds < 30
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: http://127.0.0.1:"), err
    assert "cannot reach 127.0.0.1 (ConnectionRefusedError" in lines[0]
    listed = ["archives.txt", "eigen.txt", "params.yaml", "train.txt"]
    assert out == "" and sorted(p.name for p in work.iterdir()) == listed
    print(f"{seconds:.1f} s: {lines[0]}")


# Two days, five drives: the train split names two of them, the Eigen list another and one of
# those, the benchmark list one; the fifth (2011_09_26_drive_0005) no list names.
LISTED = [
    "2011_09_26_drive_0001",
    "2011_09_26_drive_0002",
    "2011_09_26_drive_0003",
    "2011_09_26_drive_0005",
    "2011_09_28_drive_0001",
]


@pytest.mark.parametrize(
    ("extra_sets", "header", "asked"),
    [
        (
            ["eigen"],
            "KITTI raw: 3 drives named by the train split and eigen (of 5 in the archive list) "
            "+ 2 calibration archives",
            [
                "2011_09_26_calib.zip",
                "2011_09_26_drive_0001_sync.zip",
                "2011_09_26_drive_0003_sync.zip",
                "2011_09_28_calib.zip",
                "2011_09_28_drive_0001_sync.zip",
                "data_scene_flow.zip",
            ],
        ),
        (
            ["eigen_benchmark"],
            "KITTI raw: 2 drives named by the train split and eigen_benchmark (of 5 in the archive list) "
            "+ 1 calibration archive",
            [
                "2011_09_26_calib.zip",
                "2011_09_26_drive_0001_sync.zip",
                "2011_09_26_drive_0003_sync.zip",
                "data_depth_annotated.zip",
                "data_scene_flow.zip",
            ],
        ),
        (
            ["kitti2012"],
            "KITTI raw: 2 drives named by the train split (of 5 in the archive list) + 1 calibration archive",
            [
                "2011_09_26_calib.zip",
                "2011_09_26_drive_0001_sync.zip",
                "2011_09_26_drive_0003_sync.zip",
                "data_scene_flow.zip",
                "data_stereo_flow.zip",
            ],
        ),
    ],
)
def test_stage_dry_run_asks_only_for_what_the_splits_and_sets_need(
    server: _Server, tmp_path: Path, extra_sets: list[str], header: str, asked: list[str]
) -> None:
    for i, drive in enumerate(LISTED):
        _serve_drive(server, name=f"{drive}_sync.zip", seed=i)
    for day in ("2011_09_26", "2011_09_28"):
        server.files[f"{day}_calib.zip"] = calib_zip(day)
    server.files["data_scene_flow.zip"] = calib_zip("2015_00_00")
    server.files["data_depth_annotated.zip"] = calib_zip("train")
    server.files["data_stereo_flow.zip"] = calib_zip("training")
    work = _kitti_project(
        tmp_path,
        server.base_url,
        LISTED,
        train=["2011_09_26_drive_0003", "2011_09_26_drive_0001"],
        eigen=["2011_09_28_drive_0001", "2011_09_26_drive_0003"],
        benchmark=["2011_09_26_drive_0003"],
        extra_sets=extra_sets,
    )
    before = _tree(work)
    rc, out, err, _ = _stage(work, "--dry-run")
    assert rc == 0, err
    assert _tree(work) == before
    assert {e["method"] for e in server.log} == {"HEAD"}
    assert sorted(e["name"] for e in server.log) == asked
    lines = out.splitlines()
    assert lines[0] == header
    annotated = [line for line in lines if line.startswith("KITTI annotated depth: ")]
    assert len(annotated) == ("eigen_benchmark" in extra_sets)
    assert len([line for line in lines if line.startswith("KITTI 2012: ")]) == ("kitti2012" in extra_sets)
    assert lines[-1].startswith(f"dry run, in all: would fetch {len(asked)} archive(s), ")


def test_stage_with_a_split_naming_an_unlisted_drive_fails_in_one_line_asking_nothing(
    server: _Server, tmp_path: Path
) -> None:
    work = _kitti_project(
        tmp_path, server.base_url, 2, eigen=["2011_09_26_drive_0001", "2011_09_26_drive_0099"]
    )
    rc, out, err, _ = _stage(work, "--dry-run")
    assert rc == 1 and out == ""
    assert err.strip().splitlines() == [
        "error: eigen.txt (eigen): names 1 drive(s) not in archives.txt: 2011_09_26_drive_0099"
    ]
    assert server.log == []


def test_annotated_depth_archive_unpacks_where_the_benchmark_index_looks(
    server: _Server, tmp_path: Path
) -> None:
    """data_depth_annotated.zip holds train/ and val/ at its top: fetched into data.root/<depth_annotated>,
    each frame's GT is where msdepth.data.eval_sets.annotated_gt_path finds it."""
    from msdepth.data.eval_sets import _annotated_gt_path

    depth = np.full((24, 40), 256 * 10, dtype=np.uint16)  # 10 m everywhere, KITTI's depth PNG scale
    ok, png = cv2.imencode(".png", depth)
    assert ok
    members = {
        "train/2011_09_26_drive_0001_sync/proj_depth/groundtruth/image_02/0000000005.png": png.tobytes(),
        "val/2011_09_26_drive_0002_sync/proj_depth/groundtruth/image_02/0000000069.png": png.tobytes(),
    }
    buf = stdio.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    server.files["data_depth_annotated.zip"] = buf.getvalue()
    root = tmp_path / "kitti" / "depth_annotated"
    report = fetching.fetch_all(server.base_url, ["data_depth_annotated.zip"], tmp_path / "zips", root, FAST)
    assert report["extracted"] == ["data_depth_annotated.zip"]
    assert sorted(p.name for p in root.iterdir()) == [".data_depth_annotated.zip.complete", "train", "val"]
    for (name, data), (drive, number) in zip(
        members.items(),
        [("2011_09_26/2011_09_26_drive_0001_sync", 5), ("2011_09_26/2011_09_26_drive_0002_sync", 69)],
        strict=True,
    ):
        found = _annotated_gt_path(root, drive, number)
        assert found == root / name and found.read_bytes() == data
    assert _annotated_gt_path(root, "2011_09_26/2011_09_26_drive_0001_sync", 6) is None


def test_every_extra_set_has_its_list_or_its_archive_for_the_download() -> None:
    """A set of raw frames has its split list (the drives to fetch); KITTI 2012 its own archive;
    KITTI 2015's is the archive data.source kitti always fetches (its tree is the set's); a stereo
    folder is the user's, nothing to fetch."""
    from msdepth.data.eval_sets import SETS
    from msdepth.download.kitti import SET_SPLITS, _single_archives

    for name in set(SETS) - set(SET_SPLITS):
        params = Params()
        params = dataclasses.replace(
            params,
            data=dataclasses.replace(params.data, source="kitti"),
            eval=dataclasses.replace(params.eval, extra_sets=(name,)),
        )
        own = name not in ("kitti2015", "folder")
        assert len(_single_archives(params)) == 1 + own, name  # KITTI 2015's and the set's


def test_kitti2012_archive_unpacks_where_the_kitti2012_index_looks(server: _Server, tmp_path: Path) -> None:
    """data_stereo_flow.zip holds training/ and testing/ at its top: fetched into data.root/kitti2012
    (prepare's folder for it), the set's index finds its frames, GT and reflective GT there; a
    second fetch of the complete archive asks nothing."""
    from msdepth.data.eval_sets import _build_kitti2012_index
    from msdepth.download.kitti import _single_archives

    image = cv2.imencode(".png", np.full((370, 1226, 3), 128, np.uint8))[1].tobytes()
    disp = cv2.imencode(".png", np.full((370, 1226), 256 * 20, np.uint16))[1].tobytes()
    members = {f"training/{d}/000000_10.png": image for d in ("colored_0", "colored_1")}
    members |= {f"training/{d}/000000_10.png": disp for d in ("disp_occ", "disp_refl_occ")}
    members["testing/colored_0/000000_10.png"] = image
    buf = stdio.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    server.files["data_stereo_flow.zip"] = buf.getvalue()
    params = Params()
    params = dataclasses.replace(
        params,
        data=dataclasses.replace(params.data, source="kitti", root=str(tmp_path / "kitti")),
        eval=dataclasses.replace(params.eval, extra_sets=("kitti2012",)),
    )
    label, archive, dest = _single_archives(params)[-1]
    assert (label, archive, dest) == ("KITTI 2012", "data_stereo_flow.zip", tmp_path / "kitti" / "kitti2012")
    report = fetching.fetch_all(server.base_url, [archive], tmp_path / "zips", dest, FAST)
    assert report["extracted"] == ["data_stereo_flow.zip"]
    index = _build_kitti2012_index(dest / "training")
    assert list(index["frame"]) == ["000000_10"] and index["focal"][0] == pytest.approx(707.0912)
    assert Path(index["class_map"][0]) == dest / "training" / "disp_refl_occ" / "000000_10.png"
    asked = len(server.log)
    assert fetching.fetch_all(server.base_url, [archive], tmp_path / "zips", dest, FAST)["extracted"] == []
    assert len(server.log) == asked


# --------------------------------------------------------------------------- a hostile list or mirror

D2, D3 = "2011_09_26_drive_0002_sync.zip", "2011_09_26_drive_0003_sync.zip"


@pytest.mark.parametrize(
    "entry",
    ["?.zip", "raw_data/a.zip?v=.zip", "raw_data/a.zip#.zip", "raw_data/..", "raw_data/.zip"],
)
def test_an_entry_naming_no_archive_file_is_refused_before_anything_is_asked(
    server: _Server, tmp_path: Path, entry: str
) -> None:
    """``raw_data/?.zip`` names no file: the download folder itself was taken for the archive,
    failed to verify and was renamed to ``zips.corrupt`` with its manifest (``..``: its parent)."""
    _serve_drive(server)
    zips, raw = tmp_path / "zips", tmp_path / "raw"
    fetching.fetch_all(server.base_url, [f"raw_data/{DRIVE}"], zips, raw, FAST)
    before, asked = _tree(tmp_path), len(server.log)
    problem = "has a query or fragment" if "?" in entry or "#" in entry else "names no archive file"
    for options in (FAST, DRY):
        with pytest.raises(DataError, match=re.escape(f"archive {entry!r}: {problem}")) as err:
            fetching.fetch_all(server.base_url, [f"raw_data/{DRIVE}", entry], zips, raw, options)
        assert "\n" not in str(err.value)
    assert _tree(tmp_path) == before and len(server.log) == asked
    listed = tmp_path / "list.txt"
    listed.write_text(f"raw_data/{DRIVE}\n{entry}{'' if entry.endswith('.zip') else '/x.zip'}\n")
    if entry.endswith(".zip"):  # the list's own check (one .zip URL per line) catches the others
        with pytest.raises(DataError, match=re.escape(f"{listed}:2: archive {entry!r}: {problem}")):
            lists.parse_archive_list(listed)


def _zip(path: Path, members: dict[str, str]) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        for name, text in members.items():
            zf.writestr(name, text)
    return path


@pytest.mark.parametrize(
    ("member", "message"),
    [
        ("2011_09_26", "is a file but {raw}/2011_09_26 is a folder already"),
        (
            "2011_09_26/calib_cam_to_cam.txt/x",
            "is a folder but {raw}/2011_09_26/calib_cam_to_cam.txt is a file already",
        ),
    ],
)
def test_a_member_colliding_with_what_other_archives_unpacked_is_refused(
    tmp_path: Path, member: str, message: str
) -> None:
    """A file where a drive's day folder is: today the extracted drives were deleted (rmtree) while
    their markers still said complete; a folder where a file is: the file was deleted."""
    raw = tmp_path / "raw"
    (tmp_path / "c.zip").write_bytes(calib_zip("2011_09_26"))
    (tmp_path / "d.zip").write_bytes(drive_zip("2011_09_26", 1))
    assert extraction.extract(tmp_path / "d.zip", raw) and extraction.extract(tmp_path / "c.zip", raw)
    before = _tree(raw)
    hostile = _zip(tmp_path / D2, {member: "x"})
    colliding = "/".join(member.split("/")[:2])
    expected = f"{hostile}: member {colliding!r} " + message.format(raw=raw) + "; refusing to extract"
    with pytest.raises(DataError, match=re.escape(expected)):
        extraction.extract(hostile, raw)
    assert _tree(raw) == before  # nothing removed, nothing added, no temp folder left


@pytest.mark.parametrize("member", [f".{DRIVE}.complete", f"./.{DRIVE}.complete", f".{DRIVE}.x.tmp/a"])
def test_a_top_level_dot_member_is_refused(server: _Server, tmp_path: Path, member: str) -> None:
    """A member named like another archive's completion marker made that archive "skipped"."""
    server.files[D2] = _zip(tmp_path / D2, {"2011_09_26/ok.txt": "fine", member: "{}"}).read_bytes()
    _serve_drive(server)
    zips, raw = tmp_path / "zips", tmp_path / "raw"
    with pytest.raises(fetching.DownloadError) as err:
        fetching.fetch_all(server.base_url, [f"raw_data/{D2}"], zips, raw, FAST)
    assert f"member {member!r} is a top-level dot-file" in err.value.report["failed"][D2]
    assert not raw.exists()
    report = fetching.fetch_all(server.base_url, [f"raw_data/{DRIVE}"], zips, raw, FAST)
    assert report["fetched"] == report["extracted"] == [DRIVE]


def test_a_content_length_that_is_no_byte_count_fails_only_its_archive(
    server: _Server, tmp_path: Path, capsys
) -> None:
    """``²`` passes str.isdigit() and int() raised: the dry run ended in a traceback."""
    _serve_drive(server)
    _serve_drive(server, "bad_length", name=D2, seed=2)
    zips, raw = tmp_path / "zips", tmp_path / "raw"
    refused = f"{server.url(D2)}: the server's Content-Length '\u00b2' is not a byte count; refusing it"
    for options in (DRY, FAST):
        with pytest.raises(fetching.DownloadError) as err:
            fetching.fetch_all(server.base_url, [f"raw_data/{DRIVE}", f"raw_data/{D2}"], zips, raw, options)
        assert err.value.report["failed"] == {D2: refused}
    assert err.value.report["fetched"] == [DRIVE] and not (zips / D2).exists()


@pytest.mark.parametrize(
    ("mode", "refused"),
    [
        ("overlong", "the server sent more than the {size} bytes it declared; refusing the rest"),
        ("no_length", "the server declares no size (no Content-Length); refusing an unbounded download"),
    ],
)
def test_a_body_past_or_without_a_declared_size_is_cut_off(
    server: _Server, tmp_path: Path, mode: str, refused: str
) -> None:
    """A GET streamed without a length was read to its end (300 MB kept, from a probe): now it is
    bounded by the size HEAD declared, and a size declared nowhere is refused."""
    data = _serve_drive(server, mode)
    zips = tmp_path / "zips"
    with pytest.raises(fetching.DownloadError) as err:
        fetching.fetch_all(server.base_url, [f"raw_data/{DRIVE}"], zips, tmp_path / "raw", FAST)
    reason = err.value.report["failed"][DRIVE]
    assert reason == f"{server.url(DRIVE)}: " + refused.format(size=len(data))
    assert sorted(p.name for p in zips.iterdir()) == []  # no archive, no .part, no .corrupt


def test_a_server_dripping_bytes_is_cut_off_below_the_minimum_rate(server: _Server, tmp_path: Path) -> None:
    """One byte per 10 ms never trips a per-read timeout; 1000 B/s over 0.1 s windows does."""
    server.files["2011_09_26_calib.zip"], server.modes["2011_09_26_calib.zip"] = (
        calib_zip("2011_09_26"),
        "drip",
    )
    _serve_drive(server)
    slow = dataclasses.replace(FAST, min_rate=1000, rate_window=0.1)
    names = ["raw_data/2011_09_26_calib.zip", f"raw_data/{DRIVE}"]
    with pytest.raises(fetching.DownloadError) as err:
        fetching.fetch_all(server.base_url, names, tmp_path / "zips", tmp_path / "raw", slow)
    report = err.value.report
    assert report["failed"] == {
        "2011_09_26_calib.zip": f"{server.url('2011_09_26_calib.zip')}: download failed after 3 retries: "
        "slower than 1000 B/s over 0.1 s"
    }
    assert report["fetched"] == [DRIVE]
    assert len(server.gets("2011_09_26_calib.zip")) == 1 + slow.retries


def test_a_redirect_off_http_or_to_an_unreachable_host_fails_only_its_archive(
    server: _Server, tmp_path: Path
) -> None:
    """With allow_http, a redirect to ftp:// was followed, and its refused connection was taken
    for the mirror being unreachable: NetworkUnreachable stopped every archive."""
    _serve_drive(server)
    port = _closed_port()
    server.redirects[D2] = f"ftp://127.0.0.1:{port}/x.zip"
    server.redirects[D3] = f"http://127.0.0.1:{port}/x.zip"
    names = [f"raw_data/{n}" for n in (DRIVE, D2, D3)]
    for options in (DRY, FAST):
        with pytest.raises(fetching.DownloadError) as err:
            fetching.fetch_all(server.base_url, names, tmp_path / "zips", tmp_path / "raw", options)
        failed = err.value.report["failed"]
        assert failed[D2] == (
            f"{server.url(D2)}: redirected to ftp://127.0.0.1:{port}/x.zip, which is not an http(s) URL; "
            "refusing to follow it"
        )
        assert failed[D3].startswith(
            f"{server.url(D3)}: redirected to http://127.0.0.1:{port}/x.zip, which cannot be reached "
            "(ConnectionRefusedError"
        )
        assert sorted(failed) == [D2, D3]
    assert err.value.report["fetched"] == [DRIVE]


def test_same_day_archives_finishing_together_both_land(tmp_path: Path, monkeypatch) -> None:
    """Both threads found no day folder, then both moved theirs in: ENOTEMPTY for the second.

    Each move of a day folder waits (up to 1 s) until the other thread reaches its own, which is
    exactly the interleaving that failed; a move that cannot be reached meanwhile passes alone.
    """
    for i in (1, 2):
        (tmp_path / f"d{i}.zip").write_bytes(drive_zip("2011_09_26", i, frames=1))
    real = {"replace": os.replace, "rename": os.rename}
    both = threading.Barrier(2, timeout=1.0)

    def meeting(kind: str):
        def move(src, dst, *args, **kwargs):
            if Path(dst).name == "2011_09_26" and str(src).endswith(".tmp/2011_09_26"):
                try:
                    both.wait()
                except threading.BrokenBarrierError:
                    pass
            return real[kind](src, dst, *args, **kwargs)

        return move

    for kind in real:
        monkeypatch.setattr(os, kind, meeting(kind))
    raw, errors = tmp_path / "raw", []

    def unpack(i: int) -> None:
        try:
            extraction.extract(tmp_path / f"d{i}.zip", raw)
        except DataError as exc:
            errors.append(str(exc))

    threads = [threading.Thread(target=unpack, args=(i,)) for i in (1, 2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert errors == []
    day = raw / "2011_09_26"
    assert sorted(p.name for p in day.iterdir()) == [
        "2011_09_26_drive_0001_sync",
        "2011_09_26_drive_0002_sync",
    ]
    assert sorted(p.name for p in raw.iterdir()) == [".d1.zip.complete", ".d2.zip.complete", "2011_09_26"]


def test_the_temps_of_a_run_killed_writing_the_manifest_or_a_marker_are_removed(
    server: _Server, tmp_path: Path
) -> None:
    # Issue 27, item 12: a run killed (kill -9) inside the manifest's or a marker's atomic write
    # left its temp (".manifest.json.msdepth-tmp-<random>.json") for good.
    _serve_drive(server)
    zips, raw = tmp_path / "zips", tmp_path / "raw"
    writers = [
        dl_io.atomic_path(zips / verification.MANIFEST_NAME),
        dl_io.atomic_path(raw / f".{DRIVE}.complete"),
    ]
    temps = [writer.__enter__() for writer in writers]  # entered and never left (kept referenced)
    users = [zips / ".manifest.json.k1ll3d_9.json", raw / f"..{DRIVE}.complete.msdepth-tmp-k1ll3d_9.bak"]
    for path in users:
        path.write_text("a user's file")
    report = fetching.fetch_all(server.base_url, [f"raw_data/{DRIVE}"], zips, raw, FAST)
    assert report["fetched"] == report["extracted"] == [DRIVE]
    assert [t.exists() for t in temps] == [False, False] and all(p.exists() for p in users)
