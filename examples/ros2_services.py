"""The scripted experiment of ``scripted_experiment.py``, through Crazyswarm2's services on the
run's ROS 2 bridge (docs/ros2.md, "Services"), called with zenoh-ros2-sdk, a pure-Python ROS 2
client over rmw_zenoh (``pip install -e '.[dev]'`` installs it; no ROS 2 needed):

    swarm run configs/ros2_lab.yaml --out runs/r1          # one shell: the swarm, waiting
    python examples/ros2_services.py runs/r1               # another: take off, square, swap, land

    python examples/ros2_services.py                       # or: start the run itself (runs/ros2_services)

It joins as the run's ROS 2 participant (``runs/r1/secrets/ros2.env``, as ``ros2`` would) and
hands zenoh-ros2-sdk the interface definitions this project ships (crazyflie_interfaces'
requests, and the standard messages from rosbags), so nothing is downloaded.
"""

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import zenoh_ros2_sdk as sdk

from swarm.config import load
from swarm.net.ros2.interfaces import message_definition
from swarm.net.ros2.services import EMPTY_RESPONSE, REQUESTS
from swarm.ros2.participant import ENV_FILE, read_env

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "ros2_lab.yaml"
SQUARE = [[-0.5, -0.5, 1.0], [0.5, -0.5, 1.0], [0.5, 0.5, 1.0], [-0.5, 0.5, 1.0]]  # m, world


def definitions(folder: Path) -> Path:
    """The .msg files zenoh-ros2-sdk needs (the requests' and the poses' types and theirs),
    written from rosbags' own definitions."""
    for top in ("builtin_interfaces/msg/Duration", "geometry_msgs/msg/Point", "geometry_msgs/msg/PoseStamped"):
        name, *rest = [top, *message_definition(top).split("\n" + "=" * 80 + "\nMSG: ")]
        for block in [f"{name}\n{rest[0]}", *rest[1:]]:
            t, _, text = block.partition("\n")
            package, _, msg = t.rpartition("/")
            path = folder / package.split("/")[0] / "msg" / f"{msg}.msg"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
    return folder


class Crazyswarm:
    """Calls of the run's services, and each drone's newest pose."""

    def __init__(self) -> None:
        self.clients: dict[str, sdk.ROS2ServiceClient] = {}
        self.poses: dict[str, np.ndarray] = {}
        self.subs = [
            sdk.ROS2Subscriber(f"/{d}/pose", "geometry_msgs/msg/PoseStamped", self._pose(d), node_name="example")
            for d in ("cf1", "cf2", "cf3")
        ]
        types = sdk.ZenohSession.get_instance().store.types
        self.duration, self.point = types["builtin_interfaces/msg/Duration"], types["geometry_msgs/msg/Point"]

    def _pose(self, d: str):
        def on(msg) -> None:
            p = msg.pose.position
            self.poses[d] = np.array([p.x, p.y, p.z])

        return on

    def call(self, name: str, srv: str, **fields) -> None:
        if name not in self.clients:
            self.clients[name] = sdk.ROS2ServiceClient(
                name, f"crazyflie_interfaces/srv/{srv}", request_definition=REQUESTS[srv],
                response_definition=EMPTY_RESPONSE, node_name="example", timeout=30.0,
            )  # fmt: skip
        if self.clients[name].call(**fields) is None:
            raise RuntimeError(f"{name}: no answer (see the run's logs/ros2.log)")

    def wait(self, d: str, ok, what: str, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not (d in self.poses and ok(self.poses[d])):
            if time.monotonic() > deadline:
                raise TimeoutError(f"{d} not {what} within {timeout_s} s")
            time.sleep(0.01)

    def sec(self, s: float):
        return self.duration(sec=int(s), nanosec=int(round((s % 1) * 1e9)))


def experiment(cs: Crazyswarm) -> None:
    cs.call("/all/takeoff", "Takeoff", group_mask=0, height=1.0, duration=cs.sec(2.5))
    for d in ("cf1", "cf2", "cf3"):
        cs.wait(d, lambda x: abs(x[2] - 1.0) < 0.15, "at 1 m")
    print("all at 1 m")
    for c in (np.array(c) for c in SQUARE):
        goal = cs.point(x=c[0], y=c[1], z=c[2])
        cs.call("/cf1/go_to", "GoTo", group_mask=0, relative=False, goal=goal, yaw=0.0, duration=cs.sec(1.5))
        cs.wait("cf1", lambda x, c=c: np.linalg.norm(x - c) < 0.15, f"at {c.tolist()}")
        print(f"cf1 at {c.tolist()}")
    a, b = cs.poses["cf1"].copy(), cs.poses["cf2"].copy()
    for d, x in (("cf1", b), ("cf2", a)):
        goal = cs.point(x=float(x[0]), y=float(x[1]), z=1.0)
        cs.call(f"/{d}/go_to", "GoTo", group_mask=0, relative=False, goal=goal, yaw=0.0, duration=cs.sec(3.0))
    cs.wait("cf1", lambda x: np.linalg.norm(x[:2] - b[:2]) < 0.15, "in cf2's place")
    cs.wait("cf2", lambda x: np.linalg.norm(x[:2] - a[:2]) < 0.15, "in cf1's place")
    print("cf1 and cf2 swapped")
    cs.call("/all/land", "Land", group_mask=0, height=0.04, duration=cs.sec(2.0))
    for d in ("cf1", "cf2", "cf3"):
        cs.wait(d, lambda x: x[2] < 0.3, "landed")
    print("landed")


def main(run_dir: Path | None, out: Path, mode: str | None = None) -> None:
    handle = None
    if run_dir is None:
        from swarm.runs.launch import RunHandle

        handle = RunHandle.start(load(CONFIG, {"time": {"mode": mode}} if mode else None), out)
        run_dir = out
    cfg = load(run_dir / "config.yaml")
    os.environ.update(read_env(run_dir / "secrets" / ENV_FILE))  # what `source .../ros2.env` does
    with tempfile.TemporaryDirectory() as tmp:
        sdk.get_registry().messages_dir = definitions(Path(tmp))
        sdk.ZenohSession.get_instance(cfg.network.host, cfg.network.port)
        try:
            experiment(Crazyswarm())
        finally:
            sdk.ZenohSession.get_instance().close()
            if handle is not None:
                handle.finish("the example is done")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir", nargs="?", type=Path, help="the folder of a running swarm (swarm run ... --out DIR)")
    ap.add_argument(
        "--mode", choices=["realtime", "lockstep"], help="the run's time.mode (no run_dir; default: the config's)"
    )
    ap.add_argument("--out", type=Path, default=Path("runs/ros2_services"), help="where to start the run (no run_dir)")
    args = ap.parse_args()
    main(args.run_dir, args.out, args.mode)
