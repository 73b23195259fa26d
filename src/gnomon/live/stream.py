"""Sensors as they arrive: time-stamped samples of each sensor, on its own rate and clock,
turned into the rows a filter runs on, as ``Recording.on_time_base`` makes them.

:class:`LiveFilter` takes one sample at a time (``push("gyro" | "accel" | "mag", t_s,
value)``, VQF's ``updateGyr``/``updateAcc``/``updateMag`` as the model) and returns the
estimates it could make so far. The rules (the batch ones, so that a recording replayed
sample by sample gives ``run``'s result):

* **Rows.** Each gyro sample is a row; the accelerometer and magnetometer samples whose
  stamps fall in ``(t[k-1], t[k]]`` belong to row ``k`` (their mean when several do), a row
  without one has no sample of that sensor. Nothing is held or interpolated.
* **Order.** A row is run when a gyro sample at least half a gyro period later has
  arrived (``hold_periods``): a sample of any sensor that arrives late by less than that
  still lands in its own row, in order. One that arrives after its row ran is used in the
  next row (counted ``late``), never dropped silently and never used twice.
* **Start.** The first ``warmup_samples`` rows are collected before any runs; the filter
  is then started from them exactly as ``run`` starts from a recording (``prepare``:
  the initial attitude, nominal sample times), and they run. A stream that ends sooner
  starts from what it has.
* **Clocks.** A sensor whose stamps are more than ``clock_tolerance_s`` away from the
  gyro's on its first sample is on a clock of its own: its stamps are shifted onto the
  gyro's (``clock_offset``, once per sensor). A stamp that jumps (its step differs from
  the step of the arrival times by more than ``clock_tolerance_s``: a reboot, a clock set
  forward or back) re-anchors that sensor's clock at its arrival (``clock_jump``); the gyro
  row after a jump runs with the nominal period. A gyro stamp that is not later than the
  last one run (a repeat, a small step back) is dropped (``out_of_order``); sensor samples
  with a non-finite value are dropped (``invalid``).
* **Never NaN, never an exception.** A filter that raises on a row, or whose estimate is
  not finite, is counted (``filter_errors``) and started again from the next rows
  (``restarts``); ``push`` never raises for bad data.

Time: ``t_s`` is the sensor's own stamp (s); ``arrival_s`` the time the sample was
received on this computer's monotonic clock (``time.perf_counter``) or, for a replay, the
replay's clock. Values: gyro rad/s, accelerometer m/s², magnetometer µT, body frame.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate
from gnomon.recording import Recording

__all__ = ["LiveFilter", "StreamStats", "SENSORS"]

SENSORS = ("gyro", "accel", "mag")


@dataclass
class StreamStats:
    """What a :class:`LiveFilter` has seen: counts of samples and of every fault."""

    samples: dict = field(default_factory=lambda: dict.fromkeys(SENSORS, 0))
    rows: int = 0  #: rows run (estimates made)
    late: int = 0  #: sensor samples used in the row after their own (arrived after it ran)
    out_of_order: int = 0  #: gyro samples not later than the last row run: dropped
    invalid: int = 0  #: samples with a non-finite value or a wrong shape: dropped
    clock_offset: dict = field(default_factory=dict)  #: sensor -> offset (s) onto the gyro's
    clock_jumps: int = 0  #: stamps that jumped against the arrival times (re-anchored)
    gaps: int = 0  #: rows after an interval longer than the filter's max_dt_s
    filter_errors: int = 0  #: rows the filter refused (raised) or made non-finite
    restarts: int = 0  #: times the filter was started again after an error
    last_error: str = ""

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class _Clock:
    """One sensor's stamps mapped onto the gyro's clock: an offset, re-anchored on jumps."""

    def __init__(self):
        self.offset = None  # s, added to the sensor's stamps
        self.last = None  # (stamp, arrival) of the previous sample

    def map(self, stamp: float, arrival: float, tolerance: float) -> tuple[float, bool]:
        """The stamp on the gyro's clock, and whether it jumped (re-anchored)."""
        jumped = False
        if self.last is not None:
            step, waited = stamp - self.last[0], arrival - self.last[1]
            if abs(step - waited) > tolerance:
                self.offset = (self.last[0] + self.offset) + waited - stamp
                jumped = True
        self.last = (stamp, arrival)
        return stamp + self.offset, jumped


class LiveFilter:
    """A causal gnomon filter fed by per-sensor samples as they arrive (module docstring).

    ``filter``: an estimator from ``gnomon.make_filter`` (an IMU filter with ``update_many``).
    ``push`` returns a list of ``Estimate`` chunks (possibly empty): the rows that could be
    run, with every signal the filter's ``run`` returns. ``flush`` runs what is left (end
    of stream). ``stats`` counts samples and faults.
    """

    def __init__(self, filter, *, warmup_samples: int = 101, hold_periods: float = 0.5,
                 clock_tolerance_s: float = 1.0, nominal_dt_s: float | None = None):
        if getattr(filter, "offline", False) or not hasattr(filter, "update_many"):
            raise InputError(f"filter '{filter.name}' cannot run live (it needs the whole "
                             "recording)", field="--filter")
        if warmup_samples < 1:
            raise InputError(f"must be >= 1, got {warmup_samples!r}", field="warmup_samples")
        self.filter = filter
        self.fresh = type(filter)(filter.params)  # a filter to restart from
        self.warmup_samples = int(warmup_samples)
        self.hold_periods = float(hold_periods)
        self.clock_tolerance_s = float(clock_tolerance_s)
        self.nominal_dt_s = nominal_dt_s  # s, the gyro period (estimated when None)
        self.stats = StreamStats()
        self._clocks = {name: _Clock() for name in SENSORS}
        self._pending = {name: [] for name in SENSORS}  # sorted [(t on gyro clock, value)]
        self._arrivals = []  # arrival times of the pending gyro rows (same order)
        self._t_run = None  # time of the last row run (gyro clock)
        self._newest = -math.inf  # newest gyro stamp seen (gyro clock)
        self._started = False
        self._warm = {name: [] for name in SENSORS}  # the warm-up rows' raw samples
        self._dt_after_jump = False
        self.row_arrivals: list[float] = []  # arrival time of each row's gyro sample, last push
        self._load_kernels()

    def _load_kernels(self) -> None:
        """Run a copy of the filter on three resting rows, so that its compiled code is
        loaded (or compiled) now, not while the first samples queue up behind it."""
        t = np.array([0.0, 0.01, 0.02])
        rec = Recording(t=t, gyro=np.zeros((3, 3)), accel=np.tile([0.0, 0.0, 9.81], (3, 1)),
                        mag=np.tile([0.0, 20.0, -40.0], (3, 1)), mag_unit="uT",
                        frames={"reference": "ENU", "body": "sensor"})
        try:
            f = type(self.fresh)(self.fresh.params)
            f.prepare(rec)
            f.update_many(np.diff(t, prepend=0.0), rec.gyro, rec.accel, rec.mag, t_s=t)
        except (InputError, ValueError, TypeError):  # a filter that cannot: it loads later
            pass

    # ------------------------------------------------------------------ intake
    def push(self, sensor: str, t_s: float, value, arrival_s: float | None = None
             ) -> list[Estimate]:
        """One sample of ``sensor`` (``"gyro"``, ``"accel"``, ``"mag"``) stamped ``t_s`` (s,
        its own clock; NaN: stamped on arrival), ``value`` (3,) in SI units (µT for the
        magnetometer). Returns the estimates this sample completed."""
        try:
            v = np.asarray(value, dtype=float).reshape(3)
            t = float(t_s)
            arrival = float(t if arrival_s is None else arrival_s)
        except (TypeError, ValueError):
            self.stats.invalid += 1
            return []
        if sensor not in self._clocks:
            self.stats.invalid += 1
            return []
        if not (np.all(np.isfinite(v)) and math.isfinite(arrival)):
            self.stats.invalid += 1
            return []
        t = arrival if not math.isfinite(t) else t
        self.stats.samples[sensor] += 1
        t = self._on_gyro_clock(sensor, t, arrival)
        if sensor == "gyro":
            if self._t_run is not None and t <= self._t_run:
                self.stats.out_of_order += 1
                return []
            self._insert(sensor, t, v, arrival)
            self._newest = max(self._newest, t)
        else:
            self._insert(sensor, t, v, arrival)
        return self._run_ready(final=False)

    def flush(self) -> list[Estimate]:
        """Run every row still held (the end of the stream)."""
        return self._run_ready(final=True)

    def poll(self, now_s: float, timeout_s: float = 0.05) -> list[Estimate]:
        """Run the rows whose gyro sample arrived more than ``timeout_s`` before ``now_s``
        (the arrival clock) and still waits for a later one: a stream that pauses or ends
        does not hold its last estimate back. Called by the live loop when nothing
        arrives."""
        if not self._arrivals or now_s - self._arrivals[0] <= timeout_s or not self._started:
            return []
        n = sum(1 for a in self._arrivals if now_s - a > timeout_s)
        t, gyro, acc, mag, arrivals, _ = self._take(n)
        return self._run(t, gyro, acc, mag, arrivals)

    def _on_gyro_clock(self, sensor: str, t: float, arrival: float) -> float:
        clock = self._clocks[sensor]
        if clock.offset is None:
            offset = 0.0
            ref = self._clocks["gyro"]
            if sensor != "gyro" and ref.last is not None:
                gyro_now = ref.last[0] + ref.offset + (arrival - ref.last[1])
                if abs(t - gyro_now) > self.clock_tolerance_s:
                    offset = gyro_now - t
                    self.stats.clock_offset[sensor] = offset
            clock.offset = offset
        mapped, jumped = clock.map(t, arrival, self.clock_tolerance_s)
        if jumped:
            self.stats.clock_jumps += 1
            if sensor == "gyro":
                self._dt_after_jump = True
        return mapped

    def _insert(self, sensor: str, t: float, v: np.ndarray, arrival: float) -> None:
        rows = self._pending[sensor]
        if not rows or rows[-1][0] <= t:  # in order: the usual case
            i = len(rows)
        else:
            i = bisect.bisect_right(rows, t, key=lambda r: r[0])
        rows.insert(i, (t, v))
        if sensor == "gyro":
            self._arrivals.insert(i, arrival)

    # ------------------------------------------------------------------ rows
    def _period(self) -> float:
        """The gyro's nominal period (s): given, else the median interval of the first
        rows (fixed at the start; 0 before two gyro samples)."""
        if self.nominal_dt_s is not None:
            return self.nominal_dt_s
        g = self._pending["gyro"]
        if len(g) < 2:
            return 0.0
        dt = float(np.median(np.diff([r[0] for r in g[:101]])))
        if self._started or len(g) > 100:
            self.nominal_dt_s = dt
        return dt

    def _ready_rows(self, final: bool) -> int:
        """How many of the earliest pending gyro rows can run now."""
        g = self._pending["gyro"]
        if final:
            return len(g)
        if self.hold_periods <= 0.0:  # no hold: a row runs on its gyro sample
            return len(g)
        limit = self._newest - self.hold_periods * self._period()
        n = 0
        while n < len(g) and g[n][0] <= limit and g[n][0] < self._newest:
            n += 1
        return n

    def _take(self, n: int):
        """The next ``n`` rows as arrays (``t``, gyro, accel, mag with NaN rows) and the
        raw samples they hold (for a warm-up recording)."""
        g = self._pending["gyro"][:n]
        del self._pending["gyro"][:n]
        arrivals = self._arrivals[:n]
        del self._arrivals[:n]
        t = np.array([r[0] for r in g])
        gyro = np.array([r[1] for r in g]).reshape(n, 3)
        out, raw = {}, {"gyro": g}
        for name in ("accel", "mag"):
            rows = np.full((n, 3), np.nan)
            taken = []
            samples = self._pending[name]
            j = 0
            for k in range(n):
                acc, count = np.zeros(3), 0
                while j < len(samples) and samples[j][0] <= t[k]:
                    if self._t_run is not None and samples[j][0] <= self._t_run and k == 0:
                        self.stats.late += 1
                    acc = acc + samples[j][1] if count else samples[j][1].copy()
                    count += 1
                    taken.append(samples[j])
                    j += 1
                if count:
                    rows[k] = acc / count
            del samples[:j]
            out[name] = rows
            raw[name] = taken
        return t, gyro, out["accel"], out["mag"], arrivals, raw

    def _run_ready(self, final: bool) -> list[Estimate]:
        n = self._ready_rows(final)
        if not self._started:
            if n < self.warmup_samples and not (final and n):
                return []
            n = len(self._pending["gyro"]) if final else n
        if n == 0:
            return []
        t, gyro, acc, mag, arrivals, raw = self._take(n)
        if not self._started:
            for name in SENSORS:
                self._warm[name].extend(raw[name])
            if not self._start(t):
                return []
        return self._run(t, gyro, acc, mag, arrivals)

    def _start(self, t) -> bool:
        """Start the filter from the warm-up samples as ``run`` starts from a recording."""
        w = self._warm
        try:
            rec = Recording(t=np.array([r[0] for r in w["gyro"]]),
                            gyro=np.array([r[1] for r in w["gyro"]]),
                            accel=_stack(w["accel"]), accel_t=_times(w["accel"]),
                            mag=_stack(w["mag"]), mag_t=_times(w["mag"]), mag_unit="uT",
                            frames={"reference": "ENU", "body": "sensor"})
            self.filter.check_inputs(rec)
            self.filter.prepare(rec)
        except (InputError, ValueError) as err:
            self.stats.filter_errors += 1
            self.stats.last_error = str(err)
            return False
        self._started = True
        self._warm = {name: [] for name in SENSORS}
        return True

    def _run(self, t, gyro, acc, mag, arrivals) -> list[Estimate]:
        dt = np.diff(t, prepend=t[0] if self._t_run is None else self._t_run)
        if self._dt_after_jump:  # the row after a clock jump: the nominal period
            dt[0] = self._period() or 0.0
            self._dt_after_jump = False
        max_dt = getattr(self.filter.params, "max_dt_s", math.inf)
        self.stats.gaps += int(np.count_nonzero(dt > max_dt))
        self._t_run = float(t[-1])
        try:
            est = self.filter.update_many(dt, gyro, acc, mag, t_s=t)
            if not np.all(np.isfinite(est.q)):
                raise InputError("the estimate is not finite", field="q")
        except (InputError, ValueError, ArithmeticError) as err:
            self.stats.filter_errors += 1
            self.stats.last_error = str(err)
            self._restart()
            return []
        self.stats.rows += len(t)
        self.row_arrivals = arrivals
        return [est]

    def _restart(self) -> None:
        """After a filter error: a fresh filter, started from the next rows."""
        self.filter = type(self.fresh)(self.fresh.params)
        self._started = False
        self.stats.restarts += 1


def _stack(samples) -> np.ndarray | None:
    return np.array([s[1] for s in samples]).reshape(-1, 3) if samples else None


def _times(samples) -> np.ndarray | None:
    return np.array([s[0] for s in samples]) if samples else None
