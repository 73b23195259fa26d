"""The campaign report (issue 21): the budget against a closed form, the sensitivity on a
planted dependency, the re-run command against the stored row, no absolute path, every
image loaded in headless Chromium (skipped, and said so, where Chromium is absent); and
the progress helper."""

import io
import json
import math
import os
import re
import shlex
import subprocess

import numpy as np
import pandas as pd
import pytest
from test_report import CHROMIUM_FLAGS, _chromium

from gnomon.campaign.budget import budget, filters_of, is_budget_metric
from gnomon.campaign.rerun import rerun_command
from gnomon.campaign.sensitivity import sensitivity
from gnomon.metrics import score_run_budget
from gnomon.recording import Recording
from gnomon.rotation import quat_from_rotvec, quat_mul

SIGMA_DEG = np.array([0.1, 0.2, 0.4])     # per body axis, sunlit; doubled in eclipse


def _gaussian_run(rng, n=4000):
    """A run whose per-axis body errors are Gaussian, zero mean, of known σ: SIGMA_DEG
    in the first half (sunlit), 2·SIGMA_DEG in the second (eclipse); no settling."""
    t = np.arange(n, dtype=float)
    sig = np.where((t < n // 2)[:, None], SIGMA_DEG, 2 * SIGMA_DEG)
    e = np.radians(rng.normal(size=(n, 3)) * sig)
    q_true = quat_from_rotvec(rng.normal(size=3))            # any attitude, held
    q_true = np.tile(q_true, (n, 1))
    q_est = quat_mul(q_true, quat_from_rotvec(e))            # error in the body axes
    sun = np.tile([1.0, 0.0, 0.0], (n, 1))
    sun[n // 2:] = np.nan
    rec = Recording(t=t, gyro=np.zeros((n, 3)), sun=sun, q_true=q_true,
                    frames={"reference": "o", "body": "b"})
    return score_run_budget(rec, q_est)


def _gaussian_table(runs=40, seed=0):
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(runs):
        m = _gaussian_run(rng)
        row = {"index": k, "seed": k, "status": "ok", "error": ""}
        row.update({f"F.{key}": v for key, v in m.items()})
        # score_run's totals, from the per-axis RMS (independent axes)
        for prefix in ("", "sunlit_", "eclipse_"):
            row[f"F.{prefix}rms_deg"] = math.sqrt(sum(m[f"{prefix}{a}_rms_deg"] ** 2
                                                      for a in "xyz"))
        rows.append(row)
    return pd.DataFrame(rows)


def test_budget_of_gaussian_errors_is_the_closed_form():
    """Gaussian body-axis errors of σ give 3σ = 3·σ per axis, 3·√(Σσ²) in total, and a p99
    of about 2.576σ (the 99.5 % point of the normal: 99 % of |e|), sunlit and eclipse."""
    table = _gaussian_table()
    assert filters_of(table) == ["F"]
    rows = {r["phase"]: r for r in budget(table, "F")}
    assert set(rows) == {"all", "sunlit", "eclipse"}
    z99 = 2.5758293035489004
    for phase, sig in (("sunlit", SIGMA_DEG), ("eclipse", 2 * SIGMA_DEG)):
        r = rows[phase]
        assert r["runs"] == 40
        for a, s in zip("xyz", sig, strict=True):
            assert r[f"{a}_3sigma_deg"] == pytest.approx(3 * s, rel=0.02), (phase, a)
            # p99 over runs of per-run p99s: a little above the normal's own value
            assert z99 * s * 0.98 < r[f"{a}_p99_deg"] < z99 * s * 1.08, (phase, a)
        assert r["total_3sigma_deg"] == pytest.approx(3 * np.sqrt(np.sum(sig ** 2)), rel=0.02)
        assert r["total_p99_deg"] > r["z_p99_deg"]
    # all samples: half at σ, half at 2σ -> RMS = σ·√(5/2)
    for a, s in zip("xyz", SIGMA_DEG, strict=True):
        assert rows["all"][f"{a}_3sigma_deg"] == pytest.approx(3 * s * math.sqrt(2.5), rel=0.02)


def test_budget_metric_names_and_empty_phases():
    assert is_budget_metric("mekf-spacecraft.x_rms_deg")
    assert is_budget_metric("qcf.eclipse_z_p99_deg") and is_budget_metric("qcf.p99_deg")
    assert not is_budget_metric("qcf.rms_deg") and not is_budget_metric("qcf.eclipse_max_deg")
    table = _gaussian_table(runs=3)
    table.loc[:, [c for c in table if c.startswith("F.eclipse_")]] = np.nan
    table.loc[1, "status"] = "failed"                         # failed runs are left out
    rows = {r["phase"]: r for r in budget(table, "F")}
    assert rows["all"]["runs"] == 2 and rows["eclipse"]["runs"] == 0
    assert math.isnan(rows["eclipse"]["x_3sigma_deg"])


def test_sensitivity_finds_a_planted_monotone_dependency_and_not_a_random_one():
    rng = np.random.default_rng(3)
    n = 400
    a, b = rng.uniform(0, 10, n), rng.uniform(0, 1, n)
    table = pd.DataFrame({"index": range(n), "status": "ok", "param.a": a, "param.b": b,
                          "param.kind": rng.choice(["tilt", "scale"], n),
                          "param.const": np.full(n, 2.0),
                          "F.rms_deg": np.exp(0.3 * a) + rng.normal(0, 0.3, n),
                          "F.max_deg": rng.normal(5, 1, n)})
    s = sensitivity(table, ["F.rms_deg", "F.max_deg"])
    rho = {(c.param, c.metric): c for c in s.correlations}
    assert rho[("param.a", "F.rms_deg")].rho > 0.9
    assert rho[("param.a", "F.rms_deg")].p_value < 1e-10
    for pair in (("param.b", "F.rms_deg"), ("param.a", "F.max_deg"), ("param.b", "F.max_deg")):
        assert abs(rho[pair].rho) < 3 / math.sqrt(n), pair
    assert s.strongest(1)[0].param == "param.a"
    assert set(s.skipped) == {"param.kind", "param.const"}


@pytest.fixture(scope="module")
def campaign_dir(tmp_path_factory):
    """`gnomon campaign seed001 --runs 6 --report`: shortened runs, one filter, two
    parameters varied."""
    from gnomon.cli import main

    out = tmp_path_factory.mktemp("campaign") / "c1"
    argv = ["campaign", "seed001", "--runs", "6", "--out", out, "--seed", "11",
            "--vary", "duration_s=1500", "--vary", "sensors.sun_sensor.noise_deg=uniform(0.05,1)",
            "--filter", "mekf-spacecraft", "--executor", "serial", "--report", "--json",
            "--quiet"]
    assert main(argv) == 0
    return out


def test_campaign_report_sections(campaign_dir):
    text = (campaign_dir / "report.html").read_text()
    for heading in ("Error distribution", "Attitude-knowledge budget", "Worst runs",
                    "Sensitivity", "Run time and failures"):
        assert heading in text
    assert "3 · √(mean over runs" in text                   # the 3σ definition is stated
    assert "naturalWidth" in text                # the page logs an image that fails to load
    pngs = sorted(p.name for p in (campaign_dir / "report").glob("*.png"))
    assert "cdf.png" in pngs
    for name in pngs:                                       # every figure is on the page
        assert f"report/{name}" in text


def test_the_report_shows_no_absolute_path(campaign_dir):
    text = (campaign_dir / "report.html").read_text()
    for prefix in {str(campaign_dir.parent), str(campaign_dir.resolve()), os.getcwd(),
                   os.path.expanduser("~")}:
        assert prefix not in text, prefix
    assert "file:" not in text
    assert re.search(r"src=['\"]/", text) is None


def test_the_rerun_command_reproduces_the_stored_row(campaign_dir, capsys):
    from gnomon.campaign import read_manifest, read_results
    from gnomon.cli import main

    manifest = read_manifest(campaign_dir)
    table = read_results(campaign_dir)
    k = int(table.sort_values("mekf-spacecraft.rms_deg").iloc[-1]["index"])   # the worst
    cmd = rerun_command(manifest, k)
    assert cmd is not None and cmd.startswith("gnomon campaign seed001 ")
    assert cmd in (campaign_dir / "report.html").read_text().replace("&#x27;", "'")
    words = shlex.split(cmd)
    capsys.readouterr()
    assert main(words[1:] + ["--json"]) == 0
    row = json.loads(capsys.readouterr().out)["row"]
    stored = table[table["index"] == k].iloc[0]
    metrics = [c for c in table if c.startswith("mekf-spacecraft.")]
    assert len(metrics) > 20
    for c in metrics:
        a, b = stored[c], row[c]
        assert (b is None and np.isnan(a)) or a == b, c      # identical, not just close
    assert row["param.sensors.sun_sensor.noise_deg"] == stored["param.sensors.sun_sensor.noise_deg"]


def test_rerun_command_for_what_the_command_line_cannot_say():
    m = {"scenario_source": "dict", "runs": 5, "root_seed": 0, "vary": {}, "task_options": {},
         "task": "gnomon.campaign:simulate_and_score"}
    assert rerun_command(m, 1) is None
    m2 = dict(m, scenario_source="preset:seed001", task="mymod:task")
    assert rerun_command(m2, 1) is None
    m3 = dict(m, scenario_source="preset:seed001", vary={"k": "choice(a, b)"},
              task_options={"filters": ["qcf"]})
    assert shlex.split(rerun_command(m3, 4)) == [
        "gnomon", "campaign", "seed001", "--runs", "5", "--seed", "0", "--vary",
        "k=choice(a, b)", "--filter", "qcf", "--only", "4"]


def test_report_needs_a_whole_campaign(tmp_path, capsys):
    from gnomon.cli import main

    assert main(["campaign", "seed001", "--runs", "2", "--report"]) == 2
    assert main(["campaign", "seed001", "--runs", "2", "--out", tmp_path, "--only", "0",
                 "--report"]) == 2
    assert "--report" in capsys.readouterr().err


def test_gnomon_report_rebuilds_the_page(campaign_dir, capsys):
    from gnomon.cli import main

    (campaign_dir / "report.html").unlink()
    assert main(["report", campaign_dir]) == 0
    assert (campaign_dir / "report.html").is_file()
    assert main(["report", campaign_dir / "report"]) == 2     # neither campaign nor papers


def test_campaign_report_opens_in_headless_chromium(campaign_dir, tmp_path):
    chromium = _chromium()
    if chromium is None:
        pytest.skip("Chromium not installed (Debian: apt-get install chromium): "
                    "browser check of the campaign report NOT run")
    page = campaign_dir / "report.html"
    shot = tmp_path / "shot.png"
    p = subprocess.run([chromium, *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'ud'}",
                        f"--screenshot={shot}", page.as_uri()],
                       capture_output=True, text=True, timeout=120,
                       env={**os.environ, "HOME": str(tmp_path)})
    console = [line for line in p.stderr.splitlines() if ":CONSOLE" in line]
    assert console == [], console      # a missing image would be logged (the page's check)
    assert shot.stat().st_size > 5000


# ------------------------------------------------------------------ progress
class _Stream(io.StringIO):
    def __init__(self, tty):
        super().__init__()
        self._tty = tty

    def isatty(self):
        return self._tty


def test_progress_only_on_a_terminal_outside_ci(monkeypatch):
    from gnomon.progress import Progress, wanted

    monkeypatch.delenv("CI", raising=False)
    assert wanted(stream=_Stream(True))
    assert not wanted(stream=_Stream(False))
    assert not wanted(quiet=True, stream=_Stream(True))
    monkeypatch.setenv("CI", "true")
    assert not wanted(stream=_Stream(True))
    bar = Progress(10, "x")                                  # CI: a no-op
    bar.update(3, failed=0)
    bar.note("n")
    bar.close()
    assert bar.bar is None


def test_progress_bar_draws_rate_and_time_left(monkeypatch):
    import sys

    from gnomon.progress import Progress

    monkeypatch.delenv("CI", raising=False)
    err = _Stream(True)
    monkeypatch.setattr(sys, "stderr", err)
    with Progress(4, "campaign t", unit="run") as bar:
        bar.update(2, failed=0)
    out = err.getvalue()
    assert "campaign t" in out and "4/4" not in out and "2/4" in out
    assert "run/s" in out or "s/run" in out
