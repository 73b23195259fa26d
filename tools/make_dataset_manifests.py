"""Write the per-file SHA-256 manifests of the data sets gnomon can fetch (not run by tests).

Usage (from the repository root)::

    python tools/make_dataset_manifests.py [SHARED_DATA_DIR]

``SHARED_DATA_DIR`` defaults to ``../shared/data``; it holds one folder per data set
(``broad``, ``tyrex``, ``logs``, ``images``) in the layout gnomon's readers expect, made of
unmodified upstream files. For each file this writes one line of
``src/gnomon/datasets/manifests/<name>.tsv``: SHA-256, size in bytes, path in the local
layout, public URL of the upstream file (tab separated). ``gnomon datasets fetch NAME``
downloads every URL and refuses a file whose SHA-256 differs.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "src" / "gnomon" / "datasets" / "manifests"

RAW = "https://raw.githubusercontent.com"
#: commits of the upstream repositories the URLs are pinned to (files there never change)
BROAD_COMMIT = "afbaa4d75c4cd7c8ca76b8145b1812312d87fb7f"
TYREX_COMMIT = "7b070df5231ac78910ab076eeb026d2d8152a246"
PYULOG_COMMITS = {"sample.ulg": "6e74ac3a454f96a30fdb1c147b2a0d92fe380d4d",
                  "sample_log_small.ulg": "0197ebaad28a1d73c366acf0064311e3d289ec40",
                  "sample_logging_tagged_and_default_params.ulg":
                      "d3a865ffc88a5e5aa3b407827bc5b6576f90efdf"}


def url_broad(path: str) -> str | None:
    """``X.mat`` -> ``data_mat/X.mat``, ``X.hdf5`` -> ``data_hdf5/X.hdf5``."""
    name = Path(path).name
    folder = "data_hdf5" if name.endswith(".hdf5") else "data_mat"
    return f"{RAW}/dlaidig/broad/{BROAD_COMMIT}/{folder}/{name}"


def url_tyrex(path: str) -> str | None:
    """The data set's own layout; only ``datasets/`` and the ``LICENCE`` are fetched."""
    if not (path.startswith("datasets/") or path == "LICENCE"):
        return None
    return f"{RAW}/tyrex-team/benchmarks-attitude-smartphones/{TYREX_COMMIT}/{path}"


def url_logs(path: str) -> str | None:
    name = Path(path).name
    if path.startswith("px4/"):
        if name == "LICENSE.md":
            return f"{RAW}/PX4/pyulog/HEAD/LICENSE.md"
        return f"{RAW}/PX4/pyulog/{PYULOG_COMMITS.get(name, 'HEAD')}/test/{name}"
    if path.startswith("ardupilot/"):
        upstream = "COPYING" if name == "COPYING" else f"tests/{name}"
        return f"{RAW}/ArduPilot/pymavlink/HEAD/{upstream}"
    return None


def url_images(path: str) -> str | None:
    if path == "meadow_cube.jpg":
        return f"{RAW}/imageio/imageio-binaries/HEAD/images/meadow_cube.jpg"
    if path == "OPENCV_LICENSE_Apache-2.0.txt":
        return f"{RAW}/opencv/opencv/4.x/LICENSE"
    return f"{RAW}/opencv/opencv/4.x/samples/data/{path}"


URLS = {"broad": url_broad, "tyrex": url_tyrex, "logs": url_logs, "images": url_images}


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def main(shared: Path) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for name, url_of in URLS.items():
        lines = []
        for p in sorted((shared / name).rglob("*")):
            rel = p.relative_to(shared / name).as_posix()
            url = url_of(rel) if p.is_file() else None
            if url is None:
                continue
            lines.append(f"{sha256(p)}\t{p.stat().st_size}\t{rel}\t{url}")
        (OUT / f"{name}.tsv").write_text("\n".join(lines) + "\n")
        print(f"{name}: {len(lines)} files")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT.parent / "shared" / "data")
