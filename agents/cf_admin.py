"""Lab chores on Crazyflies through cflib, for ``swarm cf``: find them, read their
supervisor's state, recover one from a crash, reboot one.

    swarm cf scan                 # cflib.crtp.scan_interfaces: radios, USB, UDP (SITL) on 19850-19859
    swarm cf status URI           # the supervisor's state bits (cflib's Supervisor.decode_bitfield)
    swarm cf recover URI          # CMD_RECOVER_SYSTEM: a crashed (tumbled) drone, upright again, may fly
    swarm cf reboot URI           # cflib's PowerSwitch: the radio's power cycle (radio URIs only)

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
    """The part of cflib's ``Crazyflie`` that ``Supervisor`` uses, over one link driver:
    ``send_packet``, ``add_port_callback`` (a thread hands each received packet to the
    port's callbacks) and ``platform.get_protocol_version``."""

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
        self._callbacks: dict[int, list[Callable[[Any], None]]] = {}
        self._done = threading.Event()
        threading.Thread(target=self._receive, daemon=True).start()

    def send_packet(self, pk: Any) -> None:
        self.driver.send_packet(pk)

    def add_port_callback(self, port: int, cb: Callable[[Any], None]) -> None:
        self._callbacks.setdefault(port, []).append(cb)

    def _receive(self) -> None:
        while not self._done.is_set():
            pk = self.driver.receive_packet(0.05)
            if pk is not None:
                for cb in self._callbacks.get(pk.port, []):
                    cb(pk)

    def close(self) -> None:
        self._done.set()
        self.driver.close()


def scan() -> list[str]:
    """URIs of the Crazyflies cflib finds (radios, USB, and UDP on 19850-19859)."""
    import cflib.crtp

    cflib.crtp.init_drivers()
    return [str(found[0]) for found in cflib.crtp.scan_interfaces()]


def status(uri: str, timeout_s: float = 1.0) -> list[str]:
    """The supervisor's active states (cflib's names), read from the drone."""
    from cflib.crazyflie.supervisor import Supervisor

    link = _Link(uri)
    try:
        sup = Supervisor(link)
        bits = sup._fetch_bitfield(timeout_s)  # noqa: SLF001 - cflib's read, with our timeout
        if not sup._bitfield_received.is_set():  # noqa: SLF001
            raise TimeoutError(f"{uri}: no supervisor answer within {timeout_s} s")
        return sup.decode_bitfield(bits)
    finally:
        link.close()


def recover(uri: str, timeout_s: float = 1.0) -> list[str]:
    """Ask a crashed drone to recover (``CMD_RECOVER_SYSTEM``); returns its states after."""
    from cflib.crazyflie.supervisor import Supervisor

    link = _Link(uri)
    try:
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
