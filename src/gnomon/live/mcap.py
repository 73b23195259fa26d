"""``--mcap FILE``: the live estimates as an MCAP file with Foxglove's schemas (foxglove-sdk),
which Foxglove (and so ROS 2 users, who open MCAP there) shows without a plugin.

Per estimate, three messages:

==========================  =======================  =========================================
topic                       schema                   what
==========================  =======================  =========================================
``/gnomon/pose``            ``foxglove.PoseInFrame``  ``frame_id`` ``"enu"``, orientation the
                                                     estimate, position 0
``/gnomon/transform``       ``foxglove.FrameTransform``  parent ``"enu"``, child ``"body"``, the
                                                     same rotation (the 3-D panel's frames)
``/gnomon/state``           JSON (a JSON Schema)     :func:`gnomon.live.sinks.estimate_rows`:
                                                     ``t``, ``q``, ``euler_deg``, the bias
                                                     (``bias_rad_s``) and every flag
==========================  =======================  =========================================

Frames: the orientation is gnomon's ``q_rb`` (reference from body: ENU from the body frame of
the stream, FLU for MAVLink and the log readers) as Foxglove's ``Quaternion`` ``{x, y, z,
w}``; Foxglove's pose and transform mean the same rotation (the child's axes expressed in
the parent). The transform is on ``/gnomon/transform`` rather than ``/tf``, so that a file
merged with a ROS 2 bag does not mix it into that bag's ``tf2_msgs`` topic.

Time: every message's ``timestamp`` and its MCAP ``log_time`` and ``publish_time`` are the
estimate's ``t`` (the sensor's clock: the gyro sample's stamp, s -> ns), not the arrival
time. Assumed to be what a Foxglove user wants: the timeline is the data's own (a replay
shows its recording's time, not the speed it was replayed at; a MAVLink stream the
autopilot's boot clock, which its own logs use too), and it increases strictly (the live
filter drops gyro stamps that do not). A stream whose first stamp is negative is shifted
to start at 0 (MCAP times are unsigned; the shift is in ``describe()`` and in the file's
``gnomon`` metadata record, which foxglove-sdk 0.10 cannot write and 0.30 does).

The file is written through a ``foxglove.Context`` of its own, so that a Foxglove
WebSocket server started elsewhere in the process does not receive these channels (and
this file not theirs). An existing file is replaced, as ``--out`` does. Nothing is in the
file until ``close`` (the writer's chunks; a killed process leaves a file Foxglove may
refuse: ``mcap recover`` repairs it).
"""

from __future__ import annotations

import json
from pathlib import Path

from gnomon.errors import InputError
from gnomon.live.sinks import estimate_rows

__all__ = ["McapSink", "POSE_TOPIC", "TRANSFORM_TOPIC", "STATE_TOPIC"]

POSE_TOPIC = "/gnomon/pose"
TRANSFORM_TOPIC = "/gnomon/transform"
STATE_TOPIC = "/gnomon/state"
REFERENCE_FRAME = "enu"
BODY_FRAME = "body"


def _foxglove():
    try:
        import foxglove
    except ImportError:
        raise InputError("--mcap needs foxglove-sdk: pip install 'gnomon[live]'",
                         field="--mcap") from None
    try:
        from foxglove import messages
    except ImportError:  # foxglove-sdk before the rename of ``schemas`` to ``messages``
        from foxglove import schemas as messages
    return foxglove, messages


def _schema(row: dict) -> dict:
    """A JSON Schema of ``/gnomon/state`` from its first row (the live estimates' signals
    do not change during a run)."""
    props = {}
    for name, v in row.items():
        if isinstance(v, bool):
            props[name] = {"type": "boolean"}
        elif isinstance(v, list):
            props[name] = {"type": "array", "items": {"type": ["number", "null"]}}
        else:
            props[name] = {"type": ["number", "null"]}
    return {"type": "object", "title": "gnomon.LiveState", "properties": props}


class McapSink:
    """An MCAP file of the estimates (module docstring): ``write(est, arrivals)``,
    ``close()``, ``describe()`` as every live sink."""

    def __init__(self, path):
        self.path = Path(path)
        foxglove, self._msg = _foxglove()
        from foxglove.channels import FrameTransformChannel, PoseInFrameChannel

        self._fox = foxglove
        self.context = foxglove.Context()
        try:
            self.writer = foxglove.open_mcap(str(self.path), allow_overwrite=True,
                                             context=self.context)
        except Exception as err:  # noqa: BLE001 - the SDK raises its own errors
            raise InputError(f"cannot write ({err})", file=str(self.path),
                             field="--mcap") from None
        self.pose = PoseInFrameChannel(POSE_TOPIC, context=self.context)
        self.transform = FrameTransformChannel(TRANSFORM_TOPIC, context=self.context)
        self.state = None  # the JSON channel, made on the first row (its schema)
        self.rows = 0
        self.offset_ns = None  # added to every stamp (non-zero when the first is negative)
        self.metadata_written = False  # the "gnomon" metadata record (frames, time offset)
        self._closed = False

    def write(self, est, arrivals=None) -> None:
        m = self._msg
        for row in estimate_rows(est):
            ns = round(row["t"] * 1e9)
            if self.offset_ns is None:
                self.offset_ns = -ns if ns < 0 else 0
            ns = max(0, ns + self.offset_ns)
            stamp = m.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)
            w, x, y, z = row["q"]
            q = m.Quaternion(x=x, y=y, z=z, w=w)
            origin = m.Vector3(x=0.0, y=0.0, z=0.0)
            self.pose.log(m.PoseInFrame(timestamp=stamp, frame_id=REFERENCE_FRAME,
                                        pose=m.Pose(position=origin, orientation=q)),
                          log_time=ns)
            self.transform.log(m.FrameTransform(timestamp=stamp,
                                                parent_frame_id=REFERENCE_FRAME,
                                                child_frame_id=BODY_FRAME, translation=origin,
                                                rotation=m.Quaternion(x=x, y=y, z=z, w=w)),
                               log_time=ns)
            if self.state is None:
                self.state = self._fox.Channel(STATE_TOPIC, schema=_schema(row),
                                               message_encoding="json", context=self.context)
            self.state.log(json.dumps(row, allow_nan=False).encode(), log_time=ns)
            self.rows += 1

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        meta = {"reference_frame": REFERENCE_FRAME, "body_frame": BODY_FRAME,
                "time": "the estimate's t (the sensor clock), ns",
                "time_offset_s": repr((self.offset_ns or 0) * 1e-9)}
        try:
            self.writer.write_metadata("gnomon", meta)
            self.metadata_written = True
        except Exception:  # noqa: BLE001 - foxglove-sdk 0.10 has no metadata records
            pass
        self.writer.close()

    def describe(self) -> dict:
        return {"sink": "mcap", "path": str(self.path), "rows": self.rows,
                "topics": [POSE_TOPIC, TRANSFORM_TOPIC, STATE_TOPIC],
                "time_offset_s": (self.offset_ns or 0) * 1e-9}
