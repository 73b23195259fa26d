"""Data sets: the catalogue, fetching (from a local HTTP server only), the shipped excerpts,
the version.

No test touches the network: fetches go to an ``http.server`` on 127.0.0.1 serving files
made in ``tmp_path``, with a manifest of those files in place of the real one.
"""

from __future__ import annotations

import functools
import hashlib
import http.server
import importlib.metadata
import json
import socket
import subprocess
import sys
import threading

import pytest

import gnomon
from gnomon import datasets
from gnomon.cli import main
from gnomon.datasets import catalogue
from gnomon.datasets.catalogue import ManifestEntry

TOY_FILES = {"px4/a.ulg": b"ULog" + bytes(range(256)) * 40, "ardupilot/test.BIN": b"\xa3\x95" * 500,
             "COPYING": b"licence text\n"}


@pytest.fixture
def server(tmp_path):
    """A loopback HTTP server over ``tmp_path/srv``; yields (base URL, list of paths asked)."""
    root = tmp_path / "srv"
    root.mkdir()
    asked: list[str] = []

    class Handler(http.server.SimpleHTTPRequestHandler):
        def do_GET(self):
            asked.append(self.path)
            super().do_GET()

        def log_message(self, *args):  # keep pytest's output clean
            pass

    httpd = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(Handler, directory=str(root)))
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}", root, asked
    finally:
        httpd.shutdown()
        httpd.server_close()


@pytest.fixture
def toy_logs(server, tmp_path, monkeypatch):
    """The ``logs`` data set replaced by three small files served locally; the cache in
    ``tmp_path/cache``. Yields (base URL, served root, paths asked, cache folder)."""
    base, root, asked = server
    entries = []
    for path, data in TOY_FILES.items():
        target = root / "logs" / path
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
        entries.append(ManifestEntry(path=path, sha256=hashlib.sha256(data).hexdigest(),
                                     size=len(data), url=f"https://example.invalid/{path}"))
    real = catalogue.manifest
    monkeypatch.setattr(catalogue, "manifest",
                        lambda name: entries if name == "logs" else real(name))
    monkeypatch.setenv("GNOMON_DATA_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("GNOMON_DATA_URL", raising=False)
    yield base, root, asked, tmp_path / "cache" / "logs"


def closed_port() -> int:
    """A loopback port nothing listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ---------------------------------------------------------------- catalogue
def test_the_catalogue_names_every_data_set_with_source_licence_and_checksums():
    assert set(datasets.CATALOGUE) == {"broad", "tyrex", "logs", "images"}
    for name, ds in datasets.CATALOGUE.items():
        assert ds.licence and ds.citation and ds.source.startswith("https://github.com/"), name
        files = catalogue.manifest(name)
        assert files, name
        for e in files:
            assert len(e.sha256) == 64 and int(e.sha256, 16) >= 0, (name, e.path)
            assert e.size > 0 and e.url.startswith("https://"), (name, e.path)
        assert datasets.bundled(ds.bundled).is_dir(), name  # the excerpt ships


def test_gnomon_datasets_lists_each_set_with_licence_and_state(capsys):
    assert main(["datasets", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    rows = {r["name"]: r for r in out["datasets"]}
    assert set(rows) == set(datasets.CATALOGUE)
    for name, r in rows.items():
        assert r["licence"] == datasets.CATALOGUE[name].licence
        assert r["state"] in ("local", "cached", "partly fetched", "not fetched")
        assert r["bundled"] is not None
    assert main(["datasets"]) == 0
    text = capsys.readouterr().out
    for ds in datasets.CATALOGUE.values():
        assert f"{ds.name}: " in text and ds.licence in text


def test_an_unknown_data_set_is_one_clear_line(capsys):
    assert main(["datasets", "fetch", "nope"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "unknown data set 'nope'" in err and "broad" in err


# ---------------------------------------------------------------- fetch
def test_fetch_downloads_every_file_checks_it_and_a_second_fetch_is_a_no_op(toy_logs):
    base, _, asked, folder = toy_logs
    assert datasets.fetched_dir("logs") is None
    assert datasets.fetch("logs", base_url=base) == folder
    for path, data in TOY_FILES.items():
        assert (folder / path).read_bytes() == data
    assert sorted(asked) == sorted(f"/logs/{p}" for p in TOY_FILES)
    assert "Licence:" in (folder / "SOURCE.txt").read_text()  # the attribution goes along
    assert datasets.fetched_dir("logs") == folder
    asked.clear()
    datasets.fetch("logs", base_url=base)
    assert asked == []  # every file there with its checksum: nothing downloaded


def test_an_interrupted_fetch_resumes_with_the_missing_files(toy_logs):
    base, _, asked, folder = toy_logs
    datasets.fetch("logs", base_url=base)
    (folder / "px4" / "a.ulg").unlink()
    assert datasets.status("logs").present == len(TOY_FILES) - 1
    assert datasets.describe("logs")["cached_files"] == len(TOY_FILES) - 1
    asked.clear()
    datasets.fetch("logs", base_url=base)
    assert asked == ["/logs/px4/a.ulg"]
    assert datasets.status("logs").complete


def test_a_file_whose_checksum_differs_is_refused_and_not_kept(toy_logs):
    base, root, _, folder = toy_logs
    (root / "logs" / "ardupilot" / "test.BIN").write_bytes(b"\xa3\x95" * 499 + b"xx")
    with pytest.raises(datasets.FetchError) as err:
        datasets.fetch("logs", base_url=base)
    msg = str(err.value)
    assert "ardupilot/test.BIN" in msg and "SHA-256" in msg and "refused" in msg
    assert not (folder / "ardupilot" / "test.BIN").exists()
    assert not list(folder.rglob("tmp*"))  # no partial download left behind


def test_a_file_missing_on_the_server_is_named_and_what_came_before_is_kept(toy_logs):
    base, root, _, folder = toy_logs
    (root / "logs" / "COPYING").unlink()  # the last file of the manifest
    with pytest.raises(datasets.FetchError, match="logs/COPYING: HTTP 404"):
        datasets.fetch("logs", base_url=base)
    assert datasets.status("logs").present == len(TOY_FILES) - 1
    assert datasets.fetched_dir("logs") is None


def test_the_command_fetches_from_gnomon_data_url_into_gnomon_data_dir(toy_logs, monkeypatch,
                                                                        capsys):
    base, _, _, folder = toy_logs
    monkeypatch.setenv("GNOMON_DATA_URL", base)
    assert main(["datasets", "fetch", "logs"]) == 0
    assert f"complete in {folder}" in capsys.readouterr().out
    # with no other copy, the fetched one is the data set's folder
    monkeypatch.delenv("GNOMON_LOGS_DIR", raising=False)
    monkeypatch.setattr(datasets, "_shared", lambda *parts: None)
    assert datasets.describe("logs")["state"] == "cached"
    assert datasets.logs_dir() == folder


def test_no_network_is_one_clear_line_and_exit_status_2(toy_logs, monkeypatch, capsys):
    monkeypatch.setenv("GNOMON_DATA_URL", f"http://127.0.0.1:{closed_port()}")
    assert main(["datasets", "fetch", "logs"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert err.startswith("gnomon: error: cannot reach 127.0.0.1:") and "no network?" in err
    assert err.count("\n") == 0 and "Traceback" not in captured.err + captured.out
    assert "run the same command again" in err


def test_benchmark_without_data_says_how_to_fetch_it(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("GNOMON_BROAD_DIR", str(tmp_path / "absent"))
    assert main(["benchmark", "broad", "--filters", "mahony", "--anchors", "none"]) == 2
    err = capsys.readouterr().err
    assert "gnomon datasets fetch broad" in err and "GNOMON_BROAD_DIR" in err


def test_benchmark_without_data_uses_the_data_set_found(monkeypatch, capsys):
    """``gnomon benchmark broad`` with no --data: the folder ``dataset_dir`` finds (here the
    shipped excerpts, named by the setting)."""
    monkeypatch.setenv("GNOMON_BROAD_DIR", str(datasets.bundled("broad")))
    assert main(["benchmark", "broad", "--filters", "mahony", "--anchors", "none",
                 "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert len({r["trial"] for r in res["trials"]}) == 2


# ---------------------------------------------------------------- package data, version
def test_shipped_data_is_found_through_the_package_from_any_folder(tmp_path):
    code = ("import gnomon, pathlib; from gnomon.datasets import bundled; "
            "from gnomon.vision.images import find_image; "
            "pkg = pathlib.Path(gnomon.__file__).parent; "
            "paths = [bundled('broad', '01_undisturbed_slow_rotation_A_excerpt.mat'), "
            "bundled('logs', 'tyrex', 'LICENCE'), bundled('README.md'), "
            "find_image('meadow_cube.jpg', prefer_full=False)[0]]; "
            "print(all(p.is_file() and p.is_relative_to(pkg) for p in paths))")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True, check=True)
    assert out.stdout.strip() == "True"


def test_a_missing_shipped_file_is_named():
    with pytest.raises(FileNotFoundError, match="no broad/absent.mat"):
        datasets.bundled("broad", "absent.mat")


def test_version_comes_from_one_place(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    assert capsys.readouterr().out.strip() == f"gnomon {importlib.metadata.version('gnomon')}"
    assert gnomon.__version__ == importlib.metadata.version("gnomon")
