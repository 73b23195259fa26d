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
from gnomon.kernels.entry import BAD_GYRO, NO_SAMPLE, vec3
from gnomon.recording import Recording

__all__ = ["Params", "Estimate", "Estimator", "CompiledIMUUpdate", "param", "imu_buffer"]


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
        """The values by name (a new dict; built once per instance: a frozen instance never
        changes, and a live filter asks at every chunk)."""
        cached = self.__dict__.get("_as_dict")
        if cached is None:
            cached = dataclasses.asdict(self)
            object.__setattr__(self, "_as_dict", cached)
        return dict(cached)

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


def imu_buffer(dt_s, gyro_rad_s, accel_m_s2=None, mag_uT=None):
    """The inputs of an IMU filter's ``update_many`` checked and in kernel form: ``dt_s``
    (N,) s, ``gyro_rad_s`` (N, 3), ``accel_m_s2``, ``mag_uT`` (N, 3) (None: no sample of
    that sensor at all, a NaN array; a row with any non-finite value: no sample in that
    row). Returns the four as float64 arrays (the arrays themselves when they already
    are: strided views are fine for the kernels). Raises ``InputError`` naming the
    argument for a wrong shape, a non-finite or negative ``dt_s`` or a non-finite gyro
    row."""
    dt = np.asarray(dt_s, dtype=float)
    if dt.ndim != 1:
        raise InputError(f"expected shape (N,), got {dt.shape}", field="dt_s")
    n = dt.shape[0]
    bad = np.flatnonzero(~(np.isfinite(dt) & (dt >= 0.0)))
    if bad.size:
        raise InputError(f"must be finite and >= 0, got {dt[bad[0]]!r}", field="dt_s",
                         row=int(bad[0]))
    out = [dt]
    for name, x in (("gyro_rad_s", gyro_rad_s), ("accel_m_s2", accel_m_s2), ("mag_uT", mag_uT)):
        if x is None:
            if name == "gyro_rad_s":
                raise InputError("a gyro sample is needed in every row", field=name)
            out.append(np.full((n, 3), np.nan))
            continue
        x = np.asarray(x, dtype=float)
        if x.shape != (n, 3):
            raise InputError(f"expected shape ({n}, 3), got {x.shape}", field=name)
        bad = ~np.isfinite(x).all(axis=1)
        if name == "gyro_rad_s" and bad.any():
            k = int(np.argmax(bad))
            raise InputError(f"non-finite value {x[k].tolist()}", field=name, row=k)
        if bad.any():  # a partly broken sample is no sample (a NaN row), as in ``update``
            x = x.copy()
            x[bad] = np.nan
        out.append(x)
    return tuple(out)


class Estimator:
    """Base class: ``Params`` + state + ``reset`` / ``update`` / ``update_many`` / ``run``.

    ``update`` (one sample) and ``update_many`` (a buffer of samples) run the compiled
    kernel on the filter's own state: any split of a recording into such calls gives
    ``run``'s result. ``update_reference``, where a filter has one, is the readable twin
    of ``update`` that the tests hold the compiled paths to."""

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

    def prepare(self, rec: Recording) -> None:
        """Start a fresh filter as ``run(rec)`` does before its first sample (the initial
        attitude from ``rec``'s first samples, nominal sample times), without processing a
        sample: the rows of ``rec`` then fed through ``update``/``update_many`` in any
        split (``sample_inputs``, ``buffer_inputs``) give ``run(rec)``'s result. A filter
        that starts from its first ``update`` alone needs nothing here."""

    def sample_inputs(self, rec: Recording):
        """The rows of ``rec`` as ``update`` takes them: an iterator of ``(args, kwargs)``,
        one per gyro sample (``dt_s`` 0 at the first; a sensor without a new sample in that
        row is None). The IMU form ``(dt_s, gyro, accel, mag)``; filters with other inputs
        override it."""
        args, kwargs = self.buffer_inputs(rec)
        dt, gyro, acc, mag = args
        for k in range(len(dt)):
            a = None if acc is None or acc[k, 0] != acc[k, 0] else acc[k]
            m = None if mag is None or mag[k, 0] != mag[k, 0] else mag[k]
            yield (dt[k], gyro[k], a, m), {key: v[k] for key, v in kwargs.items()}

    def buffer_inputs(self, rec: Recording):
        """The whole of ``rec`` as ``update_many`` takes it: ``(args, kwargs)`` of arrays
        with the gyro samples along their first axis (slices of them along it are the
        inputs of a part of ``rec``). The IMU form ``(dt_s, gyro, accel, mag)`` with NaN rows
        where a sensor has no new sample; filters with other inputs override it."""
        dt = np.diff(rec.t, prepend=rec.t[0])
        return (dt, rec.gyro, rec.on_time_base("accel"), rec.on_time_base("mag")), {}

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


_ND = np.ndarray
_F8 = np.dtype(np.float64)
_S3 = (3,)
_INF = float("inf")


class CompiledIMUUpdate:
    """``update`` of an IMU filter through its compiled sample kernel (mixed into the
    filter's class before ``Estimator``).

    The filter provides ``_sample_kernel(dt_s, accel, mag)``: called at the first
    ``update`` after ``reset`` (the state may still need its start: an initial attitude,
    nominal sample times), it returns ``(kernel, coefficients)``: a numba kernel
    ``kernel(dt_s, gyro, acc, mag, state, coefficients, q_out) -> flags`` (``gyro``, ``acc``,
    ``mag`` (3,) float64, NaN in ``acc``/``mag``: no sample; ``q_out`` (4,) written with
    the estimate; ``flags`` the kernel's bits, ``BAD_GYRO`` for a non-finite gyro sample
    that changed nothing) and its coefficients as a record (``gnomon.kernels.entry.record``:
    unboxed per call at the cost of one array, where a named tuple of 50 numbers costs a
    microsecond). ``flag_bits`` names the bits for ``flags``.

    Per call: the inputs' types are checked inline (a float64 (3,) array passes as it is;
    anything else goes through ``vec3``), then one call of the compiled entry point
    (``gnomon.kernels.entry.entry_point``); the result is a fresh (4,) array.
    """

    #: flag name -> bit of the sample kernel's flags (``flags``)
    flag_bits: ClassVar[dict[str, int]] = {}

    def _sample_kernel(self, dt_s, accel, mag):  # pragma: no cover - every filter overrides
        raise NotImplementedError

    def _reset_sample_path(self) -> None:
        """Called by the filter's ``reset``: the next ``update`` looks its kernel up again."""
        self._sample = None
        self._flags = 0

    def set_state(self, state: dict) -> None:
        """``Estimator.set_state``, then the compiled path is looked up again (the state's
        coefficients may differ)."""
        super().set_state(state)
        self._reset_sample_path()

    @property
    def flags(self) -> dict[str, bool]:
        """What the last ``update`` did, by name (``flag_bits``)."""
        f = getattr(self, "_flags", 0)
        return {name: bool(f & bit) for name, bit in self.flag_bits.items()}

    def _compile_sample(self, dt_s, g, a, m):
        from gnomon.kernels.entry import entry_point

        if not np.all(np.isfinite(g)):  # before the state starts from this sample
            raise InputError(f"non-finite value {g.tolist()} (the sample was not used)",
                             field="gyro_rad_s")

        kernel, coefficients = self._sample_kernel(dt_s, None if a is NO_SAMPLE else a,
                                                   None if m is NO_SAMPLE else m)
        self._q_now = np.zeros(4)
        self._coefficients_record = coefficients
        self._sample = entry_point(kernel, 0.0, g, a, m, self.state, coefficients,
                                   self._q_now)
        return self._sample

    def update(self, dt_s: float, gyro_rad_s, accel_m_s2=None, mag_uT=None) -> np.ndarray:
        """One sample through the compiled kernel (the arithmetic of ``run``): ``dt_s`` (s)
        since the previous sample (0 at the first), ``gyro_rad_s`` (3,), ``accel_m_s2``
        (3,) m/s², ``mag_uT`` (3,) µT, body frame; None (or a NaN) is no new sample of that
        sensor. Returns the estimate ``q_rb`` (4,); ``flags`` says what the sample did.
        ``update_reference`` is the readable twin. A non-finite gyro sample raises
        ``InputError`` and changes nothing."""
        g, a, m = gyro_rad_s, accel_m_s2, mag_uT
        if not (type(g) is _ND and g.dtype is _F8 and g.shape == _S3):
            g = vec3(g, "gyro_rad_s")
        if a is None:
            a = NO_SAMPLE
        elif not (type(a) is _ND and a.dtype is _F8 and a.shape == _S3):
            a = vec3(a, "accel_m_s2")
        if m is None:
            m = NO_SAMPLE
        elif not (type(m) is _ND and m.dtype is _F8 and m.shape == _S3):
            m = vec3(m, "mag_uT")
        if not 0.0 <= dt_s < _INF:
            raise InputError(f"must be finite and >= 0, got {dt_s!r}", field="dt_s")
        sample = self._sample
        if sample is None:
            sample = self._compile_sample(dt_s, g, a, m)
        f = sample(dt_s, g, a, m, self.state, self._coefficients_record, self._q_now)
        self._flags = f
        if f & BAD_GYRO:
            raise InputError(f"non-finite value {g.tolist()} (the sample was not used)",
                             field="gyro_rad_s")
        return self._q_now.copy()
