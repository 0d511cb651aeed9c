"""Lab chores on Crazyflies through cflib, for ``swarm cf``: find them, read their
supervisor's state, recover one from a crash, reboot one, check the setpoint's signs.

    swarm cf scan                 # cflib.crtp.scan_interfaces: radios, USB, UDP (SITL) on 19850-19859
    swarm cf status URI           # the supervisor's state bits (cflib's Supervisor.decode_bitfield)
    swarm cf recover URI          # CMD_RECOVER_SYSTEM: a crashed (tumbled) drone, upright again, may fly
    swarm cf reboot URI           # cflib's PowerSwitch: the radio's power cycle (radio URIs only)
    swarm cf check URI            # PROPELLERS OFF: a known setpoint sequence, read back as the firmware decoded it

A locked drone (after an emergency stop or a watchdog timeout: supervisor.c "Locked,
reboot required") needs ``reboot``; a crashed one ``recover``. The requests go over the
link without cflib's full connection (no parameter table, no memories), as the link
guard's do; the firmware's CRTP protocol version is asked first (cflib's
``PlatformService``), and what is asked follows it as cflib's ``Supervisor`` does: from
protocol 12 (firmware 2025.09) the supervisor's port (crtp_supervisor.c); before it the
supervisor's bits are read from the log table (``supervisor.info``, supervisor.c), and a
crash recovery goes on the platform port. Log tables are cached by their CRC under
``$XDG_CACHE_HOME/c3swarm/cflib-toc`` (cflib's ``TocCache``).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from swarm.agents.cf_guard import LANDED_AFTER_S

SUPERVISOR_PORT_PROTOCOL = 12  # cflib supervisor.py _is_legacy_firmware: the supervisor port from protocol 12


def toc_cache_dir() -> Path:
    """Where log tables of contents are kept between calls (by CRC; cflib's ``TocCache``)."""
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "c3swarm" / "cflib-toc"


class _Link:
    """The part of cflib's ``Crazyflie`` that ``Supervisor``, ``Log``, ``Commander`` and
    ``PlatformService`` use, over one link driver: ``send_packet`` (asked again after
    ``timeout`` while its ``expected_reply`` has not come, as cflib's ``Crazyflie.send_packet``
    does), ``add_port_callback`` and ``remove_port_callback`` (a thread hands each received
    packet to the port's callbacks), ``platform`` (the protocol version, asked once by
    :meth:`protocol_version`), ``link`` and ``log``."""

    RESENDS = 5  # a request asked this many times more before it is given up

    def __init__(self, uri: str) -> None:
        import cflib.crtp
        from cflib.crazyflie.platformservice import PlatformService

        cflib.crtp.init_drivers()
        self.uri = uri
        self.errors: list[str] = []
        self.driver = cflib.crtp.get_link_driver(uri, link_error_callback=lambda m: self.errors.append(str(m)))
        if self.driver is None:
            raise ValueError(f"no cflib driver for {uri}")
        self.link = self.driver  # what cflib's LogConfig looks at
        self.log: Any = None
        self._callbacks: dict[int, list[Callable[[Any], None]]] = {}
        self._waiting: dict[tuple[int, ...], threading.Timer] = {}  # answer pattern -> its resend timer
        self._lock = threading.Lock()
        self._done = threading.Event()
        threading.Thread(target=self._receive, daemon=True).start()
        self.platform = PlatformService(self)

    def protocol_version(self, timeout_s: float) -> int:
        """The firmware's CRTP protocol version (cflib's ``PlatformService``); raises on no answer."""
        got = threading.Event()
        for _ in range(3):
            self.platform.fetch_platform_informations(got.set)
            if got.wait(timeout_s / 3):
                return int(self.platform.get_protocol_version())
        raise TimeoutError(f"{self.uri}: no answer to the protocol version request within {timeout_s} s")

    def send_packet(self, pk: Any, expected_reply: tuple = (), resend: bool = False, timeout: float = 0.2) -> None:
        if expected_reply:
            pattern = (pk.header, *expected_reply)
            with self._lock:
                old = self._waiting.pop(pattern, None)
                if old is not None:
                    old.cancel()
                timer = threading.Timer(timeout, self._resend, (pk, pattern, timeout, self.RESENDS))
                timer.daemon = True
                self._waiting[pattern] = timer
            timer.start()
        self.driver.send_packet(pk)

    def _resend(self, pk: Any, pattern: tuple[int, ...], timeout: float, left: int) -> None:
        with self._lock:
            if pattern not in self._waiting or left <= 0 or self._done.is_set():
                self._waiting.pop(pattern, None)
                return
            timer = threading.Timer(timeout, self._resend, (pk, pattern, timeout, left - 1))
            timer.daemon = True
            self._waiting[pattern] = timer
        timer.start()
        self.driver.send_packet(pk)

    def add_port_callback(self, port: int, cb: Callable[[Any], None]) -> None:
        self._callbacks.setdefault(port, []).append(cb)

    def remove_port_callback(self, port: int, cb: Callable[[Any], None]) -> None:
        if cb in self._callbacks.get(port, []):
            self._callbacks[port].remove(cb)

    def _receive(self) -> None:
        while not self._done.is_set():
            pk = self.driver.receive_packet(0.05)
            if pk is None:
                continue
            data = (pk.header, *pk.data)
            with self._lock:  # the longest pattern this packet answers (cflib's _check_for_answers)
                hits = [p for p in self._waiting if data[: len(p)] == p]
                if hits:
                    self._waiting.pop(max(hits, key=len)).cancel()
            for cb in list(self._callbacks.get(pk.port, [])):
                cb(pk)

    def read_log_toc(self, timeout_s: float) -> None:
        """The firmware's log table of contents into :attr:`log` (cflib's ``Log``, cached by CRC)."""
        from cflib.crazyflie.log import Log
        from cflib.crazyflie.toccache import TocCache

        self.log = Log(self)
        cache = toc_cache_dir()
        cache.mkdir(parents=True, exist_ok=True)
        done = threading.Event()
        self.log.refresh_toc(done.set, TocCache(rw_cache=str(cache)))
        if not done.wait(timeout_s):
            raise TimeoutError(f"{self.uri}: no log table of contents within {timeout_s:.0f} s")

    def log_once(self, names: list[str], timeout_s: float) -> dict[str, float]:
        """One sample of the log variables ``names`` (after :meth:`read_log_toc`)."""
        from cflib.crazyflie.log import LogConfig

        conf = LogConfig("c3swarm_once", 10)
        for n in names:
            element = self.log.toc.get_element_by_complete_name(n)
            if element is None:
                raise ValueError(f"{self.uri}: the firmware logs no {n}")
            conf.add_variable(n, element.ctype)
        got: dict[str, float] = {}
        done = threading.Event()

        def first(_ts: int, data: dict[str, float], _conf: Any) -> None:
            got.update(data)
            done.set()

        conf.data_received_cb.add_callback(first)
        self.log.add_config(conf)
        conf.start()
        try:
            if not done.wait(timeout_s):
                raise TimeoutError(f"{self.uri}: no log data of {names} within {timeout_s:.0f} s")
        finally:
            conf.delete()
        return got

    def close(self) -> None:
        self._done.set()
        with self._lock:
            for t in self._waiting.values():
                t.cancel()
            self._waiting.clear()
        self.driver.close()


def scan() -> list[str]:
    """URIs of the Crazyflies cflib finds (radios, USB, and UDP on 19850-19859)."""
    import cflib.crtp

    cflib.crtp.init_drivers()
    return [str(found[0]) for found in cflib.crtp.scan_interfaces()]


def status(uri: str, timeout_s: float = 3.0) -> list[str]:
    """The supervisor's active states (cflib's names), read from the drone: on its
    supervisor port from protocol 12, else its ``supervisor.info`` log variable."""
    from cflib.crazyflie.supervisor import Supervisor

    link = _Link(uri)
    try:
        sup = Supervisor(link)
        if link.protocol_version(timeout_s) >= SUPERVISOR_PORT_PROTOCOL:
            bits = sup._fetch_bitfield(timeout_s)  # cflib's read, with our timeout
            if not sup._bitfield_received.is_set():
                raise TimeoutError(f"{uri}: no supervisor answer within {timeout_s} s")
        else:
            link.read_log_toc(max(timeout_s, 10.0))
            bits = int(link.log_once(["supervisor.info"], timeout_s)["supervisor.info"])
        return sup.decode_bitfield(bits)
    finally:
        link.close()


def recover(uri: str, timeout_s: float = 3.0) -> list[str]:
    """Ask a crashed drone to recover (``CMD_RECOVER_SYSTEM``; on the platform port before
    protocol 12, as cflib's ``Supervisor`` does); returns its states after.

    The stop setpoint goes first. The firmware keeps the last setpoint whatever its age
    (commander.c ``commanderGetSetpoint``) and passes it through once ready to fly again
    (supervisor.c ``supervisorOverrideSetpoint``: ready to fly does nothing): without the
    stop, a crash's last flight setpoint would spin the motors up after the recovery, and
    the commander watchdog would then lock the drone (supervisor_state_machine.c:
    flying, commander watchdog timeout -> exception free fall -> locked)."""
    import warnings

    from cflib.crazyflie.commander import Commander
    from cflib.crazyflie.supervisor import Supervisor

    link = _Link(uri)
    try:
        link.protocol_version(timeout_s)
        Commander(link).send_stop_setpoint()
        with warnings.catch_warnings():  # cflib warns that an older firmware takes the platform port
            warnings.simplefilter("ignore")
            Supervisor(link).send_crash_recovery_request()
    finally:
        link.close()
    return status(uri, timeout_s)


def reboot(uri: str) -> None:
    """Power-cycle the drone's STM32 through the radio (cflib's ``PowerSwitch``)."""
    if not uri.startswith("radio://"):
        raise ValueError(f"{uri}: reboot goes through a Crazyradio (radio://...); power-cycle this one by hand")
    from cflib.utils.power_switch import PowerSwitch

    ps = PowerSwitch(uri)
    try:
        ps.stm_power_cycle()
    finally:
        ps.close()


CHECK_STEPS = [
    # (what we ask, roll [deg], pitch [deg], yaw rate [deg/s, counter-clockwise], thrust [N])
    ("roll 10 deg: move right", 10.0, 0.0, 0.0, 0.10),
    ("pitch 10 deg: move forward", 0.0, 10.0, 0.0, 0.10),
    ("yaw rate +30 deg/s: turn counter-clockwise", 0.0, 0.0, 30.0, 0.10),
    ("thrust 0.15 N", 0.0, 0.0, 0.0, 0.15),
]
CHECK_LOG = {
    # what the firmware decoded, by name of ours: the setpoint it flies (stabilizer.c log group ctrltarget,
    # which has no thrust) and the controller's thrust command (stabilizer.c log group stabilizer: control.thrust)
    "roll": "ctrltarget.roll",
    "pitch": "ctrltarget.pitch",
    "yaw": "ctrltarget.yaw",
    "thrust": "stabilizer.thrust",
}


def check(uri: str, thrust: Any, hold_s: float = 0.3) -> list[dict[str, Any]]:
    """PROPELLERS OFF. Send :data:`CHECK_STEPS` as an agent would (``swarm.agents.crazyflie.rpyt``
    with the calibration ``thrust``) and read back what the firmware decoded: :data:`CHECK_LOG`
    through cflib's log subsystem. Each row says what was asked, what the firmware holds,
    what its rules (``swarm.crazyflie_fw``) say it must hold, and whether they agree: roll
    as sent, pitch negated (cflib's), yaw rate counter-clockwise as asked (the firmware
    inverts the wire's), thrust the command (0 would be a locked thrust). A variable the
    firmware does not log is reported missing in every row (and fails it).

    The motors spun, so the supervisor counts the drone as flying for 2 s after they stop;
    without setpoints it would level out after 500 ms and lock it at 2 s (supervisor.c,
    supervisor_state_machine.c: level out never lands). So zero-thrust setpoints go on for
    :data:`LANDED_AFTER_S` before the drone is handed back, as the link guard does."""
    import math
    import time

    from cflib.crazyflie.commander import Commander
    from cflib.crazyflie.log import LogConfig

    from swarm.agents.crazyflie import rpyt

    link = _Link(uri)
    try:
        link.protocol_version(3.0)
        link.read_log_toc(10.0)
        have = {k: v for k, v in CHECK_LOG.items() if link.log.toc.get_element_by_complete_name(v) is not None}
        missing = [v for k, v in CHECK_LOG.items() if k not in have]
        conf = LogConfig("c3swarm_check", 20)
        for name in have.values():
            conf.add_variable(name, "float")
        latest: dict[str, float] = {}
        conf.data_received_cb.add_callback(lambda _ts, data, _conf: latest.update(data))
        link.log.add_config(conf)
        conf.start()
        cmd = Commander(link)
        for _ in range(3):
            cmd.send_setpoint(0.0, 0.0, 0.0, 0)  # unlock the thrust (crtp_commander_rpyt.c)
            time.sleep(0.02)
        rows = []
        by_var = {v: k for k, v in have.items()}
        for what, roll, pitch, yaw, thrust_N in CHECK_STEPS:
            sp = rpyt(math.radians(roll), math.radians(pitch), math.radians(yaw), thrust_N, thrust)
            end = time.monotonic() + hold_s
            while time.monotonic() < end:
                cmd.send_setpoint(*sp)
                time.sleep(0.02)
            got = {by_var[k]: v for k, v in latest.items() if k in by_var}
            want = {"roll": roll, "pitch": -pitch, "yaw": yaw, "thrust": float(sp[3])}
            ok = not missing and all(abs(got.get(k, math.nan) - v) <= 1e-3 * max(1.0, abs(v)) for k, v in want.items())
            rows.append({"step": what, "sent": sp, "firmware": got, "expected": want, "ok": ok, "missing": missing})
        end = time.monotonic() + LANDED_AFTER_S  # the supervisor counts it landed, not locked
        while time.monotonic() < end:
            cmd.send_setpoint(0.0, 0.0, 0.0, 0)
            time.sleep(0.02)
        cmd.send_notify_setpoint_stop()
        conf.delete()
        return rows
    finally:
        link.close()
