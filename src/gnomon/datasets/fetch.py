"""Download a data set of the catalogue into the user's cache folder, verified file by file.

Where: :func:`cache_dir` (``$GNOMON_DATA_DIR``, else the platform's user cache folder from
platformdirs, e.g. ``~/.cache/gnomon`` on Linux), one sub-folder per data set, in the
layout gnomon's readers expect.

What is verified: every file of the data set's manifest
(:func:`gnomon.datasets.catalogue.manifest`) is downloaded with pooch, which computes its
SHA-256 while writing it to a temporary file beside the target and moves it into place
only when the hash equals the manifest's; otherwise :class:`FetchError` names the file
and nothing is kept. The manifests were computed from copies of the upstream files (not
from the upstream servers, which could not be reached when they were written): if an
upstream file changed, its fetch is refused rather than silently accepted.

Resuming: a file already in the cache whose SHA-256 matches is not downloaded again, so
an interrupted fetch continues with the missing files and a second fetch downloads
nothing. (A file cut off mid-download is never kept, so it is downloaded again whole.)

``$GNOMON_DATA_URL`` (or ``base_url=``) replaces the public URLs by
``<base>/<name>/<path>``: a mirror, or a local server in the tests.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from pathlib import Path
from urllib.parse import urlsplit

from gnomon.datasets import catalogue
from gnomon.errors import InputError

__all__ = ["FetchError", "CacheStatus", "cache_dir", "fetch", "fetched_dir", "status"]


class FetchError(InputError):
    """A data set could not be fetched (no network, a missing file, a checksum mismatch)."""


@dataclasses.dataclass(frozen=True)
class CacheStatus:
    """The cached copy of a data set: ``present`` of ``total`` files (sizes checked, not
    hashes), ``bytes_total`` of the whole set, in ``folder``."""

    present: int
    total: int
    bytes_total: int
    folder: Path

    @property
    def complete(self) -> bool:
        return self.present == self.total


def cache_dir() -> Path:
    """The folder fetched data sets go to: ``$GNOMON_DATA_DIR``, else the user cache folder
    (``platformdirs.user_cache_dir("gnomon")``)."""
    value = os.environ.get("GNOMON_DATA_DIR")
    if value:
        return Path(value).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("gnomon", appauthor=False))


def status(name: str) -> CacheStatus:
    """How much of data set ``name`` is in the cache (a file counts when its size matches)."""
    entries = catalogue.manifest(name)
    folder = cache_dir() / catalogue.dataset(name).name
    present = 0
    for e in entries:
        p = folder / e.path
        if p.is_file() and p.stat().st_size == e.size:
            present += 1
    return CacheStatus(present=present, total=len(entries),
                       bytes_total=sum(e.size for e in entries), folder=folder)


def fetched_dir(name: str) -> Path | None:
    """The cached copy of data set ``name`` when every file of it is there, else None."""
    st = status(name)
    return st.folder if st.complete else None


def _url(entry: catalogue.ManifestEntry, name: str, base_url: str | None) -> str:
    base = base_url or os.environ.get("GNOMON_DATA_URL")
    return f"{base.rstrip('/')}/{name}/{entry.path}" if base else entry.url


def fetch(name: str, base_url: str | None = None, progress: bool = False) -> Path:
    """Download data set ``name`` into ``cache_dir()/name`` and return that folder.

    base_url : replaces the public URLs by ``<base_url>/<name>/<path>`` (default
        ``$GNOMON_DATA_URL``, else the manifest's URLs).
    progress : show a progress bar (bytes of the whole set) on stderr.

    Raises :class:`FetchError` (one line) when a server cannot be reached, a file is
    missing there or its SHA-256 differs from the manifest's; the files already fetched
    stay and the next call continues from them.
    """
    import pooch
    import requests
    from tqdm import tqdm

    ds = catalogue.dataset(name)
    entries = catalogue.manifest(ds.name)
    folder = cache_dir() / ds.name
    downloader = pooch.HTTPDownloader(progressbar=False, timeout=30)
    logger = pooch.get_logger()
    level = logger.level
    logger.setLevel(logging.WARNING)  # pooch says "Downloading ..." for every file
    bar = tqdm(total=sum(e.size for e in entries), unit="B", unit_scale=True,
               desc=f"{ds.name}", disable=not progress)
    try:
        for e in entries:
            url = _url(e, ds.name, base_url)
            target = folder / e.path
            try:
                pooch.retrieve(url, known_hash=f"sha256:{e.sha256}", fname=target.name,
                               path=target.parent, downloader=downloader)
            except ValueError as err:
                if "hash" not in str(err).lower():
                    raise
                raise FetchError(f"{url}: its SHA-256 differs from the catalogue's "
                                 f"({e.sha256}); refused, not kept", field=e.path) from None
            except requests.exceptions.HTTPError as err:
                raise FetchError(f"{url}: HTTP {err.response.status_code}; {ds.name} not "
                                 f"complete ({status(ds.name).present} of {len(entries)} "
                                 f"files in {folder})") from None
            except (requests.exceptions.ConnectionError, requests.exceptions.Timeout):
                host = urlsplit(url).netloc
                raise FetchError(f"cannot reach {host} (no network?): {ds.name} not "
                                 f"complete ({status(ds.name).present} of {len(entries)} "
                                 f"files in {folder}); run the same command again when "
                                 f"online to continue") from None
            bar.update(e.size)
    finally:
        bar.close()
        logger.setLevel(level)
    _write_attribution(ds, folder)
    return folder


def _write_attribution(ds: catalogue.DataSet, folder: Path) -> None:
    """``SOURCE.txt`` beside the fetched files: whom to credit, licence, where from."""
    (folder / "SOURCE.txt").write_text(
        f"{ds.title}\n\nCredit: {ds.citation}\nLicence: {ds.licence}\nSource: {ds.source}\n"
        f"Fetched by gnomon: {ds.scope}; every file checked against its SHA-256 in "
        f"gnomon/datasets/manifests/{ds.name}.tsv.\n", encoding="utf-8")
