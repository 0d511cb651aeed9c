"""The Crazyflie firmware's packet protocol as the software-in-the-loop relay
(``swarm.world.sitl_fw``) speaks it: CRTP headers, the ports and channels it uses, which
requests the firmware answers and how cflib asks again, and the supervisor's state as the
firmware's log shows it (each constant's source file in the firmware or cflib beside it)."""

from __future__ import annotations

import math
from enum import StrEnum

# (port, channel) the firmware answers (crtp.h ports; param.c, crtp_mem.c, log.c, platformservice.c, crtpservice.c)
ANSWERED = frozenset({(2, 0), (2, 1), (2, 2), (2, 3), (4, 0), (4, 1), (4, 2), (5, 0), (5, 1), (13, 0), (13, 1),
                      (15, 0), (15, 1)})  # fmt: skip
RESEND_AFTER_S = 0.2  # cflib crazyflie/__init__.py send_packet(timeout=0.2)
RESENDS = 5
MONITOR_BLOCK = 255  # cflib's log block ids run 0..254 (log.py: (counter + 1) % 255)
MONITOR_PERIOD_10MS = 1  # 100 Hz
# CRTP (crtp.h): header = port << 4 | link bits 0b11 << 2 | channel
PORT_LOG, PORT_SIM, PORT_LINK = 5, 9, 15
LOG_TOC_CH, LOG_CONTROL_CH, LOG_DATA_CH = 0, 1, 2  # log.c
CMD_GET_ITEM_V2, CMD_GET_INFO_V2 = 2, 3  # log.c TOC channel
CONTROL_START_BLOCK, CONTROL_RESET, CONTROL_CREATE_BLOCK_V2 = 3, 5, 6  # log.c control channel
LOG_TYPES = {1: "<B", 2: "<H", 3: "<I", 4: "<b", 5: "<h", 6: "<i", 7: "<f"}  # log.h LOG_UINT8 .. LOG_FLOAT
MONITOR_VARS = (
    "supervisor.info",  # supervisor.c: the state bits (cflib's Supervisor.STATES order)
    "ctrltarget.roll",  # stabilizer.c: the setpoint after the supervisor's override [deg]
    "ctrltarget.pitch",
    "ctrltarget.yaw",  # the yaw rate [deg/s]
    "stabilizer.thrust",  # the controller's thrust command (control.thrust)
    "stateEstimateZ.x",  # the position estimate [mm]
    "stateEstimateZ.y",
    "stateEstimateZ.z",
)
LEVEL_OUT_AFTER_S = 0.45  # supervisor.c levels out 500 ms after the newest setpoint (COMMANDER_WDT_TIMEOUT_STABILIZE)
BIT_CAN_FLY, BIT_FLYING, BIT_TUMBLED, BIT_LOCKED, BIT_CRASHED = 3, 4, 5, 6, 7  # supervisor.c infoBitfield


def header(port: int, channel: int) -> int:
    return (port & 0x0F) << 4 | 0x0C | (channel & 0x03)


class FwState(StrEnum):
    """The supervisor's state as its log shows it (``supervisor.info`` and the setpoint it
    flies). ``level_out`` is not a bit: it is read off the setpoint, roll, pitch and yaw rate
    zeroed with the thrust kept (supervisor.c ``supervisorOverrideSetpoint``), once the
    client's newest setpoint is :data:`LEVEL_OUT_AFTER_S` old (a client may send such a
    setpoint itself, and the log's thrust can trail a motors-off setpoint by a sample).
    ``ready`` covers ready to fly and landed (both may fly, neither flies)."""

    NOT_READY = "not_ready"
    READY = "ready"
    FLYING = "flying"
    LEVEL_OUT = "level_out"
    LOCKED = "locked"
    CRASHED = "crashed"


def fw_state(
    info: int, roll_deg: float, pitch_deg: float, yaw_dps: float, thrust: float, setpoint_age_s: float = math.inf
) -> FwState:
    """The state of one monitor sample (see :class:`FwState`); ``setpoint_age_s``: how long
    ago the client's newest setpoint came."""
    if info >> BIT_LOCKED & 1:
        return FwState.LOCKED
    if info >> BIT_CRASHED & 1:
        return FwState.CRASHED
    if info >> BIT_FLYING & 1:
        level = roll_deg == 0.0 and pitch_deg == 0.0 and yaw_dps == 0.0 and thrust > 0.0
        level = level and setpoint_age_s >= LEVEL_OUT_AFTER_S
        return FwState.LEVEL_OUT if level else FwState.FLYING
    return FwState.READY if info >> BIT_CAN_FLY & 1 else FwState.NOT_READY
