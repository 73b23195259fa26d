"""The estimator interface every gnomon filter follows.

* ``Params``: a frozen dataclass of tuning values in SI units with defaults.
  ``Params.from_dict`` rejects unknown names (a typo raises, naming it) and
  converts command-line strings; ``validate`` checks ranges.
* ``Estimator``: holds ``params`` and the evolving state. ``reset()`` returns it
  to a fresh instance's state, ``update(...)`` processes one sample (streaming
  use), ``run(recording)`` processes a whole ``Recording`` and returns an
  ``Estimate`` with the attitude and the filter's internal signals (bias
  estimate, rejection flags, ...).

Streaming ``update``: one argument order for every filter,

    update(dt_s, gyro_rad_s=None, accel_m_s2=None, mag_uT=None, *, <other inputs>) -> q

``dt_s`` is the time since the previous sample (s; 0 at the first), then the
IMU's three sensors in the body frame (rad/s, m/s², µT); a filter that needs
other inputs (sun sensor, reference vectors, orbital rate, a measured
quaternion) takes them as keyword-only arguments whose names say frame and
unit (``sun_b``, ``mag_ref_o``: directions, any unit; ``w_io_o_rad_s``). ``None`` means "no new
sample of that sensor at this instant": the filter only uses a measurement
when it is new. The return value is the attitude estimate after the sample,
``q_rb`` (4,) in the filter's reference frame (``reference_frame``).

Adding a filter: its module in ``gnomon.estimators`` (``Params`` + ``Estimator``
with the readable ``update`` and ``run``), its compiled twin in ``gnomon.kernels``
(optional), one line in ``gnomon.estimators.registry``, and its tests. The
command line, benchmarks, campaigns and docs' filter tables find it through
the registry and these class attributes.
"""

from __future__ import annotations

import dataclasses
import functools
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from gnomon.errors import InputError
from gnomon.recording import Recording

__all__ = ["Params", "Estimate", "Estimator", "param"]


def param(default, unit: str = "", doc: str = ""):
    """A ``Params`` field with its unit and a one-line description (shown by ``gnomon filters``)."""
    return field(default=default, metadata={"unit": unit, "doc": doc})


_BOOL_WORDS = {"1": True, "true": True, "yes": True, "on": True,
               "0": False, "false": False, "no": False, "off": False}


def _convert(name: str, kind: type, value: Any):
    if isinstance(value, str):
        if kind is bool:
            if value.lower() not in _BOOL_WORDS:
                raise InputError(f"expected true/false, got {value!r}", field=name)
            return _BOOL_WORDS[value.lower()]
        try:
            return kind(value)
        except ValueError:
            raise InputError(f"expected {kind.__name__}, got {value!r}", field=name) from None
    if kind is float and isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    if kind is int and isinstance(value, int) and not isinstance(value, bool):
        return value
    if isinstance(value, kind):
        return value
    raise InputError(f"expected {kind.__name__}, got {value!r}", field=name)


@functools.cache
def _type_hints(cls) -> dict:
    return typing.get_type_hints(cls)


@dataclass(frozen=True)
class Params:
    """Base class of every filter's tuning values (frozen; SI units; see ``describe``).

    ``renamed`` maps former parameter names to their new ones: an old name raises an
    error that names the new one (a renamed unit must not be read silently)."""

    renamed: ClassVar[dict[str, str]] = {}

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and not np.isfinite(v):
                raise InputError(f"must be finite, got {v!r}", field=f.name)
        self.validate()

    def validate(self) -> None:
        """Override to check ranges; raise ``InputError(field=name)``."""

    def _require(self, name: str, ok: bool, what: str) -> None:
        if not ok:
            raise InputError(f"{what}, got {getattr(self, name)!r}", field=name)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]):
        """Build from a mapping (e.g. parsed ``--param KEY=VALUE``); unknown names raise."""
        if not values:
            return cls()
        hints = _type_hints(cls)
        known = {f.name for f in dataclasses.fields(cls)}
        kwargs = {}
        for key, value in values.items():
            if key in cls.renamed:
                raise InputError(f"renamed: use {cls.renamed[key]!r} (check its unit with "
                                 f"`gnomon filters`)", field=key)
            if key not in known:
                raise InputError(
                    f"unknown parameter for {cls.__qualname__}; known: {', '.join(sorted(known))}",
                    field=key,
                )
            kwargs[key] = _convert(key, hints[key], value)
        return cls(**kwargs)

    def replace(self, **changes):
        """A copy with some values changed (same validation)."""
        return type(self).from_dict({**dataclasses.asdict(self), **changes})

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def describe(cls) -> list[dict]:
        """Name, default, unit and description of every parameter."""
        return [
            {"name": f.name, "default": f.default, "unit": f.metadata.get("unit", ""),
             "doc": f.metadata.get("doc", "")}
            for f in dataclasses.fields(cls)
        ]


@dataclass
class Estimate:
    """What a filter's batch run returns.

    ``q`` (N, 4) is the estimate ``q_rb`` ``[w, x, y, z]``: reference frame r
    (``frames['reference']``, the same as the recording's) from body b.
    ``signals`` holds internal time series (N, ...), e.g. ``bias_rad_s`` (N, 3)
    and boolean flags such as ``acc_rejected``.
    """

    t: np.ndarray
    q: np.ndarray
    estimator: str
    params: dict
    frames: dict = field(default_factory=dict)
    signals: dict = field(default_factory=dict)


class Estimator:
    """Base class: ``Params`` + state + ``reset`` / ``update`` / ``run``."""

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    #: Where the method comes from (shown in the filter tables).
    paper: ClassVar[str] = ""
    Params: ClassVar[type[Params]] = Params
    #: Recording fields the filter needs (checked by ``run`` with a clear error).
    needs: ClassVar[tuple[str, ...]] = ("gyro",)
    #: ``"imu"`` (a body moving near the Earth, navigation frame ENU) or ``"spacecraft"``
    #: (a satellite, orbital frame): which benchmarks, scenarios and defaults apply.
    kind: ClassVar[str] = "imu"
    #: The reference frame the filter estimates against; ``check_inputs`` refuses a
    #: recording whose ``frames['reference']`` names another one (None: any).
    reference_frame: ClassVar[str | None] = None
    #: Whether ``run`` takes sensors at their own rates (``Recording.on_time_base``: a
    #: measurement is used only in its arrival row); a filter that does not refuses a
    #: multi-rate recording rather than misreading it.
    multi_rate: ClassVar[bool] = False
    #: Whether the filter needs the whole recording (forward and backward passes; no
    #: streaming ``update``): its name ends in ``-offline``, causal benchmarks leave it out.
    offline: ClassVar[bool] = False
    #: Attributes that make up the evolving state (saved by ``get_state``).
    state_fields: ClassVar[tuple[str, ...]] = ()

    def __init__(self, params: Params | None = None, **overrides):
        if params is None:
            params = self.Params.from_dict(overrides)
        elif overrides:
            params = params.replace(**overrides)
        if not isinstance(params, self.Params):
            raise TypeError(f"params must be {self.Params.__qualname__}, got {type(params)}")
        self.params = params
        self.reset()

    def reset(self) -> None:  # pragma: no cover - every filter overrides
        raise NotImplementedError

    def run(self, rec: Recording) -> Estimate:  # pragma: no cover - every filter overrides
        raise NotImplementedError

    @classmethod
    def run_many(cls, recs: list[Recording], params: Params | None = None) -> list[np.ndarray]:
        """``q`` (N_k, 4) of a fresh filter run on each of ``recs`` (Monte Carlo runs).

        One by one here; a filter with a batch-over-runs kernel overrides it (same
        results to 1e-12), and the campaign runner calls it for the runs of a chunk
        that share the filter and its parameters."""
        return [cls(params).run(rec).q for rec in recs]

    def get_state(self) -> dict:
        """A copy of the evolving state; ``set_state`` on a fresh instance resumes exactly."""
        import copy

        return {name: copy.deepcopy(getattr(self, name)) for name in self.state_fields}

    def set_state(self, state: dict) -> None:
        """Restore a state from ``get_state`` (unknown or missing names raise)."""
        import copy

        if set(state) != set(self.state_fields):
            raise InputError(f"expected state fields {sorted(self.state_fields)}, "
                             f"got {sorted(state)}", field="state")
        for name, value in state.items():
            setattr(self, name, copy.deepcopy(value))

    def first_dt(self, rec: Recording) -> float:
        """Interval before ``rec``'s first sample: 0 for a fresh filter, else since the last
        sample this filter processed (so a run split in two equals the whole run)."""
        t_last = getattr(self, "t_last", None)
        if t_last is None:
            return 0.0
        dt = float(rec.t[0] - t_last)
        if dt <= 0.0:
            raise InputError(f"recording starts at t = {rec.t[0]!r}, not after the filter's "
                             f"last sample t = {t_last!r}", field="t", row=0)
        return dt

    def check_inputs(self, rec: Recording) -> None:
        """Raise ``InputError`` naming the first field the filter needs that ``rec`` lacks,
        or the reference frame when it is not the filter's ``reference_frame``."""
        for name in self.needs:
            present = (rec.extra.get(name[6:]) is not None if name.startswith("extra.")
                       else getattr(rec, name) is not None)
            if not present:
                raise InputError(f"filter '{self.name}' needs it; the recording has none",
                                 field=name, file=rec.source or None)
        if not self.multi_rate and not rec.single_rate:
            rates = ", ".join(f"{n} {rec.rate_hz(n):.4g} Hz" for n in ("gyro", "accel", "mag")
                              if n == "gyro" or getattr(rec, n) is not None)
            raise InputError(f"filter '{self.name}' needs every sensor on the gyro's time "
                             f"stamps; the recording has its own rates ({rates})",
                             field="t", file=rec.source or None)
        ref = rec.frames.get("reference")
        if self.reference_frame is not None and ref is not None and ref != self.reference_frame:
            raise InputError(f"filter '{self.name}' estimates against {self.reference_frame}; "
                             f"the recording's reference frame is {ref!r} (convert the truth "
                             f"and frames at the reader, see docs/conventions.md)",
                             field="frames.reference", file=rec.source or None)
