"""``swarm view RUN_DIR``: the recorded run in 3-D in a web browser, offline.

The run's ``run.mcap`` becomes a Rerun recording (``RUN_DIR/view.rrd``; rerun-sdk) and
the Rerun web viewer that the rerun-sdk wheel carries serves it on localhost: no
internet, no account. Time is the run's sim time (scrub it on the timeline); the scene
holds the obstacles to scale (spheres, and cylinders ``CYLINDER_LENGTH_M`` long), each
drone as its bounding sphere with its name, its trail of the last ``TRAIL_S`` seconds,
and a red marker where each collision began.

    swarm view runs/swap_2-20261202-010000            # opens http://127.0.0.1:9090
    swarm view RUN_DIR --port 9100 --no-browser

Kept library, not ours: Rerun (its viewer, web server and file format). Foxglove is the
other way to look at a run (``run.mcap`` and ``foxglove_layout.json``).
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections import deque
from pathlib import Path
from urllib.parse import quote

import numpy as np
import rerun as rr

from swarm.net.messages import CLOCK_XVR
from swarm.runs.foxglove_scene import CYLINDER_LENGTH_M, quat_z_to
from swarm.runs.runfiles import RecordingStream

TRAIL_S = 5.0  # s of trail per drone
VIEW_HZ = 25.0  # clocks drawn per second of sim time (the recorded rate is the control rate)
_DRONE = (30, 115, 240)
_OBSTACLE = (140, 150, 175)
_TRAIL = (240, 140, 25)
_CONTACT = (230, 15, 15)


def _obstacles(items: list[dict]) -> None:
    spheres = [it for it in items if not any(it["a"])]
    cylinders = [it for it in items if any(it["a"])]
    if spheres:
        rr.log(
            "world/obstacles/spheres",
            rr.Ellipsoids3D(
                centers=[it["c"] for it in spheres],
                half_sizes=[[it["r"]] * 3 for it in spheres],
                colors=_OBSTACLE,
                fill_mode="solid",
                labels=[it["id"] for it in spheres],
            ),
        )
    if cylinders:
        rr.log(
            "world/obstacles/cylinders",
            rr.Cylinders3D(
                lengths=[CYLINDER_LENGTH_M] * len(cylinders),
                radii=[it["r"] for it in cylinders],
                centers=[it["c"] for it in cylinders],
                quaternions=[rr.Quaternion(xyzw=quat_z_to(it["a"])) for it in cylinders],
                colors=_OBSTACLE,
                fill_mode="solid",
                labels=[it["id"] for it in cylinders],
            ),
        )


def write_rrd(run_dir: Path, out: Path | None = None) -> Path:
    """``run_dir/run.mcap`` as a Rerun recording at ``out`` (default ``run_dir/view.rrd``)."""
    out = out or run_dir / "view.rrd"
    records = RecordingStream(run_dir / "run.mcap")  # (read once: an hour of flight does not fit in memory)
    rec = rr.RecordingStream("c3swarm", recording_id=run_dir.name)
    with rec:
        rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        trails: dict[str, deque] = {}
        where: dict[str, np.ndarray] = {}
        last_t = -np.inf
        moving = None
        contacts: list[np.ndarray] = []
        for r in records:
            if r.get("kind") == "collision":
                pts = [where[n] for n in (r["a"], r["b"]) if n in where]
                if pts:
                    contacts.append(np.mean(pts, axis=0))
                    rr.set_time("sim_time", duration=float(r["t"]))
                    rr.log("world/collisions", rr.Points3D(contacts, radii=0.06, colors=_CONTACT))
                continue
            if r.get("kind") != "clock":
                continue
            t = float(r["t"])
            ids = list(r["ids"])
            xvr = np.asarray(r["xvr"], dtype=float).reshape(len(ids), CLOCK_XVR)
            for i, name in enumerate(ids):
                where[name] = xvr[i, :3]
                trail = trails.setdefault(name, deque())
                trail.append((t, xvr[i, :3].copy()))
                while trail[0][0] < t - TRAIL_S:
                    trail.popleft()
            if t - last_t < 1.0 / VIEW_HZ - 1e-9:
                continue
            last_t = t
            rr.set_time("sim_time", duration=t)
            rr.log("world/drones", rr.Points3D(xvr[:, :3], radii=xvr[:, 6], colors=_DRONE, labels=ids))
            rr.log("world/trails", rr.LineStrips3D([[x for _, x in trails[n]] for n in ids], colors=_TRAIL, radii=0.01))
            items = r["items"]
            now_moving = any(any(it["cd"]) for it in items)
            if moving is None or now_moving:  # static obstacles once, moving ones at every frame
                _obstacles(items)
            moving = now_moving
        rec.save(str(out))
    return out


def viewer_url(port: int, grpc_port: int) -> str:
    """The address that opens the web viewer on the served recording."""
    data = quote(f"rerun+http://127.0.0.1:{grpc_port}/proxy", safe="")
    return f"http://127.0.0.1:{port}/?url={data}&renderer=webgl"


def main(run_dir: Path, port: int = 9090, browser: bool = True) -> int:
    """Write the recording and serve it with Rerun's web viewer (HTTP on ``port``, its
    data on ``port + 1``, both on 127.0.0.1) until interrupted."""
    rrd = write_rrd(run_dir)
    grpc_port = port + 1
    cmd = [
        sys.executable,
        "-m",
        "rerun",
        str(rrd),
        "--web-viewer",
        "--bind",
        "127.0.0.1",
        "--web-viewer-port",
        str(port),
        "--port",
        str(grpc_port),
        "--renderer",
        "webgl",
    ]
    print(f"serving {rrd}: open {viewer_url(port, grpc_port)} (Ctrl-C stops)", flush=True)
    env = dict(os.environ)
    if not browser:
        env["BROWSER"] = "true"  # Python's webbrowser runs `true`: opens nothing
    try:
        return subprocess.run(cmd, env=env).returncode
    except KeyboardInterrupt:
        return 0
