"""Benchmark of swarms with the Crazyflie firmware in the loop, printed as JSON lines.

    python -m tools.bench_firmware [--firmware 1,2,3] [--sims 2] [--seconds 12] [--cf2 PATH]
        [--thrust crazysim|2026.04] [--out runs/bench_firmware]

Each line is one run of N firmware drones (CrazySim's ``cf2``, ``swarm.world.sitl_fw``) holding
1 m over a row of starts, taking off from the floor with their yaw 20 degrees off, while
``--sims`` simulated drones cross beside them, then landing; realtime. The firmware drones'
thrust calibration is ``--thrust`` (``crazysim``: the simulated motors' own quadratic map;
``2026.04``: the linear map of a release on a real drone, to see what a linear fit costs).
Keys, for the firmware drones (worst or mean over them as named):

* ``hold_z_err_mean_m``, ``hold_z_err_max_m``: height error [m] over the last 1.5 s of the
  hold (mean signed: negative is low; max absolute, worst drone);
* ``att_err_rms_deg``: roll and pitch of the body against the roll and pitch the firmware
  was asked to fly (its ``ctrltarget`` log), RMS over the flight [deg], worst drone;
  ``yaw_err_max_deg``: the body's yaw in the hold, largest [deg];
* ``thrust_made_over_meant``: the collective thrust the motors made (their PWM through the
  simulated motors' map) over the thrust the setpoints meant (their command through the
  agents' calibration), mean over the hold, worst drone's distance from 1;
* ``setpoint_gap_p50_ms``, ``_p99_ms``, ``_max_ms``: gaps between the setpoints the firmware
  received in flight, all drones; ``setpoints_late``: gaps longer than 20 ms (two control
  periods) as a fraction;
* ``sensor_packets_missed``: fraction of the 1 kHz IMU packets the relay could not send on
  time (the relay's loop was late);
* ``cpu_percent_per_firmware``: CPU of one ``cf2`` process, mean, as a percentage of one
  core over the relay's life; ``relay_cpu_percent``: the relay (all drones' bodies and links);

and for the whole run ``real_time_factor`` and ``on_time_fraction`` (the world's: simulated
drones' commands in time for their tick), ``late_ticks``, ``collisions``, ``min_separation_m``,
``states`` (each firmware's supervisor transitions) and ``stop_reason``. Each run's folder is
kept under ``--out``. Run it alone on the machine: it measures the machine.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from swarm.config import resolve
from swarm.rotation import R_to_euler, quat_to_R
from swarm.runs.launch import RunHandle
from swarm.world.fw_process import CF2_ENV
from swarm.world.fw_trace import read_trace

from .bench_swarm import summaries


def scenario(n_fw: int, n_sim: int, seconds: float, thrust: str, cf2: str) -> dict:
    """N firmware drones in a row along x at y = 0 (0.7 m apart), simulated ones crossing at y = +-0.6 m."""
    xs = [0.7 * (i - (n_fw - 1) / 2) for i in range(n_fw)]
    fw = [
        {"id": f"fw{i + 1}", "type": "real", "start": [x, 0.0, 1.0], "goal": [x, 0.0, 1.0],
         "crazyflie": {"uri": f"udp://127.0.0.1:{19850 + i}"}}
        for i, x in enumerate(xs)
    ]  # fmt: skip
    span = max(2.5, 0.7 * n_fw / 2 + 1.5)
    sims = []
    for j in range(n_sim):  # left to right at y = 0.6, right to left at y = -0.6, pairs 0.3 m apart in z
        side, y = (-1.0, 0.6) if j % 2 == 0 else (1.0, -0.6)
        z = 1.0 + 0.3 * (j // 2)
        sims.append({"id": f"sim{j + 1}", "start": [side * span, y, z], "goal": [-side * span, y, z]})
    return {
        "version": 1,
        "name": f"bench_fw{n_fw}_sim{n_sim}",
        "duration_s": seconds,
        "stop_when_all_reached": False,
        "goal_tolerance_m": 0.15,
        "time": {"mode": "realtime", "physics_hz": 300, "control_hz": 100, "land_timeout_s": 6.0,
                 "late_command": "brake", "start_timeout_s": 180.0},
        "mocap": {"type": "sitl", "rate_hz": 100, "lost_after_s": 0.5,
                  "options": {"yaw_offset_deg": "20", "firmware": "crazysim", "cf2": cf2}},
        "defaults": {"speed_mps": 0.8, "command_level": "attitude",
                     "filter": {"kind": "c3bf", "gamma": 1.0, "sensing_radius_m": 2.5}},
        "agent_types": {"real": {"backend": "crazyflie", "crazyflie": {
            "uri": "udp://127.0.0.1:19850", "geofence_min_m": [-4, -3, -0.2], "geofence_max_m": [4, 3, 2.5],
            "mocap_timeout_s": 0.5, "thrust": {"firmware": thrust}}}},
        "agents": fw + sims,
    }  # fmt: skip


def _yaw_deg(q: np.ndarray) -> np.ndarray:
    return np.degrees([R_to_euler(quat_to_R(x))[2] for x in q])


def firmware_row(run: Path, names: list[str], cal: object) -> dict:
    """The firmware drones' figures of one run folder (see the module docstring)."""
    z_mean, z_max, att, yaw, thrust, gaps, missed, cpu, states = [], [], [], [], [], [], [], [], {}
    for name in names:
        tr = read_trace(run / "firmware" / f"{name}.jsonl")
        x, t = tr.body_x, tr.body_t
        high = np.flatnonzero(x[:, 2] > 0.9)
        if not high.size:
            states[name] = [s for _, s in tr.transitions()]
            z_mean.append(math.nan)
            continue
        end = t[high[-1]] - 0.5
        held = (t > end - 1.5) & (t < end)
        z_mean.append(float(np.mean(x[held, 2] - 1.0)))
        z_max.append(float(np.abs(x[held, 2] - 1.0).max()))
        yaw.append(float(np.abs(_yaw_deg(tr.body_q[held])).max()))
        flying = np.array([s == "flying" for s in tr.fw_state])
        e = np.array([R_to_euler(quat_to_R(q))[:2] for q in tr.body_q])
        body_rp = np.column_stack([np.interp(tr.fw_t, t, np.degrees(e[:, i])) for i in range(2)])
        # the firmware's setpoint: roll as is, pitch as on the wire (cflib's negation): the body pitch is minus it
        want = np.column_stack([tr.fw_setpoint[:, 0], -tr.fw_setpoint[:, 1]])
        att.append(float(np.sqrt(np.mean((body_rp[flying] - want[flying]) ** 2))))
        in_hold = (tr.sp_t > t[held][0]) & (tr.sp_t < t[held][-1])
        meant = np.mean([cal.collective_N(c) for c in tr.sp[in_hold, 3]])  # type: ignore[attr-defined]
        thrust.append(float(tr.body_thrust_N[held].mean() / meant))
        fly_sp = tr.sp[:, 3] > 0
        gaps.extend(np.diff(tr.sp_t[fly_sp]).tolist())
        sent = tr.end.get("sensor_packets", 0)
        missed.append(tr.end.get("missed_packets", 0) / max(1, sent + tr.end.get("missed_packets", 0)))
        states[name] = [s for _, s in tr.transitions()]
    g = np.array(gaps) * 1e3 if gaps else np.array([math.nan])
    summary: dict[str, Any] = next(
        (json.loads(m.group(1)) for line in (run / "logs" / "sitl.log").read_text().splitlines()
         if (m := re.match(r"SITL_FW_SUMMARY (.*)", line))),
        {},
    )  # fmt: skip
    if summary:
        cpu = [100 * c / summary["wall_s"] for c in summary["firmware_cpu_s"].values()]
    worst = lambda v: float(max(v, key=abs)) if v else math.nan
    return {
        "hold_z_err_mean_m": round(worst(z_mean), 4),
        "hold_z_err_max_m": round(max(z_max, default=math.nan), 4),
        "att_err_rms_deg": round(max(att, default=math.nan), 2),
        "yaw_err_max_deg": round(max(yaw, default=math.nan), 2),
        "thrust_made_over_meant": round(float(max(thrust, key=lambda r: abs(r - 1))) if thrust else math.nan, 4),
        "setpoint_gap_p50_ms": round(float(np.percentile(g, 50)), 1),
        "setpoint_gap_p99_ms": round(float(np.percentile(g, 99)), 1),
        "setpoint_gap_max_ms": round(float(g.max()), 1),
        "setpoints_late": round(float(np.mean(g > 20.0)), 4),
        "sensor_packets_missed": round(float(np.mean(missed)) if missed else math.nan, 4),
        "cpu_percent_per_firmware": round(float(np.mean(cpu)), 1) if cpu else None,
        "relay_cpu_percent": round(100 * summary["relay_cpu_s"] / summary["wall_s"], 1) if summary else None,
        "states": states,
    }


def bench_one(n_fw: int, n_sim: int, seconds: float, thrust: str, cf2: str, out: Path) -> dict:
    raw = scenario(n_fw, n_sim, seconds, thrust, cf2)
    cfg = resolve(raw, raw["name"])
    h = RunHandle.start(cfg, out / f"{raw['name']}_{thrust}")
    reason = h.wait()
    world, _agents = summaries(h.out)
    metrics = json.loads((h.out / "metrics.json").read_text()) if (h.out / "metrics.json").exists() else {}
    cal = cfg.agents[0].crazyflie.thrust.map  # type: ignore[union-attr]
    row = {"firmware_drones": n_fw, "simulated_drones": n_sim, "thrust": thrust, "seconds": seconds}
    row |= firmware_row(h.out, [a.id for a in cfg.agents if a.crazyflie is not None], cal)
    row |= {
        "real_time_factor": round(world.get("real_time_factor", math.nan), 3),
        "on_time_fraction": round(world["on_time_fraction"], 4) if world.get("on_time_fraction") is not None else None,
        "late_ticks": world.get("late"),
        "collisions": metrics.get("collisions"),
        "min_separation_m": metrics.get("min_separation_m"),
        "stop_reason": reason,
    }
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--firmware", default="1,2,3", help="numbers of firmware drones, one run each")
    ap.add_argument("--sims", default="2", help="numbers of simulated drones (crossed with --firmware)")
    ap.add_argument("--seconds", type=float, default=12.0)
    ap.add_argument("--thrust", default="crazysim", help="the firmware drones' thrust calibration (thrust.firmware)")
    ap.add_argument("--cf2", default=os.environ.get(CF2_ENV, ""), help=f"the firmware binary (default ${CF2_ENV})")
    ap.add_argument("--out", type=Path, default=Path("runs/bench_firmware"))
    args = ap.parse_args()
    for n_fw in (int(x) for x in args.firmware.split(",")):
        for n_sim in (int(x) for x in args.sims.split(",")):
            row = bench_one(n_fw, n_sim, args.seconds, args.thrust, args.cf2, args.out)
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
