"""The catalogue of the real data sets gnomon knows: source, licence, files, excerpt.

Each data set's files are listed in ``manifests/<name>.tsv`` beside this module (made by
``tools/make_dataset_manifests.py`` from unmodified upstream copies): one line per file,
tab separated — SHA-256 (hex), size (bytes), path in the layout gnomon's readers expect,
public URL of the upstream file. The URLs point at raw files of the upstream GitHub
repositories, pinned to a commit where the index of those repositories names one
(BROAD, tyrex, the PX4 logs), else at the default branch (``HEAD``) or OpenCV's ``4.x``.

None of the data was made by gnomon; each set keeps its own licence.
"""

from __future__ import annotations

import dataclasses
import importlib.resources

from gnomon.errors import InputError

__all__ = ["DataSet", "ManifestEntry", "CATALOGUE", "dataset", "manifest"]


@dataclasses.dataclass(frozen=True)
class ManifestEntry:
    """One file of a data set: ``path`` in the local layout, its ``sha256`` (hex),
    ``size`` in bytes and the public ``url`` it is downloaded from."""

    path: str
    sha256: str
    size: int
    url: str


@dataclasses.dataclass(frozen=True)
class DataSet:
    """A data set gnomon can use.

    name : short name used on the command line (``gnomon datasets fetch NAME``).
    title : what it is, in a few words.
    citation : whom to credit (paper or project).
    licence : the data's licence (SPDX-like name).
    source : the upstream repository (a web page).
    env : the setting naming a local copy (``GNOMON_BROAD_DIR`` ...).
    bundled : folder of the excerpt shipped in the package data ``gnomon/data``.
    scope : which part of the upstream set the manifest covers.
    """

    name: str
    title: str
    citation: str
    licence: str
    source: str
    env: str
    bundled: str
    scope: str


CATALOGUE: dict[str, DataSet] = {d.name: d for d in (
    DataSet(
        name="broad",
        title="BROAD: IMU with optical motion-capture truth (benchmark for orientation "
              "estimation)",
        citation="Laidig, Caruso, Cereatti, Seel, 'BROAD - A Benchmark for Robust Inertial "
                 "Orientation Estimation', Data 6(7):72, 2021, doi:10.3390/data6070072",
        licence="CC-BY-4.0",
        source="https://github.com/dlaidig/broad",
        env="GNOMON_BROAD_DIR",
        bundled="broad",
        scope="15 of the 39 trials (the ones gnomon's benchmark scores) and trials.json",
    ),
    DataSet(
        name="tyrex",
        title="smartphones (Nexus 5, iPhone 5) with a Qualisys motion-capture reference",
        citation="Michel, Geneves, Fourati, Layaida, 'Attitude estimation for indoor "
                 "navigation and augmented reality with smartphones', Pervasive and Mobile "
                 "Computing 46, 2018 (Inria Tyrex team)",
        licence="CeCILL-2.1",
        source="https://github.com/tyrex-team/benchmarks-attitude-smartphones",
        env="GNOMON_TYREX_DIR",
        bundled="logs/tyrex",
        scope="user Guillaume, both phones, 14 recordings each, the magnetometer "
              "calibrations and the LICENCE (Android raw gyro files left out)",
    ),
    DataSet(
        name="logs",
        title="sample flight-controller logs (PX4 ULog, ArduPilot DataFlash)",
        citation="PX4 logs from the pyulog test suite (PX4 Development Team); ArduPilot "
                 "log from the pymavlink tests (ArduPilot developers)",
        licence="BSD-3-Clause (PX4), LGPL-3.0 (ArduPilot)",
        source="https://github.com/PX4/pyulog, https://github.com/ArduPilot/pymavlink",
        env="GNOMON_LOGS_DIR",
        bundled="logs",
        scope="px4/sample.ulg, sample_log_small.ulg, "
              "sample_logging_tagged_and_default_params.ulg, ardupilot/test.BIN, licences",
    ),
    DataSet(
        name="images",
        title="real photographs for the visual pitch method (seed 003)",
        citation="meadow_cube.jpg: imageio standard images (credit imageio); aero1.jpg, "
                 "aero3.jpg: OpenCV sample data (the OpenCV authors)",
        licence="public domain (imageio), Apache-2.0 (OpenCV)",
        source="https://github.com/imageio/imageio-binaries, https://github.com/opencv/opencv",
        env="GNOMON_IMAGES_DIR",
        bundled="images",
        scope="meadow_cube.jpg (full size), aero1.jpg, aero3.jpg, OpenCV's LICENSE",
    ),
)}


def dataset(name: str) -> DataSet:
    """The catalogue entry ``name``; ``InputError`` naming the known ones otherwise."""
    try:
        return CATALOGUE[name]
    except KeyError:
        raise InputError(f"unknown data set {name!r}; known: {', '.join(CATALOGUE)}",
                         field="dataset") from None


def manifest(name: str) -> list[ManifestEntry]:
    """The files of data set ``name`` (see the module docstring for the format)."""
    text = (importlib.resources.files("gnomon.datasets") / "manifests"
            / f"{dataset(name).name}.tsv").read_text(encoding="utf-8")
    entries = []
    for line in text.splitlines():
        if line.strip():
            sha, size, path, url = line.split("\t")
            entries.append(ManifestEntry(path=path, sha256=sha, size=int(size), url=url))
    return entries
