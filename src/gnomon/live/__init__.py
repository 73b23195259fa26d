"""Live estimation: sensors as they arrive, a filter per sample, estimates out as they
are made — the only part of gnomon that knows sockets and serial ports.

:class:`LiveFilter` (:mod:`gnomon.live.stream`) aligns per-sensor samples on their own
rates and clocks into a filter's rows; :mod:`gnomon.live.parse` reads lines (CSV, JSON);
:mod:`gnomon.live.sources` (UDP, serial, MAVLink, replay) and :mod:`gnomon.live.sinks`
(files, UDP JSON; MCAP and MAVLink in their own modules; the browser view in
:mod:`gnomon.live.view`) connect it; :func:`run_live` (:mod:`gnomon.live.runner`) is the
loop ``gnomon live`` runs.
"""

from gnomon.live.parse import LineParser, Malformed
from gnomon.live.runner import LiveRun, run_live
from gnomon.live.sources import open_source
from gnomon.live.stream import LiveFilter

__all__ = ["LiveFilter", "LineParser", "Malformed", "LiveRun", "run_live", "open_source"]
