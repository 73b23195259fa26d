"""The campaign directory: Parquet parts as runs finish, consolidation, resume, reading.

``DIR/campaign.json``: the campaign's description (scenario config and source, runs,
root seed, vary, task and its options), written once (atomically); a resume must give
the same one. ``DIR/parts/part-<first index>-<n>-<tag>.parquet``: the rows of one
finished chunk, written by the submitting process under a temporary name and renamed,
so never half-written; a crash, SIGKILL or Ctrl-C loses only unfinished chunks.
``DIR/results.parquet``: every finished run once, sorted by index; the parts are
consolidated into it at the end (also after an interruption) and then removed.
``DIR/only-INDEX.parquet``: the row of a run re-run alone.

Rows are dicts of the form :mod:`gnomon.campaign.worker` makes; ``seed`` is stored as
``uint64``.
"""

from __future__ import annotations

import json
import os
import pathlib
import uuid

from gnomon.errors import InputError

__all__ = ["RESULTS", "MANIFEST", "rows_to_frame", "write_part", "read_results",
           "consolidate", "open_campaign_dir", "read_manifest", "write_only"]

RESULTS = "results.parquet"
MANIFEST = "campaign.json"
_PARTS = "parts"


def rows_to_frame(rows: list[dict]):
    """Rows -> pandas DataFrame (columns in order of first appearance; ``seed`` uint64)."""
    import pandas as pd

    df = pd.DataFrame(rows)
    if "seed" in df:
        df["seed"] = df["seed"].astype("uint64")
    return df


def write_part(out_dir: pathlib.Path, rows: list[dict]) -> pathlib.Path:
    """Write the rows of a finished chunk as a new part file (atomically); returns its path."""
    parts = out_dir / _PARTS
    parts.mkdir(parents=True, exist_ok=True)
    first = min(r["index"] for r in rows)
    name = f"part-{first:08d}-{len(rows)}-{uuid.uuid4().hex[:8]}.parquet"
    tmp = parts / (name + ".tmp")
    rows_to_frame(rows).to_parquet(tmp, index=False)
    os.replace(tmp, parts / name)
    return parts / name


def read_results(out_dir: str | pathlib.Path):
    """All finished runs under ``out_dir`` (results.parquet + part files), one row per index,
    sorted by index (a pandas DataFrame; empty if none)."""
    import pandas as pd

    out_dir = pathlib.Path(out_dir)
    frames = []
    main = out_dir / RESULTS
    if main.is_file():
        frames.append(pd.read_parquet(main))
    parts = out_dir / _PARTS
    if parts.is_dir():
        for p in sorted(parts.glob("part-*.parquet")):
            try:
                frames.append(pd.read_parquet(p))
            except Exception:  # noqa: BLE001 - a torn file (should not happen: atomic rename)
                continue
    frames = [f for f in frames if len(f)]
    if not frames:
        return pd.DataFrame(columns=["index", "seed", "status", "error", "elapsed_s"])
    df = pd.concat(frames, ignore_index=True, sort=False)
    df = df.drop_duplicates(subset="index", keep="first").sort_values("index")
    return df.reset_index(drop=True)


def consolidate(out_dir: pathlib.Path):
    """Parts and table into one ``results.parquet`` (atomically), parts removed; returns
    the table."""
    df = read_results(out_dir)
    tmp = out_dir / (RESULTS + ".tmp")
    df.to_parquet(tmp, index=False)
    os.replace(tmp, out_dir / RESULTS)
    parts = out_dir / _PARTS
    if parts.is_dir():
        for p in parts.glob("part-*"):
            p.unlink()
    return df


def _same(a, b) -> bool:
    return json.dumps(a, sort_keys=True, default=str) == json.dumps(b, sort_keys=True, default=str)


def open_campaign_dir(out_dir: pathlib.Path, manifest: dict, resume: bool) -> set[int]:
    """Make ``out_dir`` hold the campaign ``manifest``; returns the indices already done.

    A new directory gets ``campaign.json``. One that holds a campaign is an ``InputError``
    unless ``resume``, and then its description must equal ``manifest`` (the error names
    the keys that differ)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    mpath = out_dir / MANIFEST
    if mpath.is_file():
        old = json.loads(mpath.read_text())
        if not resume:
            raise InputError("holds a campaign already; use resume or another directory",
                             field="out", file=str(out_dir))
        diff = [k for k in manifest if not _same(old.get(k), manifest[k])]
        if diff:
            raise InputError(f"resume with a different campaign description ({', '.join(diff)})",
                             field="out", file=str(out_dir))
    else:
        tmp = out_dir / (MANIFEST + ".tmp")
        tmp.write_text(json.dumps(manifest, indent=1, default=str))
        os.replace(tmp, mpath)
    return set(read_results(out_dir)["index"].astype(int).tolist())


def read_manifest(out_dir: str | pathlib.Path) -> dict:
    """The description in ``out_dir/campaign.json`` (``InputError`` if there is none)."""
    mpath = pathlib.Path(out_dir) / MANIFEST
    if not mpath.is_file():
        raise InputError("holds no campaign (no campaign.json)", file=str(out_dir))
    return json.loads(mpath.read_text())


def write_only(out_dir: pathlib.Path, index: int, df) -> pathlib.Path:
    """The table of a run re-run alone, as ``out_dir/only-INDEX.parquet``; returns the path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"only-{int(index)}.parquet"
    df.to_parquet(path, index=False)
    return path
