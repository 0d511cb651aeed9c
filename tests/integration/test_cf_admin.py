"""``swarm cf``: find Crazyflies, read their supervisor, recover, reboot: the CLI through
cflib against a software-in-the-loop Crazyflie (world/sitl_cf.py), which answers the
supervisor's requests as crtp_supervisor.c does."""

from __future__ import annotations

import math
import socket
import struct
import subprocess
import sys
import threading

import numpy as np
import pytest

from swarm.rotation import euler_to_quat
from swarm.world.sitl_cf import SitlDrone, run

PORT = 19858  # in cflib's UDP scan range (19850-19859), apart from the mixed runs' 19850 and 19851


@pytest.fixture
def drone():
    d = SitlDrone.start("cfA", PORT, [0.0, 0.0, 0.0], 0.0)
    stop = threading.Event()
    t = threading.Thread(target=run, args=([d], _free_udp_port(), stop), daemon=True)
    t.start()
    yield d
    stop.set()
    t.join(2.0)
    d.close()


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def swarm_cf(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm.cli", "cf", *args], capture_output=True, text=True, timeout=60)


def _send(d: SitlDrone, header: int, body: bytes) -> None:
    """Send one packet, then a link echo (port 15, channel 0): a firmware answers neither a
    commander setpoint nor the supervisor's stop, but it serves packets in order, so the echo's
    answer says the packet was taken."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(bytes([header]) + body, ("127.0.0.1", PORT))
        s.sendto(bytes([0xF0]) + b"taken?", ("127.0.0.1", PORT))
        s.settimeout(5.0)
        while s.recv(64) != bytes([0xF0]) + b"taken?":
            pass


def test_scan_finds_the_drone_and_status_reads_its_supervisor(drone):
    res = swarm_cf("scan")
    assert res.returncode == 0 and drone.uri in res.stdout.split(), res
    res = swarm_cf("status", drone.uri)
    assert res.returncode == 0, res.stderr
    states = res.stdout.strip().split(", ")
    assert "Can fly" in states and "Is locked" not in states
    _send(drone, 0x90 | 0x0C | 1, struct.pack("<B", 3))  # the supervisor's emergency stop
    assert "Is locked" in swarm_cf("status", drone.uri).stdout  # locked: it needs a reboot now


def test_recover_clears_a_crash_once_the_drone_is_upright(drone):
    _send(drone, 0x3C, struct.pack("<fffH", 0.0, 0.0, 0.0, 0))  # unlock, then fly
    _send(drone, 0x3C, struct.pack("<fffH", 0.0, 0.0, 0.0, 40_000))
    with drone.lock:  # knocked upside down in flight
        drone.state.q = euler_to_quat(math.pi, 0.0, 0.0)
    assert "Is crashed" in swarm_cf("status", drone.uri).stdout
    assert "Is crashed" in swarm_cf("recover", drone.uri).stdout  # still upside down: refused
    with drone.lock:
        drone.state.q, drone.state.Omega_b = euler_to_quat(0.0, 0.0, 0.0), np.zeros(3)
    res = swarm_cf("recover", drone.uri)
    assert res.returncode == 0 and "Is crashed" not in res.stdout and "Can fly" in res.stdout, res


def test_reboot_and_status_fail_clearly_where_they_cannot_work():
    res = swarm_cf("reboot", "udp://127.0.0.1:19859")
    assert res.returncode == 2 and "Crazyradio" in res.stderr
    res = swarm_cf("status", "udp://127.0.0.1:19859")  # nothing there
    assert res.returncode == 2 and "udp://127.0.0.1:19859" in res.stderr


def test_check_reads_back_what_the_firmware_decoded_and_it_follows_the_rules(drone):
    """swarm cf check (propellers off): the known sequence, read back through cflib's log
    subsystem (ctrltarget), agrees with the firmware's rules: roll as sent, pitch negated,
    yaw rate counter-clockwise as asked, thrust unlocked at the command sent."""
    res = swarm_cf("check", drone.uri)
    assert res.returncode == 0, res.stdout + res.stderr
    lines = res.stdout.strip().splitlines()
    assert len(lines) == 4 and all(line.startswith("ok") for line in lines), lines
    assert "pitch -10" in lines[1] and "yaw 30" in lines[2]
