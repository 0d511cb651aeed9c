"""Starting and supervising a whole run: recorder, one process per agent, world.

Each child runs in its own session (process group) with its output in
``<run folder>/logs/<name>.log``. :class:`RunHandle` watches the world's status over
Zenoh (for the progress display) and the children's exit codes, and always leaves no
process behind (SIGTERM to each group, then SIGKILL after a grace period).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import random
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from secrets import token_hex
from typing import Any

from swarm.config import ScenarioConfig, dump
from swarm.landing import LANDED
from swarm.net import access
from swarm.net import transport as tp
from swarm.net.messages import DecodeError, decode, encode
from swarm.runs import forkserver
from swarm.runs.foxglove_layout import run_layout_json
from swarm.runs.reaper import GROUPS_FILE

EPHEMERAL_PORTS = Path("/proc/sys/net/ipv4/ip_local_port_range")
"""Linux's range of local ports for outgoing connections (``low high``)."""
PORT_BAND = 10000
"""How many ports below the ephemeral range :func:`free_port` draws from."""


def _ephemeral_low() -> int:
    """The lowest port the kernel gives an outgoing connection (32768 where unknown)."""
    try:
        return int(EPHEMERAL_PORTS.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


def _all_free(host: str, first: int, span: int) -> bool:
    """Whether ``first .. first + span - 1`` can all be bound on ``host`` now."""
    with contextlib.ExitStack() as held:
        try:
            for p in range(first, first + span):
                held.enter_context(socket.socket(socket.AF_INET, socket.SOCK_STREAM)).bind((host, p))
        except (OSError, OverflowError):  # taken, or past 65535
            return False
    return True


def free_port(host: str = "127.0.0.1", span: int = len(tp.HUBS)) -> int:
    """A port P such that P .. P + span - 1 are free now (a star's hubs listen on P, P + 1
    and P + 2; ``swarm.net.transport.process_config``), drawn at random below the kernel's
    ephemeral range: an outgoing connection takes its local port from that range, so none
    can take P between this check and the listener's bind (a port the kernel handed out by
    binding to 0, released, was once taken so by a run's own links: "Address already in
    use"). Where no band lies below the range, a kernel-chosen port."""
    low = _ephemeral_low()
    band = (max(1024, low - PORT_BAND), low - span)
    rng = random.SystemRandom()
    for _ in range(200 if band[1] > band[0] else 0):
        port = rng.randrange(*band)
        if _all_free(host, port, span):
            return port
    while True:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as first:
            first.bind((host, 0))
            port = int(first.getsockname()[1])
        if _all_free(host, port, span):
            return port


def ensure_secrets(cfg: ScenarioConfig, folder: Path) -> Path:
    """``folder`` holding the run's credentials, and its own TLS certificates when
    ``network.tls`` is on without files: written unless it already holds them."""
    if not (folder / access.USERS_FILE).exists():
        access.make_secrets(folder, [a.id for a in cfg.agents])
    tls = cfg.network.tls
    if tls.enabled and not tls.root_ca and not (folder / "ca.pem").exists():
        access.make_tls(folder, [cfg.network.host], access.run_users([a.id for a in cfg.agents]))
    return folder


class _ListGroup:
    """Run in a new child between fork and exec: append its process group (its pid, as it
    leads a session of its own) to the run's ``process_groups`` file, open as ``fd``. So a
    process is listed before it can run, even if the launcher dies the next instant; the
    reaper reads the list again after its grace time (swarm.runs.reaper). Only system calls:
    safe in a child forked from a process with threads."""

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def __call__(self) -> None:
        os.write(self.fd, b"%d\n" % os.getpid())


def _signal_group(p: subprocess.Popen[bytes] | forkserver.Child, sig: int) -> None:
    try:
        os.killpg(p.pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


CPU_ENV = "SWARM_CPU"  # the CPU a child of swarm run pins itself to (swarm.cli)


def _with_sitl_port(cfg: ScenarioConfig) -> ScenarioConfig:
    """``cfg`` with a free loopback port for the sitl poses when it names none."""
    assert cfg.mocap is not None
    if cfg.mocap.options.get("port", "0") not in ("", "0"):
        return cfg
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    mocap = cfg.mocap.model_copy(update={"options": {**cfg.mocap.options, "port": str(port)}})
    return cfg.model_copy(update={"mocap": mocap})


def cpu_plan(n_agents: int, cpus: list[int] | None = None) -> dict[str | int, int]:
    """The CPU of each process of a run: the world on the first of ``cpus`` (default: the
    CPUs this process may use), the recorder on the last, agent i round-robin from the
    second. Empty on a single CPU (nothing to choose)."""
    cpus = sorted(os.sched_getaffinity(0)) if cpus is None else cpus
    if len(cpus) < 2:
        return {}
    plan: dict[str | int, int] = {"world": cpus[0], "recorder": cpus[-1]}
    for i in range(n_agents):
        plan[i] = cpus[(i + 1) % len(cpus)]
    return plan


def unpinned(cfg: ScenarioConfig) -> ScenarioConfig:
    """``cfg`` with ``time.pin_cpus`` off: for runs that share the machine with other runs
    (``--jobs``), which would otherwise all pin their worlds to the same CPU."""
    return cfg.model_copy(update={"time": cfg.time.model_copy(update={"pin_cpus": False})})


@dataclass
class Progress:
    t_s: float = 0.0
    status: dict[str, Any] = field(default_factory=dict)


class RunHandle:
    """A started run. Use :meth:`start`, then :meth:`wait` (or :meth:`poll` in a loop)."""

    def __init__(self, cfg: ScenarioConfig, out: Path, run: str, secrets: Path | None = None) -> None:
        self.cfg, self.out, self.run = cfg, out, run
        self.secrets = secrets  # the run's credentials (swarm.net.access), None with network.access_control off
        self.procs: dict[str, subprocess.Popen[bytes] | forkserver.Child] = {}
        self.progress = Progress()
        self.reason: str | None = None
        self.result: dict[str, Any] = {}  # metrics.json as finish() wrote it
        self._session: Any = None
        self._status: Any = None  # the run's status channel (tp.open_channel), once started
        self._land_seq = 0  # land requests sent (:meth:`land`)

    @classmethod
    def start(
        cls,
        cfg: ScenarioConfig,
        out: Path,
        *,
        gui: bool = False,
        run_id: str | None = None,
        cancelled: Callable[[], bool] = lambda: False,
        secrets: Path | None = None,
        live_port: int | None = None,
        stand_ins: dict[str, tuple[str, list[str]]] | None = None,
    ) -> RunHandle:
        """Start the recorder, the world and the first agent, wait for that agent's
        liveliness (see :meth:`_wait_alive`; ``cancelled`` ends the wait early), then start
        the other agents. An exception while starting stops what was started.
        ``stand_ins``: agent id -> (a module, its extra arguments) run in that agent's place with
        the agent's own arguments and credentials (an attack's rogue member of the run:
        ``tools.rogue``).

        With ``network.access_control`` (the default) the run's credentials are in
        ``secrets`` (default ``out/secrets``; made there unless it already holds them,
        see :func:`ensure_secrets`). With ``live_port`` the recorder serves the run to
        Foxglove live (``swarm.runs.record``)."""
        port = cfg.network.port or free_port(cfg.network.host)
        cfg = cfg.model_copy(update={"network": cfg.network.model_copy(update={"port": port})})
        sitl = cfg.mocap is not None and cfg.mocap.type == "sitl"
        if sitl:
            cfg = _with_sitl_port(cfg)
        out.mkdir(parents=True, exist_ok=True)
        if cfg.network.access_control:
            secrets = ensure_secrets(cfg, secrets or out / "secrets")
        h = cls(cfg, out, run_id or f"{cfg.name}-{token_hex(3)}", secrets if cfg.network.access_control else None)
        (out / "logs").mkdir(exist_ok=True)
        cfg_path = out / "config.yaml"
        cfg_path.write_text(dump(cfg))
        (out / "foxglove_layout.json").write_text(run_layout_json([a.id for a in cfg.agents]))
        common = [str(cfg_path), "--run", h.run, *(["--secrets", str(h.secrets)] if h.secrets else [])]
        cpus = cpu_plan(len(cfg.agents)) if cfg.time.pin_cpus else {}
        launcher_conf = tp.process_config(cfg, tp.Role.LAUNCHER, h.access(tp.Role.LAUNCHER))
        if cfg.topology == "router" or cfg.uses_bundles:  # everyone links to the router (relay): it comes first
            h._spawn("router", ["-m", "swarm.cli", "router", *common])
            h._session = h._open_via_router(launcher_conf)
        else:
            h._session = tp.open_session(launcher_conf)
        h._status = tp.open_channel(h._session, tp.Keys(h.run).status, 4096)
        if sitl:
            try:
                h._start_sitl()
            except BaseException:  # no drone answered: stop what was started (the router, the drones)
                h._stop_all()
                raise
        expect = ["--expect", "recorder"]
        if "router" in h.procs:  # its liveliness comes once the relay listens to the agents' states
            expect += ["--expect", "router"]
        if cfg.ros2.enabled:  # the ROS 2 bridge (swarm.ros2.bridge), and what a ROS 2 participant needs to join
            from swarm.ros2.participant import write_env

            write_env(cfg, h.secrets or out / "secrets", h.secrets)
            h._spawn("ros2", ["-m", "swarm.cli", "ros2-bridge", *common], cpus.get("recorder"))
            expect += ["--expect", "ros2"]
        live = ["--live", str(live_port)] if live_port is not None else []
        h._spawn("recorder", ["-m", "swarm.cli", "record", *common, "--out", str(out), *live], cpus.get("recorder"))
        h._spawn(
            "world",
            ["-m", "swarm.cli", "world", *common, *expect, *(["--gui"] if gui else [])],
            cpus.get("world"),
        )
        server = forkserver.shared()
        if server is not None:  # the agents' kernels, loaded once in the server before it forks them
            server.warm(cfg_path)
        try:
            for i, a in enumerate(cfg.agents):
                if cancelled():  # stopped while the first agent came up: start no more
                    break
                module, extra = ("swarm.cli", ["agent"]), []
                if stand_ins and a.id in stand_ins:
                    module, extra = (stand_ins[a.id][0], []), stand_ins[a.id][1]
                args = ["-m", module[0], *module[1], *common, "--id", a.id, *extra]
                h._spawn(f"agent-{a.id}", args, cpus.get(i))
                if i == 0:
                    h._wait_alive(a.id, cancelled)
        except BaseException:
            h._stop_all()
            raise
        return h

    def _open_via_router(self, conf: Any) -> Any:
        """The launcher's session, which opens once the router accepts it (Zenoh retries
        the link for ``swarm.net.transport.ROUTER_WAIT_S``); else the router's cause. (A star's
        bundle relay is ``swarm router`` too.)"""
        try:
            return tp.open_session(conf)
        except Exception as exc:  # zenoh.ZError: unable to connect
            code = self.procs["router"].poll()
            self._stop_all()
            why = self._cause("router", code) if code is not None else f"not reached: {exc}"
            raise RuntimeError(f"the run's router did not start: {why}") from None

    def access(self, role: tp.Role, agent_id: str | None = None) -> tp.Access | None:
        """The credentials of a process of this run (None: access control is off)."""
        return None if self.secrets is None else tp.Access.of(self.cfg, self.run, role, self.secrets, agent_id)

    def _start_sitl(self) -> None:
        """Start the software-in-the-loop Crazyflies of the real agents and wait until each
        answers a CRTP null packet at its URI (as cflib's UDP scan probes)."""
        cfg = self.cfg
        assert cfg.mocap is not None
        opts = cfg.mocap.options
        if opts.get("firmware") == "crazysim":  # the firmware itself, one cf2 per drone (swarm.world.sitl_fw)
            cf2 = ["--cf2", opts["cf2"]] if opts.get("cf2") else []
            args = ["-m", "swarm.world.sitl_fw", "--mocap-port", opts["port"], *cf2, "--until-handed-back"]
            args += ["--telemetry", str(self.out / "firmware")]
        else:  # the stand-in (swarm.world.sitl_cf)
            args = ["-m", "swarm.world.sitl_cf", "--mocap-port", opts["port"]]
            args += ["--firmware", opts.get("firmware", "2026.04")]
        ports: list[int] = []
        for a in cfg.agents:
            if a.crazyflie is None:
                continue
            host_port = a.crazyflie.uri.removeprefix("udp://")
            host, _, p = host_port.partition(":")
            if not a.crazyflie.uri.startswith("udp://") or host not in ("127.0.0.1", "localhost") or not p.isdigit():
                raise ValueError(
                    f"agent {a.id}: mocap sitl needs crazyflie.uri udp://127.0.0.1:PORT, got {a.crazyflie.uri}"
                )
            yaw = math.degrees(a.yaw_rad) + float(opts.get("yaw_offset_deg", "0"))
            args += ["--drone", f"{a.mocap_body},{p},{a.start[0]},{a.start[1]},0.0,{yaw}"]
            ports.append(int(p))
        self._spawn("sitl", args)
        deadline = time.monotonic() + 30.0
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        probe.settimeout(0.1)
        try:
            for port_n in ports:
                while True:
                    if self.procs["sitl"].poll() is not None:
                        raise RuntimeError(f"the sitl stand-ins exited: {self._last_line('sitl')}")
                    if time.monotonic() > deadline:
                        raise RuntimeError(f"the sitl stand-in at udp://127.0.0.1:{port_n} did not answer")
                    probe.sendto(b"\xff", ("127.0.0.1", port_n))
                    try:
                        probe.recv(64)
                        break
                    except TimeoutError:
                        continue
        finally:
            probe.close()

    def _wait_alive(self, agent_id: str, cancelled: Callable[[], bool]) -> None:
        """Wait until ``agent_id`` declares its liveliness (its warm-up tick is done), or
        its process exits, or the start timeout passes.

        The first agent compiles numba's kernels into the on-disk cache when it is cold
        (after an install or a code change: about 9 s of CPU); the others then load them
        in well under a second. Started together, N agents would each compile, N times
        the CPU on two cores, and 16 of them miss the world's start timeout."""
        sub = tp.liveliness_subscriber(self._session, tp.Keys(self.run).alive(agent_id))
        try:
            deadline = time.monotonic() + self.cfg.time.start_timeout_s
            proc = self.procs[f"agent-{agent_id}"]
            while time.monotonic() < deadline and proc.poll() is None and not cancelled():
                s = tp.wait_sample(sub, min(deadline, time.monotonic() + 0.1))
                if s is not None and tp.liveliness_change(s)[1]:
                    return
        finally:
            sub.undeclare()

    def _spawn(self, name: str, args: list[str], cpu: int | None = None) -> None:
        """``python *args`` as the run's process ``name``: forked from this launcher's fork
        server (swarm.runs.forkserver), or, where there is none, started from scratch."""
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        env.pop(CPU_ENV, None)
        if cpu is not None:
            env[CPU_ENV] = str(cpu)  # the child pins itself and its threads first thing (swarm.cli)
        server = forkserver.shared()
        if server is not None:
            self.procs[name] = server.spawn(args, self.out / "logs" / f"{name}.log", env, self.out / GROUPS_FILE)
            return
        log = open(self.out / "logs" / f"{name}.log", "wb")  # owned by the child
        groups = os.open(self.out / GROUPS_FILE, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:  # each child leads its group and lists it itself, before it runs (swarm.runs.reaper)
            self.procs[name] = subprocess.Popen(
                [sys.executable, *args],
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                env=env,
                preexec_fn=_ListGroup(groups),
            )
        finally:
            os.close(groups)

    @property
    def session(self) -> Any:
        """This process's own Zenoh session in the run (tests use it to listen or inject)."""
        return self._session

    def exited(self) -> dict[str, int]:
        return {n: code for n, p in self.procs.items() if (code := p.poll()) is not None}

    @property
    def wall_limit_s(self) -> float:
        """Generous wall-clock limit of the whole run (start-up plus 20x real time)."""
        return self.cfg.time.start_timeout_s + 20.0 * self.cfg.duration_s + 60.0

    def poll(self, stop_on_agent_death: bool = False, wait_s: float = 0.0) -> str | None:
        """Read progress and exit codes once, first waiting up to ``wait_s`` for a world
        status message; returns why the run is over, or None."""
        first = tp.wait_sample(self._status, time.monotonic() + wait_s) if wait_s > 0 else None
        for s in ([first] if first is not None else []) + list(tp.drain(self._status)):
            try:
                m = decode(tp.payload(s), self.run, ("status",))
            except DecodeError:
                continue
            self.progress.t_s, self.progress.status = m.t, m.body
        ex = self.exited()
        if ex.get("router", 0) != 0:  # (it exits 0 only when stopped)
            routed = self.cfg.topology == "router"
            what = "every link of the run went through it" if routed else "it bundled the neighbours"
            return self._cause("router", ex["router"]) + f" ({what})"
        if ex.get("ros2", 0) != 0:
            return self._cause("ros2", ex["ros2"]) + " (the ROS 2 bridge)"
        if "world" in ex:
            return "completed" if ex["world"] == 0 else self._cause("world", ex["world"])
        if "recorder" in ex:
            if ex["recorder"] == 0 and self.progress.status.get("done"):
                # the world said done and the recorder finished its tail: the world is exiting
                try:
                    code = self.procs["world"].wait(30)
                except subprocess.TimeoutExpired:
                    return "the world did not exit after it reported done"
                return "completed" if code == 0 else self._cause("world", code)
            return self._cause("recorder", ex["recorder"]) + " (the run was stopped there)"
        dead = [n for n in ex if n.startswith("agent-")]
        if dead and not self.progress.status:  # before the world's first status: it could not start
            return f"{dead[0]} exited with {ex[dead[0]]} while starting: {self._last_line(dead[0])}"
        if dead and stop_on_agent_death:
            return f"{dead[0]} died"
        return None

    def _cause(self, name: str, code: int) -> str:
        """One line: which process ended the run, how, at what sim time, and its last word."""
        try:
            how = f"killed by {signal.Signals(-code).name}" if code < 0 else f"exited with {code}"
        except ValueError:  # not a signal Python knows
            how = f"killed by signal {-code}"
        at = f" at t = {self.progress.t_s:.2f} s" if self.progress.status else " before the first tick"
        said = self._own_line(name)
        return f"{name} {how}{at}" + (f": {said}" if said else "")

    def _log_lines(self, name: str) -> list[str]:
        try:
            return (self.out / "logs" / f"{name}.log").read_text(errors="replace").strip().splitlines()
        except OSError:
            return []

    def _own_line(self, name: str) -> str | None:
        """The last line a process wrote about itself ("agent cf1: ..."), or None."""
        own = [ln for ln in self._log_lines(name) if ln.startswith(name.replace("-", " ", 1) + ":")]
        return own[-1] if own else None

    def _last_line(self, name: str) -> str:
        """Why a process stopped, as it said it: its own last line, else its log's last line."""
        return self._own_line(name) or (self._log_lines(name) or ["(empty log)"])[-1]

    def wait_sim_time(self, t_s: float, timeout_s: float = 120.0) -> None:
        """Block until a world status message reports sim time ``t_s`` [s] or later;
        raises if the run ends first or ``timeout_s`` passes."""
        deadline = time.monotonic() + timeout_s
        while not self.progress.status or self.progress.t_s < t_s:
            reason = self.poll(wait_s=max(0.0, min(0.5, deadline - time.monotonic())))
            if reason is not None or time.monotonic() > deadline:
                raise RuntimeError(f"run {self.run} did not reach t = {t_s} s ({reason or 'timeout'})")

    def wait(self, timeout_s: float | None = None, stop_on_agent_death: bool = False) -> str:
        """Block until the run is over (or ``timeout_s``), then :meth:`finish`."""
        deadline = time.monotonic() + (timeout_s or self.wall_limit_s)
        reason = None
        while reason is None:
            # returns on each world status message; exit codes are looked at every 50 ms
            reason = self.poll(stop_on_agent_death, wait_s=0.05)
            if reason is None and time.monotonic() > deadline:
                reason = "wall-clock limit"
        return self.finish(reason)

    def _wait_procs(self, names: list[str], timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if all(self.procs[n].poll() is not None for n in names if n in self.procs):
                return True
            time.sleep(0.05)
        return False

    def land(self, why: str) -> None:
        """Ask the world and every agent to land every drone and end the run once they are
        down (``swarm.landing``); the run then ends as :data:`swarm.landing.LANDED`. Asking
        again repeats the request (each process takes the first)."""
        self._land_seq += 1
        self._session.put(tp.Keys(self.run).land, encode("land", self.run, "launcher", self._land_seq, 0.0, 0, why=why))

    def finish(self, reason: str) -> str:
        """Let a completed (or landed) run's processes end by themselves, stop the rest, and
        write ``metrics.json`` from the recording."""
        if reason in ("completed", LANDED):
            self._wait_procs(["recorder"], 15.0)
            self._wait_procs([n for n in self.procs if n.startswith("agent-")], 5.0)
            if "sitl" in self.procs:  # the stand-ins end once their guards have handed each drone back
                self._wait_procs(["sitl"], 10.0)
        self._stop_all()
        self.reason = reason
        self.result = self.metrics()
        if self.cfg.ros2.bag:
            self.ros2_bag()
        return reason

    def ros2_bag(self) -> None:
        """The run as a ROS 2 bag in ``ros2_bag/`` (``ros2.bag``; swarm.runs.bag)."""
        from swarm.runs.bag import write_bag

        try:
            write_bag(self.out)
        except Exception as exc:  # a recording it cannot read: the run's results stand, say why
            print(f"ros2 bag not written: {type(exc).__name__}: {exc}", file=sys.stderr)

    def _stop_all(self) -> None:
        """SIGTERM to every child's group, SIGKILL after a grace period, and then to each
        group anyway (nothing left behind)."""
        for p in self.procs.values():
            if p.poll() is None:
                _signal_group(p, signal.SIGTERM)
        if not self._wait_procs(list(self.procs), 5.0):
            stuck = [n for n, p in self.procs.items() if p.poll() is None]
            for n in stuck:  # its threads' stacks into its log first (swarm.cli._pin_cpu), then killed
                with contextlib.suppress(ProcessLookupError):
                    os.kill(self.procs[n].pid, signal.SIGUSR1)
            time.sleep(0.2)
            print(f"{', '.join(stuck)} did not end on SIGTERM in 5 s: killed (stacks in the logs)", file=sys.stderr)
            for p in self.procs.values():
                if p.poll() is None:
                    _signal_group(p, signal.SIGKILL)
            self._wait_procs(list(self.procs), 2.0)
        for p in self.procs.values():  # reap anything left in the groups
            _signal_group(p, signal.SIGKILL)

    def metrics(self) -> dict[str, Any]:
        """Write ``metrics.json`` from what the recording holds, whatever stopped the run
        (``complete`` says whether it is the whole run)."""
        from swarm.runs.runfiles import write_metrics

        codes = {n: p.returncode for n, p in self.procs.items()}
        try:
            return write_metrics(self.out, self.reason, exit_codes=codes)
        except Exception as exc:  # the config or the recorder's file unreadable: still say why the run stopped
            m = {
                "complete": False,
                "stop_reason": self.reason,
                "exit_codes": codes,
                "error": f"could not compute metrics: {type(exc).__name__}: {exc}",
            }
            print(m["error"], file=sys.stderr)
            (self.out / "metrics.json").write_text(json.dumps(m, indent=2))
            return m

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        """Send ``sig`` to one child's process group (fault injection)."""
        _signal_group(self.procs[name], sig)

    def stop(self) -> None:
        """Stop everything now (Ctrl-C)."""
        self.finish("interrupted")
