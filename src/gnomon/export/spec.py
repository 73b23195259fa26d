"""What an exported filter's C twin is made of (``FilterSpec``)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["FilterSpec"]


@dataclass(frozen=True)
class FilterSpec:
    """What a filter's C twin is made of (files in ``gnomon/export/c``).

    ``params``: the C parameter struct's fields in order, each a ``Params`` field name of
    the filter or a name that ``values(params)`` computes (a derived value);
    ``runner``: the runner's source (``runner_imu.c`` for the IMU filters); ``adapter``:
    its ``runner_adapter.h``; ``defines``: lines for ``gnomon_config.h``; ``phases``: the
    adapter defines ``GN_ADAPTER_PHASES`` (``gnomon_run --phases``: ns and operations per
    phase of the step, into ``cost.json``); ``signals``: the columns of the adapter's
    ``gn_adapter_signals`` (``GN_N_SIGNALS``), each (name, width, dtype) in the order of
    the Python ``Estimate.signals`` (``gnomon estimate --backend c`` returns them; none:
    the attitude alone); ``streams``: its adapter starts from the nominal sample times
    alone (no rows), so it runs as a streaming filter from Python
    (``gnomon.export.backend.c_filter_class``, ``gnomon live``)."""

    filter: str
    prefix: str
    sources: tuple[str, ...]
    headers: tuple[str, ...]
    adapter: str
    runner: str = "runner_imu.c"
    defines: tuple[str, ...] = ()
    params: tuple[str, ...] = ()
    values: object = None  # callable(params) -> {c field: value} for computed fields
    kind: str = "imu"
    phases: bool = False
    signals: tuple[tuple[str, int, str], ...] = ()
    streams: bool = False
