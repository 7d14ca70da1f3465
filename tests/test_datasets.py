"""Dataset downloads against a local HTTP server and file:// URLs (never the network)."""

from __future__ import annotations

import hashlib
import http.server
import io
import json
import socket
import tarfile
import threading
import zipfile
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from slamfront import DataError, manifest
from slamfront.cli import datasets_cmd
from slamfront.datasets import COMPLETE_MARKER, DatasetDownload, fetch
from slamfront.manifest import PinnedDataset, fetch_dataset, load_manifest
from slamfront.recipe import recipes_dir


class _RangeHandler(http.server.BaseHTTPRequestHandler):
    """Serves ``files`` with HTTP range support; ``cut`` makes the first full response stop
    early; ``after[a] = b`` holds the answer to ``a`` until ``b`` has been asked for (two
    downloads then surely run together, whatever the machine's load)."""

    files: dict[str, bytes] = {}
    cut: dict[str, int] = {}
    log: list[str] = []
    after: dict[str, str] = {}
    asked: dict[str, threading.Event] = {}

    def do_GET(self) -> None:  # noqa: N802 (http.server's naming)
        self.asked.setdefault(self.path, threading.Event()).set()
        if self.path in self.after:
            self.asked.setdefault(self.after[self.path], threading.Event()).wait(timeout=30)
        body = self.files.get(self.path)
        if body is None:
            self.send_error(404)
            return
        header = self.headers.get("Range")
        self.log.append(header or "")
        if header:
            start = int(header.split("=")[1].split("-")[0])
            if start >= len(body):
                self.send_error(416)
                return
            self.send_response(206)
            self.send_header("Content-Range", f"bytes {start}-{len(body) - 1}/{len(body)}")
            payload = body[start:]
        else:
            self.send_response(200)
            payload = body
        self.send_header("Content-Length", str(len(payload)))
        self.end_headers()
        if not header and self.path in self.cut:  # the connection drops half way
            self.wfile.write(payload[: self.cut.pop(self.path)])
            return
        self.wfile.write(payload)

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def server() -> Iterator[str]:
    _RangeHandler.files, _RangeHandler.cut, _RangeHandler.log = {}, {}, []
    _RangeHandler.after, _RangeHandler.asked = {}, {}
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _RangeHandler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()
    httpd.server_close()


def _zip(members: dict[str, bytes]) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as bundle:
        for name, data in members.items():
            bundle.writestr(name, data)
    return buffer.getvalue()


def _spec(url: str | None, **kw: object) -> DatasetDownload:
    return DatasetDownload(name="demo", title="demo", url=url, homepage="", license="", **kw)  # type: ignore[arg-type]


def test_download_checksum_and_extraction(server: str, tmp_path: Path) -> None:
    archive = _zip({"top/day/0.png": b"a" * 1000, "top/night/0.png": b"b" * 1000, "README": b"x"})
    _RangeHandler.files["/demo.zip"] = archive
    spec = _spec(f"{server}/demo.zip", sha256=hashlib.sha256(archive).hexdigest(), members="top/", strip="top/",
                 expect=("day/0.png", "night/0.png"))
    folder = fetch(spec, tmp_path, progress=False)
    assert (folder / "day" / "0.png").read_bytes() == b"a" * 1000
    assert not (folder / "README").exists() and (folder / COMPLETE_MARKER).exists()
    assert fetch(spec, tmp_path) == folder and len(_RangeHandler.log) == 1  # installed: no second download


def test_an_interrupted_download_resumes_with_a_range_request(server: str, tmp_path: Path) -> None:
    archive = _zip({f"f{i}.bin": bytes([i]) * 5000 for i in range(20)})
    _RangeHandler.files["/demo.zip"] = archive
    _RangeHandler.cut["/demo.zip"] = 30_000
    spec = _spec(f"{server}/demo.zip", sha256=hashlib.sha256(archive).hexdigest())
    with pytest.raises(DataError, match="ended early .* run `slamfront datasets download demo` again to resume"):
        fetch(spec, tmp_path, progress=False)
    assert (tmp_path / "demo.zip.part").stat().st_size == 30_000
    folder = fetch(spec, tmp_path, progress=False)
    assert _RangeHandler.log == ["", "bytes=30000-"]
    assert (folder / "f19.bin").read_bytes() == bytes([19]) * 5000


def test_a_checksum_mismatch_keeps_nothing_installed(server: str, tmp_path: Path) -> None:
    _RangeHandler.files["/demo.zip"] = _zip({"a": b"1"})
    spec = _spec(f"{server}/demo.zip", sha256="0" * 64)
    with pytest.raises(DataError, match="does not match the published"):
        fetch(spec, tmp_path, progress=False)
    assert (tmp_path / "demo.zip.bad").exists() and not spec.is_installed(tmp_path)


def test_without_a_published_checksum_it_is_recorded_and_then_enforced(server: str, tmp_path: Path) -> None:
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as bundle:
        info = tarfile.TarInfo("pkg-1/data/summer/x.png")
        info.size = 3
        bundle.addfile(info, io.BytesIO(b"abc"))
    archive = buffer.getvalue()
    _RangeHandler.files["/a.tar.gz"] = archive
    notes: list[str] = []
    spec = _spec(f"{server}/a.tar.gz", archive="tar", members="pkg-1/data/", strip="pkg-1/data/")
    folder = fetch(spec, tmp_path, progress=False, report=notes.append)
    assert (folder / "summer" / "x.png").read_bytes() == b"abc"
    assert hashlib.sha256(archive).hexdigest() in notes[0]
    assert (tmp_path / "demo.tar.sha256").read_text().startswith(hashlib.sha256(archive).hexdigest())


def test_file_urls_work_offline(tmp_path: Path) -> None:
    source = tmp_path / "mirror.zip"
    source.write_bytes(_zip({"day/1.png": b"p"}))
    folder = fetch(_spec(source.as_uri()), tmp_path / "cache", progress=False, report=lambda _: None)
    assert (folder / "day" / "1.png").read_bytes() == b"p"


def test_offline_is_one_clear_error_saying_where_to_put_the_file(tmp_path: Path) -> None:
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    spec = _spec(f"http://127.0.0.1:{port}/demo.zip")
    with pytest.raises(DataError, match=f"cannot download demo from .*Offline\\? .* save it as {tmp_path}/demo.zip"):
        fetch(spec, tmp_path, progress=False, timeout=5)


def test_an_archive_placed_by_hand_is_verified_and_extracted(tmp_path: Path) -> None:
    (tmp_path / "demo.zip").write_bytes(_zip({"a/b.txt": b"hi"}))
    folder = fetch(_spec("http://unreachable.invalid/demo.zip"), tmp_path, report=lambda _: None)
    assert (folder / "a" / "b.txt").read_bytes() == b"hi"


def test_members_escaping_the_folder_are_refused(tmp_path: Path) -> None:
    (tmp_path / "demo.zip").write_bytes(_zip({"../../evil.txt": b"x"}))
    with pytest.raises(DataError, match="outside"):
        fetch(_spec("http://unreachable.invalid/demo.zip"), tmp_path, report=lambda _: None)
    assert not (tmp_path.parent / "evil.txt").exists()


def test_a_corrupt_archive_is_named(tmp_path: Path) -> None:
    (tmp_path / "demo.zip").write_bytes(b"not a zip")
    with pytest.raises(DataError, match="demo.zip: not a valid zip archive"):
        fetch(_spec("http://unreachable.invalid/demo.zip"), tmp_path, report=lambda _: None)


def test_datasets_command(cli, tmp_path: Path) -> None:
    code, out, _ = cli("datasets", "--dir", tmp_path)
    assert code == 0
    for name in ("nordland", "gardens_point", "uofa"):
        assert name in out
    code, out, _ = cli("datasets", "path", "gardens_point", "--dir", tmp_path)
    assert out.strip() == str(tmp_path / "gardens_point")
    code, _, err = cli("datasets", "download", "uofa", "--dir", tmp_path)
    assert code == 2 and "Google Drive" in err and str(tmp_path / "uofa" / "day_evening") in err
    code, _, err = cli("datasets", "download", "nordlnd", "--dir", tmp_path)
    assert code == 2 and "unknown dataset 'nordlnd'" in err
    mirror = tmp_path / "gp.zip"
    mirror.write_bytes(_zip({"day_left/Image000.jpg": b"j"}))
    code, out, _ = cli("datasets", "download", "gardens_point", "--dir", tmp_path / "c", "--url", mirror.as_uri(), "-q")
    assert code == 0 and (tmp_path / "c" / "gardens_point" / "day_left" / "Image000.jpg").exists()


# --- pinned datasets (the manifest of the real data the tests read) -------------------


def _pinned(shared_data: Path, name: str, n_files: int, **changes: object) -> PinnedDataset:
    """A real manifest dataset cut down to its first ``n_files`` files."""
    dataset = next(d for d in load_manifest() if d.name == name)
    return replace(dataset, files=dataset.files[:n_files], **changes)


def _serve_copy(dataset: PinnedDataset, shared_data: Path, prefix: str = "/mirror") -> dict[str, bytes]:
    """Put a copy of the dataset's shared files on the test server, laid out as a data root."""
    served = {f"{prefix}/{dataset.folder}/{f.path}": (shared_data / dataset.folder / f.path).read_bytes()
              for f in dataset.files}
    _RangeHandler.files.update(served)
    return served


def test_the_data_root_holds_every_pinned_file_unchanged(shared_data: Path) -> None:
    datasets = load_manifest()
    assert {"nordland", "loop10", "redwood_sample", "posegraphs_se_sync"} <= {d.name for d in datasets}
    for dataset in datasets:
        assert dataset.origin.startswith("https://") and dataset.licence and dataset.citation
        assert not dataset.damaged(shared_data), f"{dataset.name}: the data root differs from the manifest"


def test_every_data_folder_a_shipped_recipe_reads_is_pinned(shared_data: Path) -> None:
    folders = [d.folder for d in load_manifest()]
    for path in recipes_dir().glob("*.yaml"):
        params = yaml.safe_load(path.read_text())["source"].get("params", {})
        for value in params.values():
            if isinstance(value, str) and (shared_data / value).is_dir():
                assert any(value == f or value.startswith(f + "/") for f in folders), f"{path.name}: {value}"


def test_fetch_from_a_mirror_resumes_and_refuses_a_corrupt_file(server: str, tmp_path: Path,
                                                                 shared_data: Path) -> None:
    dataset = _pinned(shared_data, "loop10", 3)
    served = _serve_copy(dataset, shared_data)
    first, second, third = sorted(served)
    served_second = served[second]
    _RangeHandler.files[second] = served_second[:-1] + bytes([served_second[-1] ^ 0xFF])  # one byte altered
    _RangeHandler.cut[third] = 100_000  # the connection drops after 100 kB
    # the corrupt file's answer waits for the third's request: the first failure stops the
    # fetch only once the third is under way (otherwise it may be cancelled before it starts)
    _RangeHandler.after[second] = third
    with pytest.raises(DataError) as failure:
        fetch_dataset(dataset, tmp_path, mirror=f"{server}/mirror", progress=False)
    assert "is not the pinned" in str(failure.value) or "ended early" in str(failure.value)
    folder = tmp_path / dataset.folder
    assert not (folder / Path(second).name).exists()  # the corrupt copy was refused
    assert (folder / (Path(third).name + ".download.part")).stat().st_size == 100_000
    _RangeHandler.files[second] = served_second
    _RangeHandler.log.clear()
    assert fetch_dataset(dataset, tmp_path, mirror=f"{server}/mirror", progress=False) >= 2
    assert "bytes=100000-" in _RangeHandler.log  # resumed, not started again
    assert not dataset.damaged(tmp_path)
    assert fetch_dataset(dataset, tmp_path, mirror=f"{server}/mirror", progress=False) == 0


def test_fetch_takes_the_files_from_a_zip_origin(server: str, tmp_path: Path, shared_data: Path) -> None:
    dataset = _pinned(shared_data, "redwood_sample", 4, origin=f"{server}/Sample.zip")
    assert dataset.archive
    folder = shared_data / dataset.folder
    _RangeHandler.files["/Sample.zip"] = _zip({f"Sample/{f.path}": (folder / f.path).read_bytes()
                                               for f in dataset.files})
    assert fetch_dataset(dataset, tmp_path, progress=False) == 4
    assert not dataset.damaged(tmp_path) and not list(tmp_path.glob(".*.zip"))  # the archive is removed


def _manifest_file(tmp_path: Path, datasets: list[PinnedDataset]) -> Path:
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps({"datasets": [
        {**{k: getattr(d, k) for k in ("name", "folder", "title", "origin", "archive", "licence", "citation")},
         "renames": dict(d.renames), "files": [[f.path, f.size, f.sha256] for f in d.files]}
        for d in datasets
    ]}))
    return path


def test_fetch_for_tests_offline_lists_each_missing_dataset_then_a_mirror_completes_it(
    cli, server: str, tmp_path: Path, shared_data: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with socket.socket() as probe:  # a port nobody listens on: the origins are unreachable
        probe.bind(("127.0.0.1", 0))
        dead = f"http://127.0.0.1:{probe.getsockname()[1]}"
    datasets = [
        _pinned(shared_data, "fr1_gt_vs_est", 2, origin=f"{dead}/slambook2/"),
        _pinned(shared_data, "posegraphs_slambook", 1, origin=f"{dead}/slambook/"),
        _pinned(shared_data, "open3d_feature_pair", 2, origin=f"{dead}/Feature.zip"),
    ]
    monkeypatch.setattr(manifest, "MANIFEST", _manifest_file(tmp_path, datasets))
    monkeypatch.setenv("SLAMFRONT_DATA", str(tmp_path / "data"))
    monkeypatch.delenv(manifest.MIRROR_ENV, raising=False)
    code, out, err = cli("datasets", "fetch", "--for-tests", "-q")
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 4, err  # one line per dataset, then the summary
    for dataset, line in zip(datasets, lines):
        assert line.startswith(f"{dataset.name}: ") and dataset.origin in line and "unreachable" in line
    assert lines[-1].startswith("slamfront: error: 3 of 3 pinned datasets are incomplete")
    for dataset in datasets:
        _serve_copy(dataset, shared_data)
    monkeypatch.setenv(manifest.MIRROR_ENV, f"{server}/mirror")
    code, out, err = cli("datasets", "fetch", "--for-tests", "-q")
    assert code == 0 and "5 files of 3 datasets present and verified" in out, err
    _RangeHandler.log.clear()
    code, out, _ = cli("datasets", "fetch", "--for-tests")
    assert code == 0 and _RangeHandler.log == []  # complete: nothing is downloaded


def test_datasets_path_without_a_name_is_the_data_root(cli, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SLAMFRONT_DATA", str(tmp_path))
    code, out, _ = cli("datasets", "path")
    assert code == 0 and out.strip() == str(tmp_path.resolve())
    code, _, err = cli("datasets", "fetch", "nordlnd")
    assert code == 2 and "unknown pinned dataset 'nordlnd'" in err


def test_a_data_folder_beside_the_checkout_is_never_written(cli, tmp_path: Path, shared_data: Path,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(manifest, "MANIFEST", _manifest_file(tmp_path, [_pinned(shared_data, "fr1_gt_vs_est", 2)]))
    monkeypatch.setattr(datasets_cmd, "data_root", lambda: tmp_path / "shared" / "data")
    monkeypatch.setattr(datasets_cmd, "download_root", lambda: tmp_path / "user")
    code, _, err = cli("datasets", "fetch", "--for-tests")
    assert code == 2 and "2 pinned files are missing or differ (fr1_gt_vs_est)" in err and "SLAMFRONT_DATA=DIR" in err
    assert not (tmp_path / "shared").exists() and not (tmp_path / "user").exists()


def test_the_catalogue_lists_every_source_s_downloads_without_importing_a_source() -> None:
    # `slamfront datasets` reads the slamfront.datasets entry points, not the sources: they must agree
    import subprocess
    import sys

    from slamfront.cli.datasets_cmd import catalogue
    from slamfront.registry import PluginRegistry

    listed = catalogue()
    for info in PluginRegistry().all("source"):
        for spec in info.cls.downloads:
            assert listed.get(spec.name) == (info.name, spec), f"{info.name}: {spec.name} is not in slamfront.datasets"
    assert {source for source, _ in listed.values()} <= set(PluginRegistry().names("source"))
    code = "import sys; from slamfront.cli.datasets_cmd import catalogue; catalogue(); print(sorted(sys.modules))"
    modules = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "numpy" not in modules and "slamfront_plugins.sources" not in modules
