"""Benchmark of the lag between the acceleration the filter commands and the one the drone makes,
and of how fast the filter changes its command in a swarm, printed as JSON lines.

    python -m tools.bench_lag [--horizon-s 0.5] [--seed 0] [--swarm ideal,crazyflie_lab] [--agents 8]

The attitude level's filter treats its command, the thrust vector ``F`` [N, world], as the
acceleration ``a_cmd = F / m - g e3`` of a point mass, at once; the drone's attitude loop (the
firmware's, ``swarm.control.OnboardController``), its rotors and its radio get there later. Flown
on the world's plant (``swarm.sim.stepper``: the attitude loop, PyBullet, the plant of
``swarm.realism``), in-process.

``"kind": "step"``: one drone hovers level, and from t = 0 is sent each tick the setpoint that the
filter sends for ``a_cmd`` (``swarm.control.setpoint_vector`` of ``F = m (a_cmd + g e3)``), a step of
``a_step_mps2`` along ``axis`` (``x``: horizontal; ``z``: vertical, signed), flown at the swarm's
rates (``--control-hz``, ``--physics-hz``) for ``--horizon-s``. The velocity deficit along the
commanded direction ``d``, ``e_v(t) = d . integral_0^t (a_cmd - a) dt = |a_step| t - d . (v(t) - v(0))``
[m/s], is sampled at every tick: ``e_v_final_mps`` (at the horizon), ``e_v_max_mps``, the largest
deficit across ``d`` (``e_perp_max_mps``), the slope of ``e_v`` over the last 0.1 s
(``e_v_slope_mps2``; 0 for a pure lag) and ``tau_eff_s = e_v_final / |a_step|``, the effective lag.
Worlds (``world``): ``ideal`` (the attitude loop only); ``lab_motors`` (the ``crazyflie_lab``
preset's rotor lag, 12.5 ms up, 25 ms down); ``lab`` (that and the preset's command radio: 10 ms
late, 10 % lost, seeded by ``--seed``); ``lab_3sigma`` (``lab`` with the preset's thrust factor
and mass factor at 3 sigma of their spread the bad way, 0.85 and 1.09: a weak, heavy drone). Aero,
wind and sensing are off. ``lab_3sigma`` hovers in trim: its command is scaled by
``mass_factor / thrust_factor``, as the tracker's feedback holds it, so ``e_v`` is its lag alone;
``accel_gain`` (``thrust_factor / mass_factor``) is the fraction of a commanded change it makes
without that feedback, a steady gap, not a lag.

``"kind": "swarm"``: ``swarm.offline.closed_loop.fly_scenario`` of ``circle_swap(--agents, 2.0)``
in ``world`` (``SwapSettings.realism``; resolved by ``swarm.config.resolve``, flown with its
realism and seed). Over every agent tick: ``da_tick_*`` the change of the commanded acceleration
over one tick ``|a_cmd[k] - a_cmd[k-1]|`` [m/s^2]; ``da_win_*`` the change over the lag window
``window_ticks = round(tau_eff_s control_hz)`` ticks; ``gap_tick_*`` and ``gap_win_*`` the velocity
gap [m/s] the plant built over one tick and over the window, ``|sum a_cmd dt - (v[k] - v[k-W])|``
(the centre of mass's true velocity; in the lab world this includes the radio's delay and loss, the
factors' spread, drag, downwash and wind), ``gap_win_xy_*`` its horizontal part (without the
downwash and the thrust and mass factors' vertical bias). ``_p50 _p95 _p99 _max`` name the percentiles.
``tau_eff_s`` is the largest of the world's step lines (``ideal``; ``lab`` for ``crazyflie_lab``).
The bound: the velocity buffer ``buffer_mps`` ``b`` covers a command that changes by up to
``da_bound_mps2 = b / tau_eff`` within a lag time; ``frac_da_tick_within``, ``frac_da_win_within``,
``frac_gap_win_within`` (``gap_win <= b``) and ``frac_gap_win_xy_within`` are the fractions of
agent ticks that stay under it.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass

import numpy as np

from swarm.config import resolve
from swarm.control import YAW_GAIN_PER_S, setpoint_vector
from swarm.model import QuadParams, thrust_vector_input_set
from swarm.offline.closed_loop import fly_scenario
from swarm.offline.scenario import SwapSettings, circle_swap
from swarm.realism.settings import PRESETS, RealismSettings
from swarm.rotation import E3, FloatArray
from swarm.sim.stepper import Stepper

HORIZONTAL_MPS2 = (0.5, 1.0, 2.0, 5.0)
VERTICAL_MPS2 = (1.0, -1.0, 3.0, -3.0)
PREROLL_S = 0.3
"""The drone hovers on its trim command this long before the step (the rotors settle)."""
SLOPE_S = 0.1
"""``e_v_slope_mps2`` is taken over the horizon's last this many seconds."""
SIGMAS = 3.0


def world_settings(world: str) -> tuple[RealismSettings, float, float]:
    """(realism, thrust factor, mass factor) of a step world (module docstring)."""
    lab = PRESETS["crazyflie_lab"]
    lag = {k: lab["motors"][k] for k in ("time_constant_up_s", "time_constant_down_s")}
    if world == "ideal":
        return RealismSettings(), 1.0, 1.0
    if world == "lab_motors":
        return RealismSettings.model_validate({"motors": lag}), 1.0, 1.0
    radio = {"command": lab["comms"]["command"]}
    if world == "lab":
        return RealismSettings.model_validate({"motors": lag, "comms": radio}), 1.0, 1.0
    if world == "lab_3sigma":
        kf = 1.0 - SIGMAS * lab["motors"]["thrust_coefficient_spread_fraction"]
        mf = 1.0 + SIGMAS * lab["motors"]["mass_spread_fraction"]
        motors = {**lag, "thrust_coefficient_offset_fraction": kf - 1.0, "mass_offset_fraction": mf - 1.0}
        return RealismSettings.model_validate({"motors": motors, "comms": radio}), kf, mf
    raise ValueError(f"unknown world {world!r}")


@dataclass(frozen=True)
class StepResponse:
    """One step's velocity deficit (module docstring)."""

    e_v_final_mps: float
    e_v_max_mps: float
    e_perp_max_mps: float
    e_v_slope_mps2: float

    def tau_eff_s(self, a_mps2: float) -> float:
        return self.e_v_final_mps / abs(a_mps2)


def fly_step(
    params: QuadParams,
    world: str,
    a_cmd_w: FloatArray,
    horizon_s: float,
    control_hz: float,
    physics_hz: float,
    seed: int,
) -> StepResponse:
    """Hover ``PREROLL_S`` on the trim command, then send ``a_cmd_w`` (3,) [m/s^2, world] each tick."""
    realism, kf, mf = world_settings(world)
    raw = {
        "version": 1,
        "name": f"step_{world}",
        "seed": seed,
        "duration_s": PREROLL_S + horizon_s,
        "time": {"mode": "lockstep", "control_hz": control_hz, "physics_hz": physics_hz},
        "world": {"realism": realism.model_dump(mode="json")},
        "agents": [{"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [1.0, 0.0, 1.0]}],
    }
    plant = Stepper(resolve(raw))  # the world's plant (swarm.sim.stepper), one drone
    dt = 1.0 / control_hz
    k = 0

    def fly(setpoint: FloatArray) -> None:
        nonlocal k
        v_tick = plant.read().v_w
        plant.send("cf1", setpoint, k * dt, k)
        for j in range(plant.cfg.time.substeps):
            plant.deliver(k)
            plant.substep(None, j == 0, {}, v_tick)
        k += 1

    trim = mf / kf
    m, g = params.mass_kg, params.g_mps2

    def command(a_w: FloatArray) -> FloatArray:
        F_w = trim * m * (a_w + g * E3)  # the filter's thrust vector for a_w, as the tracker trims it
        return setpoint_vector(F_w, 0.0, 0.0, YAW_GAIN_PER_S)

    hover = command(np.zeros(3))
    for _ in range(round(PREROLL_S * control_hz)):
        fly(hover)
    v0 = plant.read().v_w[0].copy()
    step = command(a_cmd_w)
    d = a_cmd_w / np.linalg.norm(a_cmd_w)
    ticks = round(horizon_s * control_hz)
    e = np.empty((ticks, 3))  # integral of (a_cmd - a) [m/s, world] at the end of each tick
    for j in range(ticks):
        fly(step)
        e[j] = a_cmd_w * (j + 1) / control_hz - (plant.read().v_w[0] - v0)
    plant.close()
    e_v = e @ d
    e_perp = np.linalg.norm(e - np.outer(e_v, d), axis=1)
    back = max(1, round(SLOPE_S * control_hz))
    slope = (e_v[-1] - e_v[-1 - back]) * control_hz / back
    return StepResponse(float(e_v[-1]), float(e_v.max()), float(e_perp.max()), float(slope))


def step_lines(
    params: QuadParams, worlds: list[str], horizon_s: float, control_hz: float, physics_hz: float, seed: int
) -> list[dict[str, object]]:
    usable = thrust_vector_input_set(params)
    out: list[dict[str, object]] = []
    for world in worlds:
        _, kf, mf = world_settings(world)
        for axis, sizes in (("x", HORIZONTAL_MPS2), ("z", VERTICAL_MPS2)):
            for a in sizes:
                a_w = a * (np.array([1.0, 0.0, 0.0]) if axis == "x" else E3)
                if not usable.contains(params.mass_kg * (a_w + params.g_mps2 * E3)):
                    continue  # beyond what the attitude level's thrust and tilt allow
                r = fly_step(params, world, a_w, horizon_s, control_hz, physics_hz, seed)
                out.append(
                    {
                        "kind": "step",
                        "world": world,
                        "axis": axis,
                        "a_step_mps2": a,
                        "thrust_factor": round(kf, 4),
                        "mass_factor": round(mf, 4),
                        "accel_gain": round(kf / mf, 4),
                        "horizon_s": horizon_s,
                        "e_v_final_mps": rounded(r.e_v_final_mps, 5),
                        "e_v_max_mps": rounded(r.e_v_max_mps, 5),
                        "e_perp_max_mps": rounded(r.e_perp_max_mps, 5),
                        "e_v_slope_mps2": rounded(r.e_v_slope_mps2, 4),
                        "tau_eff_s": rounded(r.tau_eff_s(a), 5),
                    }
                )
    return out


def rounded(x: float, digits: int = 5) -> float:
    """``x`` rounded, without a negative zero."""
    return round(x, digits) + 0.0


def percentiles(name: str, x: FloatArray) -> dict[str, float]:
    p50, p95, p99 = np.percentile(x, [50, 95, 99])
    return {f"{name}_p50": p50, f"{name}_p95": p95, f"{name}_p99": p99, f"{name}_max": float(x.max())}


def swarm_line(world: str, agents: int, tau_eff_s: float) -> dict[str, object]:
    """Fly ``circle_swap(agents, 2.0)`` in ``world`` and measure its commands (module docstring)."""
    cfg = resolve(circle_swap(agents, 2.0, SwapSettings(realism=world)))
    params = cfg.agents[0].quad_params()
    if any(a.quad_params() != params for a in cfg.agents):
        raise ValueError("circle_swap: the agents' airframes differ")
    t = cfg.time
    log = fly_scenario(cfg)
    assert log.accel_cmd_w is not None
    a = log.accel_cmd_w[:-1]  # (T-1, N, 3): the command of tick k, flown over tick k
    dt = 1.0 / t.control_hz
    v = log.v_w  # v[k]: at the start of tick k
    w = max(1, round(tau_eff_s / dt))
    da_tick = np.linalg.norm(a[1:] - a[:-1], axis=2).ravel()
    da_win = np.linalg.norm(a[w:] - a[:-w], axis=2).ravel()
    gap_tick = np.linalg.norm(a * dt - (v[1:] - v[:-1]), axis=2).ravel()
    cum = np.concatenate([np.zeros((1, *a.shape[1:])), np.cumsum(a * dt, axis=0)])  # cum[k]: sum of a[:k] dt
    gap = (cum[w:] - cum[:-w]) - (v[w:] - v[:-w])
    gap_win = np.linalg.norm(gap, axis=2).ravel()
    gap_win_xy = np.linalg.norm(gap[..., :2], axis=2).ravel()
    b = cfg.agents[0].filter.buffer_mps
    bound = b / tau_eff_s
    out: dict[str, object] = {
        "kind": "swarm",
        "world": world,
        "agents": agents,
        "ticks": int(a.shape[0]),
        "reached": sum(tg is not None for tg in log.time_to_goal_s),
        "min_separation_m": round(log.min_separation_m, 4),
        "control_hz": t.control_hz,
        "tau_eff_s": round(tau_eff_s, 5),
        "window_ticks": w,
        "buffer_mps": b,
        "da_bound_mps2": round(bound, 4),
    }
    parts = {"da_tick": da_tick, "da_win": da_win, "gap_tick": gap_tick, "gap_win": gap_win, "gap_win_xy": gap_win_xy}
    for name, x in parts.items():
        out.update({k: rounded(float(val)) for k, val in percentiles(name, x).items()})
    out["frac_da_tick_within"] = round(float(np.mean(da_tick <= bound)), 5)
    out["frac_da_win_within"] = round(float(np.mean(da_win <= bound)), 5)
    out["frac_gap_win_within"] = round(float(np.mean(gap_win <= b)), 5)
    out["frac_gap_win_xy_within"] = round(float(np.mean(gap_win_xy <= b)), 5)
    return out


SWARM_STEP_WORLD = {"ideal": "ideal", "crazyflie_lab": "lab"}
"""The step world whose largest ``tau_eff_s`` sizes a swarm world's bound."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worlds", default="ideal,lab_motors,lab,lab_3sigma", help="step worlds")
    ap.add_argument("--horizon-s", type=float, default=0.5)
    ap.add_argument("--control-hz", type=float, default=SwapSettings.control_hz)
    ap.add_argument("--physics-hz", type=float, default=SwapSettings.physics_hz)
    ap.add_argument("--seed", type=int, default=0, help="the lab radio's fates in the step worlds")
    ap.add_argument("--swarm", default="ideal,crazyflie_lab", help="swarm worlds ('' : none)")
    ap.add_argument("--agents", type=int, default=8)
    args = ap.parse_args()
    params = QuadParams()
    worlds = args.worlds.split(",")
    swarm_worlds = [w for w in args.swarm.split(",") if w]
    need = {SWARM_STEP_WORLD[w] for w in swarm_worlds}
    lines = step_lines(params, worlds + sorted(need - set(worlds)), args.horizon_s, args.control_hz,
                       args.physics_hz, args.seed)  # fmt: skip
    for line in lines:
        if line["world"] in worlds:
            print(json.dumps(line), flush=True)
    for world in swarm_worlds:
        taus = [float(str(x["tau_eff_s"])) for x in lines if x["world"] == SWARM_STEP_WORLD[world]]
        print(json.dumps(swarm_line(world, args.agents, max(taus) if taus else math.nan)), flush=True)


if __name__ == "__main__":
    main()
