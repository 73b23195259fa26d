"""Any table of numbers as named columns and arrays: the input of a map (:mod:`gnomon.io.mapping`).

``load_table(path)`` reads, whatever the names inside:

==========  ========================================================  =====================
kind        file                                                      read by
==========  ========================================================  =====================
``csv``     text with a header line (``.csv``, ``.tsv``, ``.txt``,    pandas (C parser); the
            ...); the delimiter found from the header (``,`` ``;``    delimiter from the
            tab ``|`` or blanks); lines starting ``#`` and lines of   header line
            metadata with fewer cells before the header are
            skipped, a row of units below it joins the names
            (``gyro_x (deg/s)``)
``mat``     MATLAB v5/v7 or v7.3 (:mod:`gnomon.io.matlab`'s loaders)  scipy.io / h5py
``npz``     numpy ``.npz``                                            numpy
``parquet`` Apache Parquet                                            pyarrow (via pandas)
==========  ========================================================  =====================

and returns a :class:`Table`: ``columns`` (name -> (N,) float; booleans as 0/1) and
``arrays`` (name -> (N, k) float, k = 3 or 4, whichever way the file stores it: a 3×N
array is transposed, the transposition said in ``layout``). A variable of another shape
(a scalar such as a sample rate, a string) is in ``scalars`` when it is one number, else
left out. Non-numeric CSV columns (dates as text) are left out and listed in ``skipped``.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gnomon.errors import InputError

__all__ = ["Table", "load_table", "table_kind", "TABLE_KINDS"]

#: the kinds of file a table (and a map) can be
TABLE_KINDS = ("csv", "mat", "npz", "parquet")

_DELIMITERS = (",", ";", "\t", "|")


@dataclass
class Table:
    """What :func:`load_table` found (module docstring)."""

    path: Path
    kind: str
    columns: dict = field(default_factory=dict)  # name -> (N,) float
    arrays: dict = field(default_factory=dict)  # name -> (N, k) float, k in (3, 4)
    layout: dict = field(default_factory=dict)  # array name -> "3xN", "Nx3", ...
    scalars: dict = field(default_factory=dict)  # name -> float
    skipped: list = field(default_factory=list)  # names left out (not numeric)
    delimiter: str | None = None  # csv: the delimiter read

    def names(self) -> list[str]:
        """Every column and array name, in the file's order."""
        return list(self.columns) + list(self.arrays)


def table_kind(path: str | os.PathLike) -> str:
    """``csv``, ``mat``, ``npz`` or ``parquet`` from a file's first bytes (the suffix when
    they do not tell); an :class:`InputError` for anything else."""
    p = Path(path)
    if not p.is_file():
        raise InputError("no such file", file=str(p))
    with open(p, "rb") as fh:
        head = fh.read(128)
    from gnomon.io.matlab import mat_version

    if mat_version(head) is not None:
        return "mat"
    if head.startswith(b"PAR1"):
        return "parquet"
    if head.startswith(b"PK\x03\x04") and p.suffix.lower() == ".npz":
        return "npz"
    if p.suffix.lower() == ".mat":
        return "mat"
    if b"\x00" not in head:
        return "csv"
    raise InputError("not a table gnomon can map: CSV/TSV text, MATLAB .mat, .npz or "
                     "Parquet", file=str(p))


def load_table(path: str | os.PathLike, kind: str | None = None) -> Table:
    """The named columns and arrays of a CSV/TSV, ``.mat``, ``.npz`` or Parquet file
    (module docstring); ``kind`` forces one of :data:`TABLE_KINDS`."""
    p = Path(path)
    kind = table_kind(p) if kind is None else kind
    if kind not in TABLE_KINDS:
        raise InputError(f"unknown kind {kind!r}; use one of {', '.join(TABLE_KINDS)}",
                         field="kind")
    if kind == "csv":
        return _csv(p)
    if kind == "parquet":
        import pandas as pd

        try:
            frame = pd.read_parquet(p)
        except Exception as err:  # noqa: BLE001 - pyarrow's errors vary
            raise InputError(f"cannot read as Parquet ({err})", file=str(p)) from None
        return _from_frame(p, "parquet", frame)
    if kind == "npz":
        try:
            with np.load(p, allow_pickle=False) as z:
                variables = {k: z[k] for k in z.files}
        except (OSError, ValueError) as err:
            raise InputError(f"cannot read as .npz ({err})", file=str(p)) from None
        return _from_variables(p, "npz", variables)
    from gnomon.io.matlab import _load_v5, _load_v73, mat_version

    with open(p, "rb") as fh:
        version = mat_version(fh.read(128))
    variables = _load_v5(p) if version == "5" else _load_v73(p)
    return _from_variables(p, "mat", variables)


def _header(p: Path, scan: int = 60) -> tuple[int, str]:
    """(lines before the header, the header line) of a text table: the first line that is
    not blank or a ``#`` comment and has as many cells as the data lines (the last of the
    first ``scan`` lines), so that lines of metadata above the header (``Frame Rate,100``)
    are skipped."""
    lines = []
    try:
        with open(p, encoding="utf-8-sig") as fh:
            for i, line in enumerate(fh):
                if line.strip() and not line.lstrip().startswith("#"):
                    lines.append((i, line.rstrip("\r\n")))
                if len(lines) >= scan:
                    break
    except UnicodeDecodeError as err:
        raise InputError(f"not a UTF-8 text file ({err.reason} at byte {err.start})",
                         file=str(p)) from None
    if not lines:
        raise InputError("empty file: no header line", file=str(p))
    last = lines[-1][1]
    delim = max(_DELIMITERS, key=last.count)
    cells = last.count(delim)
    for i, line in lines:
        if cells == 0 or line.count(delim) == cells:
            return i, line
    return lines[0]


def _csv(p: Path) -> Table:
    import pandas as pd

    skip, header = _header(p)
    counts = {d: header.count(d) for d in _DELIMITERS}
    delim = max(counts, key=counts.get)
    if counts[delim] == 0:
        delim = r"\s+" if len(header.split()) > 1 else ","
    try:
        frame = pd.read_csv(p, sep=delim, skiprows=skip, comment=None, skipinitialspace=True,
                            engine="c" if delim != r"\s+" else "python",
                            encoding="utf-8-sig", skip_blank_lines=True)
    except (ValueError, pd.errors.ParserError) as err:
        raise InputError(f"malformed CSV ({' '.join(str(err).split())})", file=str(p)) from None
    if frame.shape[0] == 0:
        raise InputError("no data rows after the header", file=str(p))
    frame.columns = [str(c).strip() for c in frame.columns]
    frame = _units_row(frame)
    table = _from_frame(p, "csv", frame)
    table.delimiter = "whitespace" if delim == r"\s+" else delim
    return table


def _units_row(frame):
    """A first data row of text above numbers (a row of units, ``s, rad/s, ...``) becomes
    part of the names (``gyro_x (rad/s)``) and is dropped."""
    import pandas as pd

    if frame.shape[0] < 2:
        return frame
    text = [c for c in frame.columns if not pd.api.types.is_numeric_dtype(frame[c])]
    if not text:
        return frame
    first = pd.to_numeric(frame[text].iloc[0], errors="coerce")
    rest = frame[text].iloc[1:].apply(pd.to_numeric, errors="coerce")
    if first.notna().any() or rest.isna().all().any():
        return frame
    units = ["" if pd.isna(u) else str(u).strip() for u in frame.iloc[0]]
    out = frame.iloc[1:].apply(pd.to_numeric, errors="coerce").reset_index(drop=True)
    out.columns = [f"{c} ({u})" if u else c for c, u in zip(frame.columns, units, strict=True)]
    return out


def _from_frame(p: Path, kind: str, frame) -> Table:
    import pandas as pd

    t = Table(path=p, kind=kind)
    for name in frame.columns:
        col = frame[name]
        if pd.api.types.is_bool_dtype(col):
            t.columns[str(name)] = col.to_numpy(dtype=float)
        elif pd.api.types.is_numeric_dtype(col):
            t.columns[str(name)] = col.to_numpy(dtype=float, na_value=np.nan)
        else:
            low = col.astype(str).str.strip().str.lower()
            if low.isin(["true", "false", "nan", ""]).all():
                t.columns[str(name)] = np.where(low == "true", 1.0,
                                                np.where(low == "false", 0.0, np.nan))
            else:
                t.skipped.append(str(name))
    return t


def _from_variables(p: Path, kind: str, variables: dict) -> Table:
    """Variables of a .mat/.npz as columns (vectors), arrays (3 or 4 wide) and scalars; the
    length N is the most common long axis (a second length: those are left out)."""
    t = Table(path=p, kind=kind)
    shaped = {}
    for name, v in variables.items():
        a = np.asarray(v)
        if a.dtype.kind not in "biuf":
            t.skipped.append(str(name))
            continue
        a = a.astype(float)
        if a.size == 1:
            t.scalars[str(name)] = float(a.reshape(-1)[0])
        elif a.ndim == 1 or (a.ndim == 2 and 1 in a.shape):
            shaped[str(name)] = (a.reshape(-1), "N")
        elif a.ndim == 2 and (a.shape[1] in (3, 4) or a.shape[0] in (3, 4)):
            if a.shape[1] in (3, 4) and not (a.shape[0] in (3, 4) and a.shape[1] > a.shape[0]):
                shaped[str(name)] = (a, f"Nx{a.shape[1]}")
            else:
                shaped[str(name)] = (a.T, f"{a.shape[0]}xN")
        else:
            t.skipped.append(str(name))
    lengths = [v.shape[0] for v, _ in shaped.values()]
    if not lengths:
        return t
    n = max(set(lengths), key=lambda m: (lengths.count(m), m))
    for name, (a, layout) in shaped.items():
        if a.shape[0] != n:
            t.skipped.append(name)
        elif a.ndim == 1:
            t.columns[name] = a
        else:
            t.arrays[name] = a
            t.layout[name] = layout
    return t


def split_unit(name: str) -> tuple[str, str | None]:
    """``"Gyroscope X (rad/s)"`` -> ``("Gyroscope X", "rad/s")``: a unit in brackets at the
    end of a column name, removed."""
    m = re.match(r"^(.*?)\s*[\(\[]\s*([^\)\]]*)\s*[\)\]]\s*$", name)
    return (m.group(1), m.group(2)) if m else (name, None)
