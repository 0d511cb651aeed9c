"""What a ROS 2 participant needs to join a run (pure): its environment.

``swarm run`` writes it to ``<run>/secrets/ros2.env`` (readable by its owner alone: it holds
the run's ``ros2`` password); ``source`` it in a shell, then ``ros2 topic list``. It sets
``RMW_IMPLEMENTATION=rmw_zenoh_cpp``, ``ROS_DOMAIN_ID`` and ``ZENOH_CONFIG_OVERRIDE``, which
rmw_zenoh_cpp (and zenoh-ros2-sdk) apply over their default session config: client mode,
linked to the run's router alone, with the run's credentials (and TLS files, if the run
uses TLS).
"""

from __future__ import annotations

import json
import os
import shlex
from pathlib import Path

from swarm.config import ScenarioConfig
from swarm.net import access


def zenoh_override(cfg: ScenarioConfig, secrets: Path | None) -> str:
    """``ZENOH_CONFIG_OVERRIDE``: ``key=json5 value`` pairs separated by ``;``."""
    net = cfg.network
    proto = "tls" if net.tls.enabled else "tcp"
    pairs: dict[str, object] = {"mode": "client", "connect/endpoints": [f"{proto}/{net.host}:{net.port}"]}
    pairs["scouting/multicast/enabled"] = False
    if secrets is not None:
        pairs["transport/auth/usrpwd/user"] = access.ROS2
        pairs["transport/auth/usrpwd/password"] = access.password(secrets, access.ROS2)
        if net.tls.enabled:
            files = net.tls.files(secrets, access.ROS2)
            pairs["transport/link/tls/root_ca_certificate"] = str(files.root_ca)
            if net.tls.mutual:
                pairs["transport/link/tls/connect_certificate"] = str(files.certificate)
                pairs["transport/link/tls/connect_private_key"] = str(files.private_key)
    return ";".join(f"{k}={json.dumps(v)}" for k, v in pairs.items())


def participant_env(cfg: ScenarioConfig, secrets: Path | None) -> dict[str, str]:
    return {
        "RMW_IMPLEMENTATION": "rmw_zenoh_cpp",
        "ROS_DOMAIN_ID": str(cfg.ros2.domain_id),
        "ZENOH_CONFIG_OVERRIDE": zenoh_override(cfg, secrets),
    }


ENV_FILE = "ros2.env"


def write_env(cfg: ScenarioConfig, folder: Path, secrets: Path | None) -> Path:
    """``folder/ros2.env`` (mode 0600): ``export`` lines a shell can ``source``."""
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    path = folder / ENV_FILE
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        for k, v in participant_env(cfg, secrets).items():
            f.write(f"export {k}={shlex.quote(v)}\n")
    return path


def read_env(path: Path) -> dict[str, str]:
    """The variables of a :func:`write_env` file."""
    out = {}
    for line in path.read_text().splitlines():
        if line.startswith("export "):
            k, _, v = line.removeprefix("export ").partition("=")
            out[k] = shlex.split(v)[0] if v else ""
    return out
