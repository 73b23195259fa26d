"""Scenarios: a YAML file (or a shipped preset) that fully describes a simulated run.

Two kinds: a spacecraft in orbit (the default; ``gnomon.scenarios.simulator``) and,
with ``kind: imu``, an IMU on the ground (``gnomon.simulation.ahrs``).

>>> sc = load_scenario("seed000")                 # a preset name or a path to a .yaml file
>>> sc2 = sc.replace({"sensors.magnetometer.noise_nT": 500.0, "duration_s": 600.0})
>>> rec = simulate(sc2)                           # -> gnomon.recording.Recording

Keys, defaults and units: :data:`gnomon.scenarios.schema.SCHEMA` and
``IMU_SCHEMA`` (``describe(kind)`` lists them). Unknown keys are rejected by their
dotted name, before any simulation.
"""

from __future__ import annotations

import copy
import pathlib
from dataclasses import dataclass, field
from importlib import resources
from typing import Any

import yaml

from gnomon.errors import InputError
from gnomon.scenarios.schema import KINDS, get_dotted, schema_of, set_dotted, validate

__all__ = ["Scenario", "load_scenario", "list_presets", "simulate", "simulate_many",
           "describe"]


@dataclass(frozen=True, eq=False)
class Scenario:
    """A validated scenario: ``config`` is the full nested dict (defaults filled in)."""

    config: dict
    source: str = ""
    _user: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_dict(cls, d: dict, source: str = "") -> Scenario:
        """Validate a nested dict (missing keys take their defaults)."""
        return cls(validate(d), source, copy.deepcopy(d or {}))

    @property
    def name(self) -> str:
        return self.config["name"]

    @property
    def kind(self) -> str:
        """``"spacecraft"`` or ``"imu"``: which schema and simulator the scenario uses."""
        return self.config["kind"]

    def get(self, key: str) -> Any:
        """Value of a dotted key, e.g. ``"sensors.gyro.bias_deg_s"``."""
        set_dotted({}, key, None, schema_of(self.config))  # raises InputError if unknown
        return copy.deepcopy(get_dotted(self.config, key))

    def replace(self, overrides: dict | None = None, **kw) -> Scenario:
        """A new validated scenario with dotted-key overrides.

        ``sc.replace({"spacecraft.inertia_error_pct": 10.0})``; keyword form with ``__``
        for dots: ``sc.replace(spacecraft__inertia_error_pct=10.0)``. Unknown keys raise
        ``InputError`` naming them.
        """
        d = copy.deepcopy(self.config)
        items = dict(overrides or {})
        items.update({k.replace("__", "."): v for k, v in kw.items()})
        for key, value in items.items():
            if key == "kind" and value != self.kind:
                raise InputError(f"a {self.kind} scenario cannot become {value!r}", field=key)
            set_dotted(d, key, value, schema_of(self.config))
        return Scenario(validate(d), self.source)

    def to_dict(self) -> dict:
        return copy.deepcopy(self.config)

    def to_yaml(self) -> str:
        """The full scenario (every key, defaults filled in) as YAML text that
        :func:`load_scenario` reads back to the same scenario (save it beside results)."""
        return yaml.safe_dump(self.config, sort_keys=False, default_flow_style=None)


def list_presets() -> list[str]:
    """Names of the scenario presets shipped with gnomon (``seed000``, ``seed001``, ...)."""
    pkg = resources.files("gnomon.scenarios")
    return sorted(p.name[:-5] for p in pkg.iterdir() if p.name.endswith(".yaml"))


def load_scenario(name_or_path: str | pathlib.Path) -> Scenario:
    """Load a preset by name or a YAML scenario file by path (validated; ``InputError`` if bad)."""
    s = str(name_or_path)
    p = pathlib.Path(s)
    if s in list_presets():
        text = resources.files("gnomon.scenarios").joinpath(f"{s}.yaml").read_text("utf-8")
        source = f"preset:{s}"
    elif p.is_file():
        text = p.read_text("utf-8")
        source = str(p)
    else:
        raise InputError(f"no scenario file or preset named {s!r}; presets: "
                         f"{', '.join(list_presets())}", field="scenario")
    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise InputError(f"not valid YAML: {err}".replace("\n", " "), file=source) from None
    try:
        return Scenario.from_dict(d or {}, source)
    except InputError as err:
        raise err.with_file(source) from None


def describe(kind: str = "spacecraft") -> list[tuple[str, str, str, Any, str]]:
    """Rows ``(dotted key, kind, unit, default, description)`` of the schema of scenarios
    of ``kind`` (``"spacecraft"`` or ``"imu"``)."""
    if kind not in KINDS:
        raise InputError(f"expected one of {sorted(KINDS)}, got {kind!r}", field="kind")
    rows = []

    def walk(node, prefix):
        for k, v in node.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            else:
                rows.append((f"{prefix}{k}", v.kind, v.unit, v.default, v.doc))

    walk(KINDS[kind], "")
    return rows


def simulate(scenario: Scenario | str | pathlib.Path, rng_seed: int | None = None):
    """Run a scenario; see :func:`gnomon.scenarios.simulator.simulate`."""
    from gnomon.scenarios.simulator import simulate as _simulate

    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    return _simulate(scenario, rng_seed=rng_seed)


def simulate_many(scenarios, seeds) -> list:
    """``[simulate(scenarios[k], seeds[k]) for k]``, batched: a ``Recording`` per run, or
    the exception that failed that run.

    The ``kind: imu`` runs that share their time base and truth integration
    (``gnomon.simulation.ahrs.batch_key``: noise levels, biases, rates, the field may
    differ) are simulated in one call (``simulate_ahrs_batch``: each run's draws by its
    own generator, the rest compiled for all of them); the others one by one. Each run
    equals its ``simulate`` (the same function computes it)."""
    from gnomon.scenarios.simulator import IMU_DRAW_ORDER, _imu_params, imu_rng
    from gnomon.simulation.ahrs import batch_key, simulate_ahrs_batch

    out: list = [None] * len(scenarios)
    groups: dict = {}
    for k, (sc, seed) in enumerate(zip(scenarios, seeds, strict=True)):
        try:
            if isinstance(sc, Scenario) and sc.config["kind"] == "imu":
                p = _imu_params(sc.config)
                s = sc.config["seed"] if seed is None else seed
                groups.setdefault(batch_key(p), []).append((k, p, int(s)))
                continue
            out[k] = simulate(sc, rng_seed=seed)
        except Exception as err:  # noqa: BLE001 - this run fails, the others go on
            out[k] = err
    for items in groups.values():
        ks = [k for k, _, _ in items]
        try:
            recs = simulate_ahrs_batch([p for _, p, _ in items],
                                       [imu_rng(s) for _, _, s in items], IMU_DRAW_ORDER)
        except Exception:  # noqa: BLE001 - then one at a time, to fail only the bad one
            recs = []
            for k in ks:
                try:
                    recs.append(simulate(scenarios[k], rng_seed=seeds[k]))
                except Exception as err:  # noqa: BLE001
                    recs.append(err)
        for k, rec in zip(ks, recs, strict=True):
            out[k] = rec
    return out
