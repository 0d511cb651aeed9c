"""Across machines for real: the world, the recorder and the router in one Linux network
namespace, each agent in another, linked by veth pairs to a bridge, as three hosts on a
LAN would be. Every process is started by hand, as docs/running.md's "Across machines"
says (``swarm secrets``, then ``swarm router``, ``swarm record``, ``swarm world`` and one
``swarm agent`` per host, each with ``--secrets``), and the swap is flown through the router
at 10.123.0.1. The namespaces are made and removed by the test (it needs root and
iproute2); elsewhere it is skipped with the reason."""

from __future__ import annotations

import json
import os
import re
import secrets
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from swarm.config import dump
from swarm.runs.runfiles import write_metrics

from .conftest import scenario

SUBNET = "10.123.0"
ROUTER_HOST = f"{SUBNET}.1"
PORT = 7447  # free: the namespace is new


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


def _why_not() -> str | None:
    if shutil.which("ip") is None:
        return "iproute2's ip is not installed"
    if os.geteuid() != 0:
        return "making network namespaces needs root"
    probe = f"c3probe{secrets.token_hex(2)}"
    try:
        _ip("netns", "add", probe)
    except subprocess.CalledProcessError as exc:
        return f"ip netns add failed: {exc.stderr.strip()}"
    _ip("netns", "del", probe)
    return None


@pytest.fixture
def lan() -> Iterator[dict[str, str]]:
    """Three namespaces, ``hub`` (10.123.0.1, a bridge) and two hosts ``a`` (.2) and
    ``b`` (.3), each linked to the bridge by a veth pair; removed afterwards."""
    why = _why_not()
    if why:
        pytest.skip(why)
    tag = secrets.token_hex(2)
    ns = {"hub": f"c3hub{tag}", "a": f"c3a{tag}", "b": f"c3b{tag}"}
    try:
        for name in ns.values():
            _ip("netns", "add", name)
            _ip("-n", name, "link", "set", "lo", "up")
        _ip("-n", ns["hub"], "link", "add", "br0", "type", "bridge")
        _ip("-n", ns["hub"], "addr", "add", f"{ROUTER_HOST}/24", "dev", "br0")
        _ip("-n", ns["hub"], "link", "set", "br0", "up")
        for i, host in enumerate(("a", "b"), start=2):
            _ip(
                "link",
                "add",
                f"c3{host}{tag}h",
                "netns",
                ns["hub"],
                "type",
                "veth",
                "peer",
                "name",
                "eth0",
                "netns",
                ns[host],
            )
            _ip("-n", ns["hub"], "link", "set", f"c3{host}{tag}h", "master", "br0", "up")
            _ip("-n", ns[host], "addr", "add", f"{SUBNET}.{i}/24", "dev", "eth0")
            _ip("-n", ns[host], "link", "set", "eth0", "up")
        yield ns
    finally:
        for name in ns.values():  # (removing a namespace removes its ends of the veth pairs)
            subprocess.run(["ip", "netns", "del", name], capture_output=True)


class Hosts:
    """Processes started in namespaces, each in its own process group. Each one's output is
    read line by line by a thread of its own, kept in its log, and waited on (no polling).
    The first line of each is the network namespace it runs in, printed by the shell that
    ``ip netns exec`` started, in the very process that then becomes ``swarm``."""

    def __init__(self, logs: Path) -> None:
        self.logs, self.procs = logs, {}
        self.lines: dict[str, list[str]] = {}
        self.ended: set[str] = set()  # whose output has ended
        self._changed = threading.Condition()
        logs.mkdir(parents=True, exist_ok=True)

    def start(self, name: str, netns: str, *args: str) -> subprocess.Popen[bytes]:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        command = " ".join(["exec", sys.executable, "-m", "swarm.cli", *map(shlex.quote, args)])
        p = subprocess.Popen(
            ["ip", "netns", "exec", netns, "sh", "-c", f"readlink /proc/self/ns/net; {command}"],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            env=env,
        )
        self.procs[name], self.lines[name] = p, []
        threading.Thread(target=self._read, args=(name, p), daemon=True).start()
        return p

    def _read(self, name: str, p: subprocess.Popen[bytes]) -> None:
        assert p.stdout is not None
        with open(self.logs / f"{name}.log", "w") as log:
            for raw in p.stdout:
                line = raw.decode(errors="replace")
                log.write(line)
                log.flush()
                with self._changed:
                    self.lines[name].append(line.rstrip("\n"))
                    self._changed.notify_all()
        with self._changed:  # (the end of its output: a waiter stops waiting)
            self.ended.add(name)
            self._changed.notify_all()

    def log(self, name: str) -> str:
        with self._changed:
            return "\n".join(self.lines[name])

    def wait_line(self, name: str, pattern: str, timeout_s: float) -> str:
        """The first line of ``name``'s output matching ``pattern``, waiting for it."""
        deadline = time.monotonic() + timeout_s
        seen = 0
        with self._changed:
            while True:
                lines = self.lines[name]
                for line in lines[seen:]:
                    if re.search(pattern, line):
                        return line
                seen = len(lines)
                left = deadline - time.monotonic()
                if name in self.ended or left <= 0:
                    raise AssertionError(f"{name}: no {pattern!r}: {self.log(name)[-2000:]}")
                self._changed.wait(left)

    def netns_of(self, name: str) -> int:
        """The inode of the network namespace ``name`` runs in (its first line)."""
        return int(re.fullmatch(r"net:\[(\d+)\]", self.wait_line(name, r"^net:\[", 30.0)).group(1))

    def stop(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        deadline = time.monotonic() + 10.0
        for p in self.procs.values():
            try:
                p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(5.0)


def test_a_swap_through_the_router_with_the_agents_on_two_other_hosts(lan, tmp_path):
    cfg = scenario(
        "swap_2.yaml", name="lan", network={"host": ROUTER_HOST, "port": PORT}, time={"start_timeout_s": 120.0}
    )
    assert cfg.topology == "router" and cfg.uses_bundles and cfg.network.access_control
    path = tmp_path / "lan.yaml"
    path.write_text(dump(cfg))
    out, keys = tmp_path / "run", tmp_path / "secrets"
    made = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "secrets", str(path), "--out", str(keys)], capture_output=True, text=True
    )
    assert made.returncode == 0, made.stderr
    common = [str(path), "--run", "lan", "--secrets", str(keys)]
    hosts = Hosts(tmp_path / "logs")
    try:
        hosts.start("router", lan["hub"], "router", *common)
        hosts.wait_line("router", "router: listening", 60.0)
        hosts.start("recorder", lan["hub"], "record", *common, "--out", str(out))
        world = hosts.start("world", lan["hub"], "world", *common, "--expect", "recorder")
        hosts.start("agent-cf1", lan["a"], "agent", *common, "--id", "cf1")
        hosts.start("agent-cf2", lan["b"], "agent", *common, "--id", "cf2")
        # each process runs in its host's network namespace
        for name, host in (("router", "hub"), ("world", "hub"), ("agent-cf1", "a"), ("agent-cf2", "b")):
            assert hosts.netns_of(name) == os.stat(f"/run/netns/{lan[host]}").st_ino, name
        assert world.wait(180.0) == 0, hosts.log("world")[-3000:]
        for name in ("agent-cf1", "agent-cf2"):
            hosts.procs[name].wait(30.0)
            assert hosts.procs[name].returncode == 0, hosts.log(name)[-2000:]
        hosts.procs["recorder"].wait(30.0)
    finally:
        hosts.stop()
    summary = json.loads(hosts.wait_line("world", r"^WORLD_SUMMARY ", 30.0).split(" ", 1)[1])
    assert summary["collisions"] == 0 and summary["late"] == 0, summary
    for aid in ("cf1", "cf2"):
        agent = json.loads(hosts.wait_line(f"agent-{aid}", r"^AGENT_SUMMARY ", 30.0).split(" ", 1)[1])
        assert agent["missed_neighbours"] == 0 and agent["dropped"] == 0, agent
        assert agent["rx_bytes"] > agent["ticks"] * 100, agent  # its tick and the other agent's states
    m = write_metrics(out, "completed")
    assert m["all_reached_goal"] is True and m["collisions"] == 0, m
    assert m["min_separation_m"] >= 2 * 0.07 + 0.02 - 1.5e-3


def test_the_agents_really_are_on_other_hosts(lan, tmp_path):
    """The namespaces are apart: from host a, the router's address answers, and host a's
    own loopback does not reach a port listened on in the hub's."""
    hosts = Hosts(tmp_path / "logs")
    cfg = scenario("swap_2.yaml", name="lan", network={"host": ROUTER_HOST, "port": PORT, "access_control": False})
    path = tmp_path / "lan.yaml"
    path.write_text(dump(cfg))
    try:
        hosts.start("router", lan["hub"], "router", str(path), "--run", "lan")
        hosts.wait_line("router", "router: listening", 60.0)
        probe = (
            "import socket, sys; s = socket.socket(); s.settimeout(2); "
            "print(s.connect_ex((sys.argv[1], int(sys.argv[2]))))"
        )
        for host, want in ((ROUTER_HOST, "0"), ("127.0.0.1", "111")):  # connected; refused (nothing listens there)
            got = subprocess.run(
                ["ip", "netns", "exec", lan["a"], sys.executable, "-c", probe, host, str(PORT)],
                capture_output=True,
                text=True,
                timeout=30,
            )
            assert got.stdout.strip() == want, (host, got.stdout, got.stderr)
    finally:
        hosts.stop()
