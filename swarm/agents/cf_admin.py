"""Lab chores on Crazyflies through cflib, for ``swarm cf``: find them, read their
supervisor's state, recover one from a crash, reboot one.

    swarm cf scan                 # cflib.crtp.scan_interfaces: radios, USB, UDP (SITL) on 19850-19859
    swarm cf status URI           # the supervisor's state bits (cflib's Supervisor.decode_bitfield)
    swarm cf recover URI          # CMD_RECOVER_SYSTEM: a crashed (tumbled) drone, upright again, may fly
    swarm cf reboot URI           # cflib's PowerSwitch: the radio's power cycle (radio URIs only)
    swarm cf check URI            # PROPELLERS OFF: a known setpoint sequence, read back as the firmware decoded it

A locked drone (after an emergency stop or a watchdog timeout: supervisor.c "Locked,
reboot required") needs ``reboot``; a crashed one ``recover``. The supervisor requests
need CRTP protocol 12 or later (firmware 2023.02 on); they go over the link without
cflib's full connection (no parameter or log table download), as the link guard's do.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any


class _Link:
    """The part of cflib's ``Crazyflie`` that ``Supervisor``, ``Log`` and ``Commander`` use,
    over one link driver: ``send_packet``, ``add_port_callback`` and
    ``remove_port_callback`` (a thread hands each received packet to the port's
    callbacks), ``platform.get_protocol_version``, ``link`` and ``log``."""

    class _Platform:
        @staticmethod
        def get_protocol_version() -> int:
            return 12  # see the module docstring: the supervisor port's protocol

    def __init__(self, uri: str) -> None:
        import cflib.crtp

        cflib.crtp.init_drivers()
        self.errors: list[str] = []
        self.driver = cflib.crtp.get_link_driver(uri, link_error_callback=lambda m: self.errors.append(str(m)))
        if self.driver is None:
            raise ValueError(f"no cflib driver for {uri}")
        self.platform = self._Platform()
        self.link = self.driver  # what cflib's LogConfig looks at
        self.log: Any = None
        self._callbacks: dict[int, list[Callable[[Any], None]]] = {}
        self._done = threading.Event()
        threading.Thread(target=self._receive, daemon=True).start()

    def send_packet(self, pk: Any, expected_reply: tuple = (), resend: bool = False, timeout: float = 0.2) -> None:
        self.driver.send_packet(pk)  # (no resending: the caller reads back what arrived)

    def add_port_callback(self, port: int, cb: Callable[[Any], None]) -> None:
        self._callbacks.setdefault(port, []).append(cb)

    def remove_port_callback(self, port: int, cb: Callable[[Any], None]) -> None:
        if cb in self._callbacks.get(port, []):
            self._callbacks[port].remove(cb)

    def _receive(self) -> None:
        while not self._done.is_set():
            pk = self.driver.receive_packet(0.05)
            if pk is not None:
                for cb in list(self._callbacks.get(pk.port, [])):
                    cb(pk)

    def close(self) -> None:
        self._done.set()
        self.driver.close()


def scan() -> list[str]:
    """URIs of the Crazyflies cflib finds (radios, USB, and UDP on 19850-19859)."""
    import cflib.crtp

    cflib.crtp.init_drivers()
    return [str(found[0]) for found in cflib.crtp.scan_interfaces()]


def status(uri: str, timeout_s: float = 3.0) -> list[str]:
    """The supervisor's active states (cflib's names), read from the drone."""
    from cflib.crazyflie.supervisor import Supervisor

    link = _Link(uri)
    try:
        sup = Supervisor(link)
        bits = sup._fetch_bitfield(timeout_s)  # cflib's read, with our timeout
        if not sup._bitfield_received.is_set():
            raise TimeoutError(f"{uri}: no supervisor answer within {timeout_s} s")
        return sup.decode_bitfield(bits)
    finally:
        link.close()


def recover(uri: str, timeout_s: float = 3.0) -> list[str]:
    """Ask a crashed drone to recover (``CMD_RECOVER_SYSTEM``); returns its states after.

    The stop setpoint goes first. The firmware keeps the last setpoint whatever its age
    (commander.c ``commanderGetSetpoint``) and passes it through once ready to fly again
    (supervisor.c ``supervisorOverrideSetpoint``: ready to fly does nothing): without the
    stop, a crash's last flight setpoint would spin the motors up after the recovery, and
    the commander watchdog would then lock the drone (supervisor_state_machine.c:
    flying, commander watchdog timeout -> exception free fall -> locked)."""
    from cflib.crazyflie.commander import Commander
    from cflib.crazyflie.supervisor import Supervisor

    link = _Link(uri)
    try:
        Commander(link).send_stop_setpoint()
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


def check(uri: str, thrust: Any, hold_s: float = 0.3) -> list[dict[str, Any]]:
    """PROPELLERS OFF. Send :data:`CHECK_STEPS` as an agent would (``swarm.agents.crazyflie.rpyt``
    with the calibration ``thrust``) and read back what the firmware decoded: its log
    group ``ctrltarget`` (stabilizer.c: roll, pitch [deg], yaw rate [deg/s], thrust)
    through cflib's log subsystem. Each row says what was asked, what the firmware
    holds, what its rules (``swarm.crazyflie_fw``) say it must hold, and whether they
    agree: roll as sent, pitch negated (cflib's), yaw rate counter-clockwise as asked
    (the firmware inverts the wire's), thrust the command (0 would be a locked thrust)."""
    import math
    import time

    from cflib.crazyflie.commander import Commander
    from cflib.crazyflie.log import Log, LogConfig
    from cflib.crazyflie.toccache import TocCache

    from swarm.agents.crazyflie import rpyt

    link = _Link(uri)
    try:
        link.log = Log(link)
        toc = threading.Event()
        link.log.refresh_toc(toc.set, TocCache())
        if not toc.wait(3.0):
            raise TimeoutError(f"{uri}: no log table of contents within 3 s")
        conf = LogConfig("c3swarm_check", 20)
        for name in ("roll", "pitch", "yaw", "thrust"):
            conf.add_variable(f"ctrltarget.{name}", "float")
        latest: dict[str, float] = {}
        conf.data_received_cb.add_callback(lambda _ts, data, _conf: latest.update(data))
        link.log.add_config(conf)
        conf.start()
        cmd = Commander(link)
        for _ in range(3):
            cmd.send_setpoint(0.0, 0.0, 0.0, 0)  # unlock the thrust (crtp_commander_rpyt.c)
            time.sleep(0.02)
        rows = []
        for what, roll, pitch, yaw, thrust_N in CHECK_STEPS:
            sp = rpyt(math.radians(roll), math.radians(pitch), math.radians(yaw), thrust_N, thrust)
            end = time.monotonic() + hold_s
            while time.monotonic() < end:
                cmd.send_setpoint(*sp)
                time.sleep(0.02)
            got = {k.split(".")[1]: v for k, v in latest.items()}
            want = {"roll": roll, "pitch": -pitch, "yaw": yaw, "thrust": float(sp[3])}
            ok = bool(got) and all(abs(got.get(k, math.nan) - v) <= 1e-3 * max(1.0, abs(v)) for k, v in want.items())
            rows.append({"step": what, "sent": sp, "firmware": got, "expected": want, "ok": ok})
        for _ in range(5):
            cmd.send_setpoint(0.0, 0.0, 0.0, 0)
            time.sleep(0.02)
        cmd.send_notify_setpoint_stop()
        return rows
    finally:
        link.close()
