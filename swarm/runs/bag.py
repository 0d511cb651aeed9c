"""A run as a ROS 2 bag: ``run.mcap`` -> ``<run>/ros2_bag/`` (rosbag2's folder: its
``metadata.yaml`` and one MCAP file with ``ros2msg`` schemas and ``cdr`` messages), which
``ros2 bag info``/``play``, Foxglove and rosbags open.

    swarm ros2-bag RUN_DIR [--out DIR]      (or ros2.bag: true in the config)

The topics are the bridge's (:mod:`swarm.net.ros2.topics`), but every tick: each drone's pose and
velocity at each of its measurements, ``/tf`` and ``/clock`` at each clock, its filter status
at each command and the obstacles at each clock, stamped (and logged) at sim time. rosbags
writes the folder; the messages are :mod:`swarm.ros2.convert`'s, as the bridge sends them.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np

from swarm.net.ros2.interfaces import serialize, store
from swarm.net.ros2.topics import TYPES, Kind, Topic, run_topics
from swarm.ros2 import convert
from swarm.runs.runfiles import RecordingStream, read_config

BAG_DIR = "ros2_bag"


class _Bag:
    def __init__(self, writer: Any, topics: list[Topic]) -> None:
        self.writer = writer
        self.conns = {
            (t.kind, t.agent): writer.add_connection(t.name, t.ros_type, typestore=store())
            for t in topics
            if not t.inbound
        }
        self.count = 0

    def write(self, kind: Kind, agent: str | None, t_s: float, msg: Any) -> None:
        self.writer.write(self.conns[(kind, agent)], int(round(t_s * 1e9)), serialize(msg, TYPES[kind]))
        self.count += 1


def write_bag(run_dir: Path, out: Path | None = None) -> tuple[Path, int]:
    """Write the bag of the run in ``run_dir`` to ``out`` (default ``run_dir/ros2_bag``,
    replaced if there); returns the folder and the number of messages."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    cfg = read_config(run_dir)
    r = cfg.ros2
    ids = [a.id for a in cfg.agents]
    lengths = {o.id: o.length_m for o in cfg.obstacles}
    out = out or run_dir / BAG_DIR
    if out.exists():
        shutil.rmtree(out)
    frame = r.frame_id
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        bag = _Bag(writer, run_topics(r.namespace, ids))
        tick: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # drone -> (x, q) of the clock read last
        tick_t = 0.0  # its sim time [s]
        for rec in RecordingStream(run_dir / "run.mcap"):
            kind, t = rec.get("kind"), float(rec.get("t", 0.0))
            if kind == "clock":
                if tick:
                    _tf(bag, frame, tick_t, tick)
                tick, tick_t = {}, t
                bag.write(Kind.CLOCK, None, t, convert.clock(t))
            elif kind == "measurement":
                name = str(rec.get("agent") or rec["topic"].split("/")[-2])
                if name not in ids:
                    continue
                x, v, q, w = (np.asarray(rec[f], float) for f in ("x", "v", "q", "w"))
                bag.write(Kind.POSE, name, t, convert.pose_stamped(t, frame, x, q))
                bag.write(Kind.VELOCITY, name, t, convert.twist_stamped(t, frame, v, w, q))
                tick[name] = (x, q)
            elif kind == "obstacles" and rec.get("items"):
                bag.write(Kind.OBSTACLES, None, t, convert.marker_array(t, frame, rec["items"], lengths))
            elif kind == "command" and rec.get("src") in ids:
                bag.write(Kind.STATUS, rec["src"], t, convert.filter_status(rec["src"], rec))
        if tick:
            _tf(bag, frame, tick_t, tick)
    return out, bag.count


def _tf(bag: _Bag, frame: str, t_s: float, tick: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    names = list(tick)
    x = np.array([tick[n][0] for n in names])
    q = np.array([tick[n][1] for n in names])
    bag.write(Kind.TF, None, t_s, convert.tf_message(t_s, frame, names, x, q))
