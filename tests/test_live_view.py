"""The live view (``gnomon live --view PORT``, :mod:`gnomon.live.view`): the page and its
WebSocket checked with a plain client, then the page in headless Chromium, driven through
the DevTools protocol: it renders the body and the traces (screenshots not blank, the
body's colours there) and it updates as estimates come.

The browser tests need Debian's ``chromium`` (``.ci/run`` installs it, as for the report's
test in ``test_report.py``, whose flags these are); where it is absent they are skipped
with a message saying so — they never pass silently.
"""

import base64
import contextlib
import io
import json
import os
import re
import shutil
import subprocess
import threading
import time
import urllib.error
import urllib.request

import numpy as np
import pytest

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate
from gnomon.live.view import ViewSink
from gnomon.rotation import euler_from_quat, quat_from_euler

websockets_client = pytest.importorskip("websockets.sync.client")

# the flags of test_report.py's Chromium runs
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--enable-logging=stderr",
                  "--v=0"]


def _replay_file():
    from gnomon.datasets import bundled

    return sorted(bundled("broad").glob("*.hdf5"))[0]


def _estimate(t0, n, dt=0.005, big=0):
    """``n`` rows from ``t0`` of a body yawing ±25 deg about -150 deg (x towards the camera
    of the page, its red, green and blue faces in view), rolling ±20 deg, pitched -15 deg;
    a gyro bias, a flag set one second in three, one never set, a scalar signal (and a
    vector signal of ``big`` values: large frames)."""
    t = t0 + dt * np.arange(n)
    yaw = np.radians(-150.0 + 25.0 * np.sin(0.8 * t))
    rpy = np.column_stack([np.radians(20.0) * np.sin(0.7 * t), np.full(n, np.radians(-15.0)),
                           yaw])
    return Estimate(t=t, q=quat_from_euler(rpy), estimator="synthetic", params={},
                    frames={"reference": "ENU", "body": "sensor"},
                    signals={"bias_rad_s": np.tile(np.radians([0.1, -0.05, 0.02]), (n, 1)),
                             "rest": t % 3.0 < 1.0, "mag_disturbed": np.zeros(n, bool),
                             "mag_gain": np.ones(n),
                             **({"big": np.full((n, big), 0.123456789)} if big else {})})


@pytest.fixture
def view():
    sink = ViewSink(0)
    yield sink
    sink.close()


def _ws(sink, **kw):
    return websockets_client.connect(f"ws://127.0.0.1:{sink.port}/ws", **kw)


def _recv(ws, timeout=5.0) -> dict:
    return json.loads(ws.recv(timeout))


class _Feeder:
    """Writes ``_estimate`` chunks into a sink in real time (``rate_hz`` rows a second, in
    chunks of ``chunk`` rows) from a thread, as the live loop would."""

    def __init__(self, sink, rate_hz=200.0, chunk=5, big=0, t0=0.0):
        self.sink, self.dt, self.chunk, self.big = sink, 1.0 / rate_hz, chunk, big
        self.stop = threading.Event()
        self.t, self.start = t0, time.perf_counter()
        self.write_s = []
        self.thread = threading.Thread(target=self._run, daemon=True)

    def rate_hz(self):
        """The rows a second it has written (behind ``rate_hz`` on a loaded computer)."""
        return len(self.write_s) * self.chunk / (time.perf_counter() - self.start)

    def _run(self):
        start = self.start = time.perf_counter()
        k = 0
        while not self.stop.is_set():
            est = _estimate(self.t, self.chunk, self.dt, self.big)
            t0 = time.perf_counter()
            self.sink.write(est)
            self.write_s.append(time.perf_counter() - t0)
            self.t += self.chunk * self.dt
            k += 1
            time.sleep(max(0.0, start + k * self.chunk * self.dt - time.perf_counter()))

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join(5.0)


# ---------------------------------------------------------------------- no browser
def test_get_returns_the_page_with_nothing_fetched_from_elsewhere(view):
    assert view.port > 0 and view.url == f"http://127.0.0.1:{view.port}/"
    with urllib.request.urlopen(view.url, timeout=5) as r:
        assert r.status == 200 and r.headers["Content-Type"].startswith("text/html")
        page = r.read().decode()
    assert "<canvas" in page and "/ws" in page
    assert not re.search(r"(src|href)\s*=\s*[\"']?(https?:)?//", page), "an external file"
    assert "http://" not in page and "https://" not in page
    with pytest.raises(urllib.error.HTTPError) as err:
        urllib.request.urlopen(view.url + "favicon.ico", timeout=5)
    assert err.value.code == 404
    err.value.close()


def test_websocket_sends_the_latest_state_and_the_new_trace_points(view):
    first = _estimate(0.0, 400)  # 2 s
    view.write(first)
    time.sleep(0.1)
    with _ws(view) as ws:
        m = _recv(ws)
        assert m["history"] is True
        assert {"t", "q", "euler_deg", "bias_deg_s", "flags", "flag_rows", "values", "rows",
                "rate_hz", "clients", "trace", "estimator", "frames"} <= set(m)
        assert m["t"] == pytest.approx(first.t[-1])
        np.testing.assert_allclose(m["q"], first.q[-1], atol=1e-12)
        np.testing.assert_allclose(m["euler_deg"], np.degrees(euler_from_quat(first.q[-1])),
                                   atol=1e-9)
        np.testing.assert_allclose(m["bias_deg_s"], [0.1, -0.05, 0.02], atol=1e-12)
        assert m["flags"] == {"rest": False, "mag_disturbed": False}
        assert m["flag_rows"] == {"rest": 200, "mag_disturbed": 0}  # t < 1 s, 5 ms apart
        assert m["values"] == {"mag_gain": 1.0}
        assert m["rows"] == 400 and m["clients"] == 1 and m["frames"]["reference"] == "ENU"
        # the history: a point every 20 ms of stream time, [t, roll, pitch, yaw]
        trace = np.array(m["trace"])
        assert trace.shape[1] == 4 and abs(len(trace) - 100) <= 1
        assert np.all(np.abs(np.diff(trace[:, 0]) - 0.02) < 0.0051)
        rows = np.searchsorted(first.t, trace[:, 0] - 1e-9)
        np.testing.assert_allclose(first.t[rows], trace[:, 0], atol=1e-4)
        np.testing.assert_allclose(trace[:, 1:], np.degrees(euler_from_quat(
            first.q[rows])), atol=1e-3)
        second = _estimate(2.0, 40)
        view.write(second)
        m2 = _recv(ws)
        assert "history" not in m2 and m2["t"] == pytest.approx(second.t[-1])
        np.testing.assert_allclose(m2["q"], second.q[-1], atol=1e-12)
        new = np.array([p[0] for p in m2["trace"]])  # only the new points
        assert new.min() > trace[-1, 0] and new.max() <= second.t[-1] and len(new) >= 8
        view.close()
        last = _recv(ws)
        assert last["ended"] is True and last["t"] == pytest.approx(second.t[-1])
    d = view.describe()
    assert d["sink"] == "view" and d["clients"] == 1 and d["rows"] == 440
    assert d["url"] == view.url
    with pytest.raises(OSError):  # the server is gone
        _ws(view, open_timeout=2).close()


def test_write_never_waits_and_browsers_get_at_most_30_frames_a_second(view):
    with _ws(view) as ws, _Feeder(view, rate_hz=1000.0, chunk=1) as feeder:
        _recv(ws)
        frames, t0 = [], time.perf_counter()
        while time.perf_counter() - t0 < 1.5:
            frames.append(_recv(ws))
    assert 15 <= len(frames) <= 1.5 * 31 + 2
    assert np.all(np.diff([f["t"] for f in frames]) > 0)
    w = np.array(feeder.write_s) * 1e6  # µs
    assert len(w) > 500 and np.median(w) < 20 and np.percentile(w, 99) < 2000, \
        (np.median(w), np.percentile(w, 99))
    assert frames[-1]["rate_hz"] == pytest.approx(feeder.rate_hz(), rel=0.3)


def test_a_slow_client_gets_the_newest_state_not_a_backlog(view):
    """A client that stops reading (a small receive buffer, frames of ~40 kB): its frames
    are dropped while its socket is full; the other client and the writer go on; when it
    reads again it soon has the newest state."""
    import socket

    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", view.port))
    with _ws(view, sock=sock, max_queue=1) as slow, _ws(view, max_size=None) as fast, \
            _Feeder(view, rate_hz=500.0, chunk=5, big=2000) as feeder:
        _recv(slow), _recv(fast)
        fast_t, t0 = [], time.perf_counter()
        while time.perf_counter() - t0 < 2.0:  # the slow one does not read
            fast_t.append(_recv(fast)["t"])
        assert len(fast_t) >= 20 and fast_t[-1] == pytest.approx(feeder.t, abs=0.2)
        late = []
        while True:
            late.append(_recv(slow)["t"])
            if late[-1] > feeder.t - 0.2:
                break
    assert len(late) < 15, late  # what its buffers held, not the 60 frames it missed
    assert view.frames_dropped > 20
    w = np.array(feeder.write_s) * 1e6
    assert np.median(w) < 50, np.median(w)


def test_a_page_busy_drawing_is_sent_nothing_until_it_has_drawn(view):
    """The page acknowledges each frame it has drawn; one that has not acknowledged the
    last two gets no more until it does, then the newest state."""
    with _ws(view) as page, _Feeder(view, rate_hz=200.0, chunk=5) as feeder:
        _recv(page)
        page.send("ack")  # the first frame drawn: from now on it is held to its acks
        got, t0 = [], time.perf_counter()
        while time.perf_counter() - t0 < 1.0:
            try:
                got.append(_recv(page, timeout=0.1))
            except TimeoutError:
                pass
        assert 1 <= len(got) <= 2, len(got)
        page.send("ack")
        page.send("ack")
        newest = _recv(page)
        assert newest["t"] == pytest.approx(feeder.t, abs=0.1)
    assert view.frames_dropped > 10


def test_a_port_in_use_is_an_input_error(view):
    with pytest.raises(InputError, match="--view"):
        ViewSink(view.port)


def test_a_replay_through_run_live_reaches_the_browser():
    """``run_live`` with a replay into the view: the browser's last frame is the filter's
    last estimate, and the end of the run is said."""
    from gnomon.estimators import registry
    from gnomon.live import open_source, run_live

    sink = ViewSink(0)
    frames, done = [], threading.Event()

    def browser():
        with _ws(sink) as ws:
            done.set()
            try:
                while True:
                    frames.append(_recv(ws, timeout=30))
            except Exception:  # noqa: BLE001 - closed at the end of the run
                pass

    reader = threading.Thread(target=browser, daemon=True)
    reader.start()
    assert done.wait(5)
    last = []
    source = open_source(f"replay://{_replay_file()}?speed=0")
    run = run_live(source, registry.create("mahony", {}), [sink], max_samples=600,
                   on_estimate=last.append)
    reader.join(10)
    assert run.samples == 600 and frames[-1]["ended"] is True
    assert frames[-1]["estimator"] == "mahony" and frames[-1]["rows"] == 600
    np.testing.assert_allclose(frames[-1]["q"], last[-1].q[-1], atol=1e-12)
    assert set(frames[-1]["flags"]) == {"acc_skipped", "mag_skipped", "gap"}
    assert run.sinks[0]["clients"] == 1


def test_gnomon_live_view_option(capsys):
    from gnomon.cli import main

    assert main(["live", f"replay://{_replay_file()}?speed=0", "--filter", "mahony",
                 "--max-samples", "300", "--view", "0", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    view = [s for s in summary["sinks"] if s["sink"] == "view"][0]
    assert re.fullmatch(r"http://127\.0\.0\.1:\d+/", view["url"]) and view["rows"] == 300


def test_the_foxglove_server_sends_the_attitude():
    """``FoxgloveViewSink``: foxglove-sdk's server advertises the three topics and sends
    the newest row on each to a subscriber (Foxglove's app speaks this protocol)."""
    pytest.importorskip("foxglove")
    from gnomon.live.view import FoxgloveViewSink

    sink = FoxgloveViewSink(0)
    try:
        assert sink.port > 0 and sink.url == f"ws://127.0.0.1:{sink.port}"
        with websockets_client.connect(sink.url, subprotocols=[
                "foxglove.sdk.v1", "foxglove.websocket.v1"]) as ws:
            channels = {}
            while len(channels) < 3:
                m = json.loads(ws.recv(5))
                channels.update({c["topic"]: c for c in m.get("channels", [])})
            assert channels["/gnomon/tf"]["schemaName"] == "foxglove.FrameTransform"
            assert channels["/gnomon/pose"]["schemaName"] == "foxglove.PoseInFrame"
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": k, "channelId": c["id"]} for k, c in enumerate(channels.values())]}))
            time.sleep(0.3)
            sink.write(_estimate(0.0, 10))
            got = [ws.recv(5) for _ in range(3)]
        assert all(isinstance(m, bytes) for m in got)
        state = json.loads(next(m for m in got if m.endswith(b"}"))[13:])  # after the header
        assert state["t"] == pytest.approx(0.045) and state["flags"]["rest"] is True
        assert state["bias_deg_s"]["x"] == pytest.approx(0.1)
        assert sink.sent == 1 and sink.rows == 10
    finally:
        sink.close()


# ---------------------------------------------------------------------- headless Chromium
def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class _Browser:
    """Headless Chromium on ``url``, driven through the DevTools protocol."""

    def __init__(self, chromium, url, tmp_path, size=(1250, 900)):
        self.proc = subprocess.Popen(
            [chromium, *CHROMIUM_FLAGS, f"--window-size={size[0]},{size[1]}",
             "--remote-debugging-port=0", f"--user-data-dir={tmp_path / 'ud'}", url],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
            env={**os.environ, "HOME": str(tmp_path)})
        self.log, self.id, self.stack = [], 0, contextlib.ExitStack()
        found = threading.Event()

        def drain():
            for line in self.proc.stderr:
                self.log.append(line.rstrip())
                if "DevTools listening on" in line:
                    found.set()

        threading.Thread(target=drain, daemon=True).start()
        if not found.wait(60):
            self.close()
            raise AssertionError("Chromium did not start:\n" + "\n".join(self.log[-20:]))
        port = re.search(r"ws://[^:]+:(\d+)/", next(x for x in self.log if "DevTools" in x))[1]
        for _ in range(100):
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=5) as r:
                pages = [p for p in json.load(r) if p["type"] == "page"]
            if pages:
                break
            time.sleep(0.1)
        self.ws = self.stack.enter_context(websockets_client.connect(
            pages[0]["webSocketDebuggerUrl"], max_size=None, open_timeout=10))

    def call(self, method, **params):
        self.id += 1
        self.ws.send(json.dumps({"id": self.id, "method": method, "params": params}))
        while True:
            m = json.loads(self.ws.recv(30))
            if m.get("id") == self.id:
                assert "error" not in m, m
                return m["result"]

    def evaluate(self, expression, check=True):
        r = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        assert not check or "exceptionDetails" not in r, r
        return r["result"].get("value") if "exceptionDetails" not in r else None

    def wait_for(self, expression, timeout=30.0):
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < timeout:
            if self.evaluate(expression, check=False):  # (the page may still be loading)
                return
            time.sleep(0.1)
        raise AssertionError(f"not true in {timeout} s: {expression}; console: "
                             f"{self.console()}")

    def screenshot(self):
        from PIL import Image

        data = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return Image.open(io.BytesIO(data)).convert("RGB"), data

    def rect(self, element_id):
        r = self.evaluate(f"JSON.stringify(document.getElementById('{element_id}')"
                          ".getBoundingClientRect())")
        r = json.loads(r)
        return int(r["left"]), int(r["top"]), int(r["right"]), int(r["bottom"])

    def console(self):
        return [line for line in self.log if ":CONSOLE" in line]

    def close(self):
        self.stack.close()
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)


@pytest.fixture
def browser_on(tmp_path):
    chromium = _chromium()
    if chromium is None:
        pytest.skip("Chromium not installed (Debian: apt-get install chromium): "
                    "browser check of the live view NOT run")
    opened = []

    def open_(url):
        b = _Browser(chromium, url, tmp_path)
        opened.append(b)
        return b

    yield open_
    for b in opened:
        b.close()


def _colour_pixels(img) -> dict:
    """Pixels of the axes' colours (red, green, blue faces and arrows, shaded)."""
    a = np.asarray(img).astype(int)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    return {"red": int(np.sum((r > 150) & (g < 100) & (b < 100))),
            "green": int(np.sum((g > 110) & (r < 110) & (b < 110))),
            "blue": int(np.sum((b > 150) & (r < 100) & (g < 150)))}


def test_the_page_renders_and_updates_in_headless_chromium(view, browser_on, tmp_path):
    view.write(_estimate(0.0, 1000))  # 5 s of history, then estimates in real time
    with _Feeder(view, rate_hz=200.0, chunk=5, t0=5.0) as feeder:
        b = browser_on(view.url)
        b.wait_for("document.getElementById('conn').textContent === 'connected' && "
                   "document.getElementById('t').textContent !== '–'")
        time.sleep(0.5)
        one, png1 = b.screenshot()
        t1 = float(b.evaluate("document.getElementById('t').textContent"))
        time.sleep(1.0)
        two, png2 = b.screenshot()
        t2 = float(b.evaluate("document.getElementById('t').textContent"))
        rate = float(b.evaluate("document.getElementById('rate').textContent"))
        written = feeder.rate_hz()
        flags = b.evaluate("document.getElementById('flags').textContent")
        bias = b.evaluate("document.getElementById('bx').textContent")
        body, trace = b.rect("body"), b.rect("trace")
    (tmp_path / "view-1.png").write_bytes(png1)
    (tmp_path / "view-2.png").write_bytes(png2)
    assert b.console() == [], b.console()
    # (a) it renders: not blank, and the body (its canvas) in its three colours
    assert np.asarray(one).std() > 20
    pixels = _colour_pixels(one.crop(body))
    assert min(pixels.values()) > 200, pixels
    assert min(_colour_pixels(one.crop(trace)).values()) > 100  # the three traces
    assert np.asarray(one.crop(trace)).std() > 10
    # (b) it updates: later estimates, the body turned, the traces moved on
    assert t2 > t1 + 0.5, (t1, t2)
    diff = np.abs(np.asarray(one.crop(body), float) - np.asarray(two.crop(body), float))
    assert np.mean(diff) > 2.0, np.mean(diff)
    assert np.any(np.asarray(one.crop(trace)) != np.asarray(two.crop(trace)))
    assert rate == pytest.approx(written, rel=0.3)
    assert "rest" in flags and "mag_disturbed" in flags and bias == "0.100"


def test_the_page_says_when_the_run_has_ended(view, browser_on):
    view.write(_estimate(0.0, 100))
    b = browser_on(view.url)
    b.wait_for("document.getElementById('conn').textContent === 'connected'")
    b.wait_for("document.getElementById('rows').textContent === '100'")
    view.close()
    b.wait_for("document.getElementById('conn').textContent.startsWith('stream ended')")
    assert b.console() == [], b.console()
