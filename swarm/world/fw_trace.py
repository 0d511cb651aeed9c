"""A firmware drone's trace as the relay (``swarm.world.sitl_fw``) writes it to
``DIR/NAME.jsonl``, read back (:func:`read_trace`) by the tests and ``tools.bench_firmware``."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import orjson


@dataclass
class FirmwareTrace:
    """One drone's trace (:func:`read_trace`); times are monotonic seconds of the machine.

    ``body_*``: the body at 100 Hz (position [m], quaternion x, y, z, w, motor PWM, the
    collective thrust it made [N]); ``fw_*``: the firmware's own log at 100 Hz (its state,
    supervisor bits, the setpoint it flies: roll, pitch [deg], yaw rate [deg/s], thrust
    command; its position estimate [m]); ``sp_*``: every RPYT setpoint relayed (roll [deg],
    pitch [deg, as on the wire], yaw rate [deg/s, as on the wire], thrust command);
    ``pose_*``: every external pose relayed (position [m]); ``packets``: (t, what) of stops,
    emergency stops and the notify-stop; ``end``: the
    summary the relay wrote last (counters, CPU time, final state, transitions)."""

    body_t: np.ndarray
    body_x: np.ndarray
    body_q: np.ndarray
    body_pwm: np.ndarray
    body_thrust_N: np.ndarray
    fw_t: np.ndarray
    fw_clock_s: np.ndarray  # the firmware's own clock at each sample (its log's timestamp) [s]
    fw_state: list[str]
    fw_info: np.ndarray
    fw_setpoint: np.ndarray  # (n, 4): roll, pitch, yaw rate, thrust
    fw_estimate: np.ndarray  # (n, 3) m
    sp_t: np.ndarray
    sp: np.ndarray  # (n, 4)
    pose_t: np.ndarray
    pose_x: np.ndarray  # (n, 3) m
    packets: list[tuple[float, str]]
    end: dict[str, Any]

    def transitions(self) -> list[tuple[float, str]]:
        """(t, state) where the firmware's state changed, starting with its first."""
        out: list[tuple[float, str]] = []
        for t, s in zip(self.fw_t, self.fw_state, strict=True):
            if not out or out[-1][1] != s:
                out.append((float(t), s))
        return out


def _records(path: Path) -> Iterator[dict[str, Any]]:
    for line in path.read_bytes().splitlines():
        try:
            yield orjson.loads(line)
        except orjson.JSONDecodeError:  # a line cut by a killed relay
            continue


def read_trace(path: Path) -> FirmwareTrace:
    """Read ``DIR/NAME.jsonl`` as the relay wrote it."""
    body, fw, sp, pose, pk, end = [], [], [], [], [], {}
    for r in _records(path):
        kind = r.get("k")
        if kind == "body":
            body.append(r)
        elif kind == "fw":
            fw.append(r)
        elif kind == "sp":
            sp.append(r)
        elif kind == "pose":
            pose.append(r)
        elif kind == "pkt":
            pk.append((r["t"], r["what"]))
        elif kind == "end":
            end = r
    nan = math.nan
    return FirmwareTrace(
        body_t=np.array([r["t"] for r in body]),
        body_x=np.array([r["x"] for r in body]).reshape(-1, 3),
        body_q=np.array([r["q"] for r in body]).reshape(-1, 4),
        body_pwm=np.array([r["pwm"] for r in body]).reshape(-1, 4),
        body_thrust_N=np.array([r["thrust_N"] for r in body]),
        fw_t=np.array([r["t"] for r in fw]),
        fw_clock_s=np.array([r.get("t_fw_ms", nan) / 1000.0 for r in fw]),
        fw_state=[r["state"] for r in fw],
        fw_info=np.array([int(r.get("supervisor.info", 0)) for r in fw], dtype=int),
        fw_setpoint=np.array(
            [
                [r.get(f"ctrltarget.{n}", nan) for n in ("roll", "pitch", "yaw")] + [r.get("stabilizer.thrust", nan)]
                for r in fw
            ]  # fmt: skip
        ).reshape(-1, 4),
        fw_estimate=np.array([[r.get(f"stateEstimateZ.{n}", nan) / 1000.0 for n in "xyz"] for r in fw]).reshape(-1, 3),
        sp_t=np.array([r["t"] for r in sp]),
        sp=np.array([[r["roll"], r["pitch"], r["yaw"], r["thrust"]] for r in sp]).reshape(-1, 4),
        pose_t=np.array([r["t"] for r in pose]),
        pose_x=np.array([r["x"] for r in pose]).reshape(-1, 3),
        packets=pk,
        end=end,
    )
