"""Live estimation: per-sensor samples as they arrive (own rates, late samples, jitter,
clocks that jump or run on their own), lines of a stream (CSV, JSON, garbage), a UDP
stream and a replay through ``gnomon live`` equal to ``gnomon estimate`` on the same
samples."""

import dataclasses
import json
import shutil
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import gnomon
from gnomon.datasets import bundled
from gnomon.live import LineParser, LiveFilter, Malformed, open_source, run_live
from gnomon.live.sinks import EstimateFileSink
from gnomon.live.sources import _replay_events
from gnomon.rotation import quat_from_euler

BROAD = sorted(bundled("broad").glob("*.hdf5"))[0]


@pytest.fixture(scope="module")
def broad():
    return gnomon.read(BROAD).slice(0, 2500)


@pytest.fixture(scope="module")
def multi_rate():
    """A recording with the accelerometer at half and the magnetometer at a quarter of the
    gyro's rate, their stamps between the gyro's."""
    from conftest import synthetic_imu

    full = synthetic_imu(quat_from_euler([0.3, -0.2, 2.0]), [0.3, -0.4, 0.5], n=2000, fs=200.0,
                         gyro_bias=[0.01, -0.02, 0.005], noise=0.005, seed=4)
    return dataclasses.replace(full, accel=full.accel[::2], accel_t=full.t[::2] + 0.001,
                               mag=full.mag[1::4], mag_t=full.t[1::4] - 0.002)


def _angle(q1, q2):
    sign = np.where(np.sum(q1 * q2, axis=-1) < 0.0, -1.0, 1.0)[..., None]
    chord = np.linalg.norm(q1 - sign * q2, axis=-1)
    return 4.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0))


def _push_all(live, events, arrivals=None):
    """Every event through ``live``; the estimates as one (t, q)."""
    t, names, values = events
    chunks = []
    for k in range(len(t)):
        chunks += live.push(names[k], t[k], values[k],
                            arrival_s=t[k] if arrivals is None else arrivals[k])
    chunks += live.flush()
    return (np.concatenate([c.t for c in chunks]), np.concatenate([c.q for c in chunks]))


@pytest.mark.slow(reason="3 s (2 cores): builds and runs the C export")
@pytest.mark.parametrize("name", ["mahony", "robust-ahrs", "eskf-r3"])
def test_samples_in_order_give_the_batch_result(broad, multi_rate, name):
    for rec in (broad, multi_rate):
        ref = gnomon.make_filter(name).run(rec)
        t, q = _push_all(LiveFilter(gnomon.make_filter(name)), _replay_events(rec))
        np.testing.assert_array_equal(t, rec.t)
        assert _angle(q, ref.q).max() < 1e-12


def test_samples_late_by_less_than_half_a_period_land_in_their_own_rows(multi_rate):
    """Shuffle the arrival order within windows shorter than the hold: the rows, hence the
    estimates, are those of the batch run."""
    rec = multi_rate
    t, names, values = _replay_events(rec)
    rng = np.random.default_rng(0)
    arrival = t + rng.uniform(0.0, 0.4 / 200.0, len(t))  # up to 0.4 gyro periods late
    order = np.argsort(arrival, kind="stable")
    events = (t[order], [names[k] for k in order], values[order])
    ref = gnomon.make_filter("mahony").run(rec)
    live = LiveFilter(gnomon.make_filter("mahony"))
    tt, q = _push_all(live, events, arrival[order])
    np.testing.assert_array_equal(tt, rec.t)
    assert _angle(q, ref.q).max() < 1e-12
    assert live.stats.late == 0 and live.stats.out_of_order == 0


def test_a_sample_later_than_its_row_is_used_once_in_the_next(multi_rate):
    t, names, values = _replay_events(multi_rate)
    k = next(i for i in range(500, len(t)) if names[i] == "accel")
    late = (t[k], names[k], values[k])
    keep = [i for i in range(len(t)) if i != k]
    events = (t[keep], [names[i] for i in keep], values[keep])
    live = LiveFilter(gnomon.make_filter("mahony"))
    chunks = []
    for j in range(len(events[0])):
        chunks += live.push(events[1][j], events[0][j], events[2][j], arrival_s=events[0][j])
        if events[0][j] > late[0] + 0.05 and late is not None:  # 10 periods late
            chunks += live.push(late[1], late[0], late[2], arrival_s=events[0][j])
            late = (np.inf, None, None)
    chunks += live.flush()
    assert live.stats.late == 1
    assert live.stats.samples["accel"] == len(multi_rate.accel)
    assert len(np.concatenate([c.t for c in chunks])) == len(multi_rate)


def test_broken_streams_are_counted_never_raise_and_never_nan(broad):
    """NaN values, unknown sensors, wrong shapes, repeated and backward gyro stamps, a gyro
    clock that jumps forward by an hour and one that jumps back: all counted, the
    estimates finite, the rows in time order."""
    t, names, values = _replay_events(broad)
    live = LiveFilter(gnomon.make_filter("robust-ahrs"))
    out = []
    offset = 0.0
    for k in range(len(t)):
        if k == 3000:
            offset = 3600.0  # the sender's clock jumps forward an hour
        if k == 5000:
            offset = -10.0  # and later back
        out += live.push(names[k], t[k] + offset, values[k], arrival_s=t[k])
        if k % 400 == 3:
            out += live.push("gyro", t[k] + offset, [np.nan, 0.0, 0.0], arrival_s=t[k])
            out += live.push("accel", t[k] + offset, [1.0, 2.0], arrival_s=t[k])
            out += live.push("compass", t[k], [1.0, 2.0, 3.0], arrival_s=t[k])
            out += live.push("gyro", t[k] + offset - 0.5, values[k], arrival_s=t[k])
    out += live.flush()
    q = np.concatenate([c.q for c in out])
    tt = np.concatenate([c.t for c in out])
    assert np.all(np.isfinite(q)) and np.all(np.diff(tt) > 0)
    s = live.stats
    assert s.clock_jumps >= 2 and s.invalid > 0 and s.out_of_order > 0
    assert s.filter_errors == 0
    assert len(tt) > 0.95 * len(broad)


def test_a_sensor_on_its_own_clock_is_shifted_onto_the_gyro_clock(multi_rate):
    """The magnetometer stamped 12 s apart from the IMU (imu_tools#152): one offset, the
    rows as if on one clock."""
    t, names, values = _replay_events(multi_rate)
    shifted = t + np.where(np.array(names) == "mag", 12.0, 0.0)
    ref = gnomon.make_filter("mahony").run(multi_rate)
    live = LiveFilter(gnomon.make_filter("mahony"))
    chunks = []
    for k in range(len(t)):
        chunks += live.push(names[k], shifted[k], values[k], arrival_s=t[k])
    chunks += live.flush()
    q = np.concatenate([c.q for c in chunks])
    assert live.stats.clock_offset["mag"] == pytest.approx(-12.0, abs=0.01)
    # the shifted stamps move each magnetometer sample by less than a gyro period at most
    assert np.degrees(_angle(q, ref.q)).max() < 0.5


def test_a_filter_that_fails_is_started_again():
    """Ten seconds of zero accelerometer and magnetometer vectors cannot start Mahony;
    the stream waits, counts, and starts when real samples come."""
    live = LiveFilter(gnomon.make_filter("mahony"), warmup_samples=5)
    out = []
    for k in range(400):
        t = k * 0.01
        a = [0.0, 0.0, 9.81] if k >= 200 else [0.0, 0.0, 0.0]
        out += live.push("accel", t, a)
        out += live.push("mag", t, [0.0, 20.0, -40.0])
        out += live.push("gyro", t, [0.0, 0.0, 0.1])
    out += live.flush()
    q = np.concatenate([c.q for c in out])
    assert np.all(np.isfinite(q)) and len(q) >= 150


# ---------------------------------------------------------------- lines
def test_csv_and_json_lines_with_units_and_empty_cells():
    p = LineParser({"t": "time", "gyr_x": "gx", "gyr_y": "gy", "gyr_z": "gz"},
                   gyro_unit="deg/s", accel_unit="g", mag_unit="nT", time_unit="ms")
    assert p.parse("time,gx,gy,gz,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z") == []
    got = p.parse("10,180,0,-90,0,0,1,,,")
    assert [s for s, _, _ in got] == ["accel", "gyro"]
    assert got[1][1] == pytest.approx(0.01)
    np.testing.assert_allclose(got[1][2], [np.pi, 0.0, -np.pi / 2])
    np.testing.assert_allclose(got[0][2], [0.0, 0.0, 9.80665])
    got = LineParser(mag_unit="gauss").parse(
        '{"t": 1.5, "gyro": [0.1, 0.2, 0.3], "mag_x": 0.2, "mag_y": 0, "mag_z": -0.4}')
    got = {s: v for s, _, v in got}
    assert set(got) == {"gyro", "mag"}
    np.testing.assert_allclose(got["mag"], [20.0, 0.0, -40.0], rtol=1e-12)
    for bad in ("1,2,3", "x,y", "1,2,3,4,5,6,7,8,9,nan", '{"t": 1, "gyro": [1, 2]}',
                "1,2,3,4,5,6,7,8,,", b"\xff\xfe\x00", '{"t": [}', "[1, 2, 3]"):
        with pytest.raises(Malformed):
            LineParser().parse(bad)
    with pytest.raises(gnomon.InputError, match="gyro_unit"):
        LineParser(gyro_unit="rpm")


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.binary(max_size=120), st.text(max_size=120),
                 st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                                    st.just(""), st.text(max_size=4)), max_size=14).map(
                     lambda cells: ",".join(map(str, cells)))))
def test_the_line_parser_returns_samples_or_raises_malformed_only(line):
    p = LineParser()
    try:
        out = p.parse(line)
    except Malformed:
        return
    for sensor, _, v in out:
        assert sensor in ("gyro", "accel", "mag")
        assert v.shape == (3,) and np.all(np.isfinite(v))


# ---------------------------------------------------------------- end to end
NO_CC = pytest.mark.skipif(shutil.which("cc") is None or shutil.which("make") is None,
                           reason="no C compiler (cc) or make: the C backend NOT tested")


@pytest.mark.slow(reason="3 s (2 cores): streams through the live pipeline in real time")
@pytest.mark.parametrize("backend", [pytest.param("c", marks=NO_CC), "python"])
def test_replay_through_gnomon_live_equals_gnomon_estimate(tmp_path, backend, capsys):
    """``gnomon live`` on the C export or on the numba kernels writes what ``gnomon
    estimate --backend python`` writes, digit for digit."""
    from gnomon.cli import main

    est_csv, live_csv = tmp_path / "est.csv", tmp_path / "live.csv"
    assert main(["estimate", BROAD, "--filter", "robust-ahrs", "--backend", "python",
                 "--out", est_csv]) == 0
    capsys.readouterr()
    assert main(["live", f"replay://{BROAD}?speed=0", "--filter", "robust-ahrs", "--out",
                 live_csv, "--backend", backend, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["backend"] == \
        ("c (double)" if backend == "c" else "python")
    assert live_csv.read_text() == est_csv.read_text()  # the same columns, the same digits


@NO_CC
def test_the_c_export_streams_sample_by_sample_as_the_filter(broad, multi_rate, tmp_path,
                                                             monkeypatch):
    from gnomon.export.backend import c_filter_class

    monkeypatch.setenv("GNOMON_DATA_DIR", str(tmp_path))
    cls = c_filter_class("robust-ahrs")
    for rec in (broad, multi_rate):
        ref = gnomon.make_filter("robust-ahrs").run(rec)
        live = LiveFilter(cls(gnomon.make_filter("robust-ahrs").params))
        t, q = _push_all(live, _replay_events(rec))
        np.testing.assert_array_equal(t, rec.t)
        assert _angle(q, ref.q).max() < 1e-12


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_udp_stream_with_garbage_equals_the_batch_estimate(broad, tmp_path):
    """CSV lines with a header over UDP on 127.0.0.1, garbage datagrams, partial lines and
    wrong field counts among them: every sample estimated, each bad line counted."""
    port = _free_udp_port()
    src = open_source(f"udp://127.0.0.1:{port}")
    out = tmp_path / "live.csv"
    result = {}
    runner = threading.Thread(target=lambda: result.update(
        run=run_live(src, gnomon.make_filter("robust-ahrs"), [EstimateFileSink(out)],
                     max_samples=len(broad), duration_s=60.0)))
    runner.start()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.sendto(b"t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z\n",
                ("127.0.0.1", port))
    garbage = [b"\x00\xff\xfe garbage", b"0.5,1.0,2.0", b"1,2,3,4,5,6,7,8,9,10,11",
               b"nan,1,2,3,4,5,6,7,8,9", b'{"t": 1, "gyro": [1, 2]}']
    bad = 0
    for k in range(len(broad)):
        row = [broad.t[k], *broad.gyro[k], *broad.accel[k], *broad.mag[k]]
        sock.sendto(",".join(repr(float(x)) for x in row).encode(), ("127.0.0.1", port))
        if k % 250 == 10:
            sock.sendto(garbage[bad % len(garbage)], ("127.0.0.1", port))
            bad += 1
        if k % 20 == 0:
            time.sleep(0.002)  # a sender at a few kHz, not a flood
    runner.join(timeout=90)
    run = result["run"]
    ref = gnomon.make_filter("robust-ahrs").run(broad)
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    assert run.samples == len(broad) and run.dropped == 0
    assert run.malformed == bad
    np.testing.assert_allclose(data[:, 0], broad.t, rtol=0, atol=1e-12)
    assert _angle(data[:, 1:5] / np.linalg.norm(data[:, 1:5], axis=1)[:, None],
                  ref.q).max() < 1e-9


@pytest.mark.slow(reason="3 s (2 cores): runs the command line in new processes")
def test_gnomon_live_json_contract_and_signals(tmp_path):
    """--json prints the contract keys; SIGTERM ends the run and the file is complete."""
    import signal

    port = _free_udp_port()
    out = tmp_path / "live.h5"
    p = subprocess.Popen([sys.executable, "-m", "gnomon.cli", "live", f"udp://127.0.0.1:{port}",
                          "--filter", "mahony", "--out", out, "--json", "--duration", "60"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rec = gnomon.read(BROAD).slice(0, 600)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    deadline = time.time() + 60
    sent = 0
    while time.time() < deadline:  # until the process listens and has estimated them all
        for k in range(len(rec)):
            obj = {"t": float(rec.t[k] + sent * 10.0), "gyro": rec.gyro[k].tolist(),
                   "accel": rec.accel[k].tolist(), "mag": rec.mag[k].tolist()}
            sock.sendto(json.dumps(obj).encode(), ("127.0.0.1", port))
        sent += 1
        time.sleep(1.0)
        if out.exists() or sent > 8:
            break
    time.sleep(0.5)
    p.send_signal(signal.SIGTERM)
    stdout, stderr = p.communicate(timeout=60)
    assert p.returncode == 0, stderr
    summary = json.loads(stdout)
    assert {"filter", "samples", "malformed", "dropped", "latency_us"} <= set(summary)
    assert {"p50", "p99"} <= set(summary["latency_us"])
    assert summary["filter"] == "mahony" and summary["ended_by"] == "signal"
    import h5py

    with h5py.File(out) as f:
        assert f["q"].shape[0] == summary["samples"] > 0
        assert np.all(np.isfinite(f["q"][:]))
