"""Run metrics from recorded messages (pure: lists of message dicts in, a dict out).

Distances are between body centres (``x + l R e3``), as the barriers use them;
obstacle clearance is to the obstacle surface (cylinders as infinite).

Safety figures, all from the measured (ground-truth) states:

* ``collisions``: contacts, bodies touching (the world's contact test, at the body radii);
* ``margin_violations``: pairs and agent-obstacles that came closer than the safety
  radius the filter keeps (body radii plus the margin), with the deepest slip;
* ``min_h``: the exact C3BF barrier (:func:`swarm.safety.barriers.cone_h`) of every pair and
  agent-obstacle an agent's filter had a row for (obstacles, and neighbours within its
  sensing radius), plus the horizon allowance where the agent's rows of that kind have one
  (``filter.horizon_s``; for obstacles ``swarm.build.obstacle_horizon_of``: on a path
  planned round walls the row keeps ``h_tau``, not the cone), its smallest value and the
  ticks it was negative; the ticks a
  neighbour outside the sensing radius was on a collision course (h < 0, no row yet) are
  counted apart. The rows' own values (lower bounds of h, and other barriers) are
  ``min_row_h``, as each agent reported them, escape rows left out;
  The barrier of a pair of drones is its keep-out ellipsoid's, as the filter's rows keep it
  (``filter.ellipsoid``: ``swarm.safety.barriers``, "Keep-out ellipsoid");
* ``downwash_pairs``, ``downwash_pair_ticks``, ``min_downwash_distance``: the pairs of drones
  that were ever inside their downwash keep-out ellipsoid (the larger of their airframes'
  ``keep_out_xy_m`` across and ``keep_out_z_m`` up and down between centres, no margin:
  Crazyswarm's 0.12 m and 0.30 m for two Crazyflies), the pair-ticks they were, and the
  smallest scaled distance ``|S (x_j - x_i)| / r_xy`` of any pair (below 1 inside;
  :func:`swarm.safety.barriers.scaled_distance`), whatever the filter keeps;
* ``infeasible_ticks``: ticks whose filter call was not a clean solve (every status but OK);
* per agent ``plugin_fallbacks``: the ticks a safety filter plugin's command was replaced by the
  built-in safe command, by reason (``swarm.safety.external.Fallback``) and in all (``total``), and
  ``controller_fallbacks`` the same of a reference controller plugin (``swarm.reference``);
  run-level ``plugin_fallbacks``: both totals of every agent summed, and ``fallback_agents``: the
  agents with any;
* ``deadlock_at_s`` (:func:`deadlock_at`): an agent that never reached its goal and
  stalled short of it; the same definition for every method.

The safety monitor (:mod:`swarm.safety.monitor`), from the verdicts the agents' commands carry
(:class:`MonitorFigures`):

* per agent ``monitor``: ``action_ticks`` (ticks it acted, per action: warn, slow, hold, land),
  ``breach_ticks`` (ticks each check breached, per name of ``BREACH_NAMES``),
  ``first_action_s`` (sim time of its first slow or stronger; None: never) and
  ``landed_by_monitor`` (it ever had the action land);
* per agent ``max_live_margin_m``: the largest live noise margin a filter row kept [m] (None: no
  command); with an estimate (world.realism.sensing) ``max_estimate_sd_m`` (the largest position
  standard deviation of the estimate it acted on [m]) and ``max_estimate_age_s`` (its oldest
  estimate since a motion-capture frame [s]), None without;
* run-level ``monitor``: ``action_ticks`` and ``breach_ticks`` summed over the agents (agent
  ticks), ``acting_agents`` (the agents it ever slowed, held or landed) and ``landed_agents``
  (the agents it landed).
"""

from __future__ import annotations

import math
from array import array
from collections import defaultdict
from collections.abc import Iterable
from typing import Any

import numpy as np

from swarm.build import obstacle_horizon_of
from swarm.config import ScenarioConfig
from swarm.geometry import items_to_arrays, min_pair_distance, surface_clearance
from swarm.ledger import Ledger, sent_counts
from swarm.model import body_centre
from swarm.net.messages import measurement_agent
from swarm.planning import StaticObstacles
from swarm.realism.comms import LOST, MessageKind
from swarm.safety.barriers import cone_h, horizon_allowance, keep_out_frame, scaled_distance
from swarm.safety.external import FALLBACK_NAMES
from swarm.safety.monitor import BREACH_NAMES, Action
from swarm.safety.obstacles import ObstacleArrays

SUMMARY_KEYS = (
    "collisions",
    "margin_violations",
    "downwash_pairs",
    "min_h",
    "min_separation_m",
    "min_obstacle_clearance_m",
    "all_reached_goal",
    "duration_s",
    "real_time_factor",
    "late_ticks",
    "dropped_messages",
    "lost_agents",
    "stop_reason",
)
"""The run-level metrics a summary shows (``swarm run``'s printout, ``swarm report``'s table)."""


def path_deviation(points_w: np.ndarray, path_w: np.ndarray) -> float:
    """Largest distance [m] of any point from the polyline ``path_w`` (k, 3)."""
    if len(points_w) == 0:
        return 0.0
    if len(path_w) == 1:
        return float(np.linalg.norm(points_w - path_w[0], axis=1).max())
    best = np.full(len(points_w), np.inf)
    for a, b in zip(path_w[:-1], path_w[1:], strict=True):
        d = b - a
        L2 = float(d @ d)
        t = np.clip((points_w - a) @ d / L2, 0.0, 1.0) if L2 > 0 else np.zeros(len(points_w))
        best = np.minimum(best, np.linalg.norm(points_w - (a + t[:, None] * d), axis=1))
    return float(best.max())


def deadlock_start(
    t_s: np.ndarray,
    x_w: np.ndarray,
    v_w: np.ndarray,
    goal_w: np.ndarray,
    tolerance_m: float,
    *,
    speed_mps: float = 0.05,
    hold_s: float = 2.0,
) -> float | None:
    """When [s] an agent became deadlocked, or None.

    Deadlocked: outside ``tolerance_m`` of its goal and slower than ``speed_mps`` without
    a break for at least ``hold_s`` seconds (up to the end of the record). An agent that
    arrives, or that stops only briefly (a yield), is not deadlocked.
    """
    if len(t_s) == 0:
        return None
    stalled = (np.linalg.norm(x_w - goal_w, axis=1) > tolerance_m) & (np.linalg.norm(v_w, axis=1) < speed_mps)
    start: float | None = None
    for t, s in zip(t_s, stalled, strict=True):
        if not s:
            start = None
        elif start is None:
            start = float(t)
        if start is not None and t - start >= hold_s:
            return start
    return None


def deadlock_at(
    t_s: np.ndarray,
    x_w: np.ndarray,
    v_w: np.ndarray,
    goal_w: np.ndarray,
    tolerance_m: float,
    *,
    speed_mps: float = 0.05,
    hold_s: float = 2.0,
) -> float | None:
    """When [s] an agent that never came within ``tolerance_m`` of its goal became
    deadlocked (:func:`deadlock_start`), or None: the one deadlock definition of every
    method's figures (a stall that the agent later got out of to its goal is a yield)."""
    if len(x_w) and bool((np.linalg.norm(x_w - goal_w, axis=1) <= tolerance_m).any()):
        return None
    return deadlock_start(t_s, x_w, v_w, goal_w, tolerance_m, speed_mps=speed_mps, hold_s=hold_s)


class SafetyFigures:
    """The exact-barrier and margin figures of a run, tick by tick from measured states
    (see the module docstring), for the runtime's metrics and ``fly_scenario``'s outcome
    alike. ``add`` takes one tick; :meth:`agent` and the attributes give the figures."""

    def __init__(self, cfg: ScenarioConfig) -> None:
        self.ids = [a.id for a in cfg.agents]
        self.body_m = np.array([a.airframe.params().body_radius_m for a in cfg.agents])  # (n,) m
        self.margin_m = np.array([a.filter.margin_m for a in cfg.agents])  # (n,) m
        self.sensing_m = np.array([a.filter.sensing_radius_m for a in cfg.agents])  # (n,) m
        kept = [a.quad_params() for a in cfg.agents]  # the keep-out the filters keep (the swarm's largest)
        # (n, 2) m: each agent's rows of drones keep this ellipsoid, before the margin (0: the sphere)
        self.keep_m = np.array([(k.keep_out_xy_m, k.keep_out_z_m) if a.filter.ellipsoid else (0.0, 0.0)
                                for k, a in zip(kept, cfg.agents, strict=True)])  # fmt: skip
        own = np.array([(p.keep_out_xy_m, p.keep_out_z_m) for p in (a.airframe.params() for a in cfg.agents)])
        # (n, n, 2) m: each pair's downwash keep-out, the larger of its two airframes' (no margin)
        self.downwash_m = np.maximum(own[:, None, :], own[None, :, :])
        still = StaticObstacles.of(list(cfg.obstacles))
        # (n,) 1/s: the horizon allowance of each agent's neighbour rows and obstacle rows (0: the cone)
        self.inv_tau_nb = np.array([1.0 / a.filter.horizon_s if a.filter.horizon_s else 0.0 for a in cfg.agents])
        tau_obs = [obstacle_horizon_of(a, still) for a in cfg.agents]
        self.inv_tau_obs = np.array([1.0 / t if t else nb for t, nb in zip(tau_obs, self.inv_tau_nb, strict=True)])
        n = len(self.ids)
        self.min_h = np.full(n, math.inf)  # (n,) m^2/s: smallest exact h of a row the agent had
        self.negative = np.zeros(n, dtype=int)  # (n,) ticks with a row's exact h < 0
        self.unseen = np.zeros(n, dtype=int)  # (n,) ticks with an unseen neighbour's exact h < 0
        self.violation_ticks = 0  # pair- or agent-obstacle-ticks inside the safety radius
        self.violations: set[str] = set()  # "a|b" of each pair or agent-obstacle that ever was
        self.depth_m = 0.0  # deepest slip inside a safety radius [m]
        self.downwash_ticks = 0  # pair-ticks inside the pair's downwash keep-out ellipsoid
        self.downwash: set[str] = set()  # "a|b" of each pair that ever was
        self.min_downwash = math.inf  # smallest scaled distance of a pair [unit-free] (below 1: inside)

    def add(
        self,
        present: list[int],
        x_w: np.ndarray,
        c_w: np.ndarray,
        cd_w: np.ndarray,
        obs: ObstacleArrays,
        obstacle_ids: list[str],
    ) -> None:
        """One tick: agents ``present`` (indices) with centres of mass ``x_w``, body centres
        ``c_w`` and their velocities ``cd_w`` (m, 3) [m, m/s, world], obstacles ``obs``."""
        idx = np.asarray(present, dtype=int)
        m = len(idx)
        own_m = self.body_m[idx] + self.margin_m[idx]  # (m,) m: what each agent adds to a radius
        h_all = np.full((m, 0), math.inf)
        seen_all = np.zeros((m, 0), dtype=bool)
        if m > 1:
            p = c_w[None, :, :] - c_w[:, None, :]  # (m, m, 3): [i, j] = c_j - c_i
            w = cd_w[None, :, :] - cd_w[:, None, :]
            r = self.body_m[idx][:, None] + self.body_m[idx][None, :]
            margin = np.maximum(self.margin_m[idx][:, None], self.margin_m[idx][None, :])
            r = r + margin
            keep = self.keep_m[idx][:, None, :] + margin[:, :, None]  # (m, m, 2): agent i's rows of j
            r_xy, sz = keep_out_frame(r, keep[..., 0], keep[..., 1])
            h, _ = cone_h(p.reshape(-1, 3), w.reshape(-1, 3), r_xy.reshape(-1), scale_z=sz.reshape(-1))
            _, inside = cone_h(p.reshape(-1, 3), w.reshape(-1, 3), r.reshape(-1))  # the sphere's margin
            h, inside = h.reshape(m, m), inside.reshape(m, m)
            if self.inv_tau_nb[idx].any():  # (none without filter.horizon_s)
                ps = np.concatenate([p[..., :2], (sz * p[..., 2])[..., None]], axis=-1)
                h = h + horizon_allowance(ps, r_xy) * self.inv_tau_nb[idx][:, None]
            self._downwash(idx, p)
            np.fill_diagonal(h, math.inf)
            np.fill_diagonal(inside, False)
            seen = np.linalg.norm(c_w[None, :, :] - x_w[:, None, :], axis=2) <= self.sensing_m[idx][:, None]
            np.fill_diagonal(seen, False)
            self.unseen[idx] += ((h < 0) & ~seen).any(axis=1)
            for i, j in zip(*np.nonzero(np.triu(inside)), strict=True):
                self._violation(self.ids[idx[i]], self.ids[idx[j]], float(r[i, j] - np.linalg.norm(p[i, j])))
            h_all, seen_all = h, seen
        if len(obs):
            o = len(obs)
            p = obs.c_w[None, :, :] - c_w[:, None, :]  # (m, o, 3)
            w = obs.c_dot_w[None, :, :] - cd_w[:, None, :]
            r = obs.radius_m[None, :] + own_m[:, None]
            axis = np.broadcast_to(obs.axis_w[None, :, :], (m, o, 3))
            h, inside = cone_h(p.reshape(-1, 3), w.reshape(-1, 3), r.reshape(-1), axis.reshape(-1, 3))
            h, inside = h.reshape(m, o), inside.reshape(m, o)
            if self.inv_tau_obs[idx].any():  # (none in open space)
                h = h + horizon_allowance(p, r, axis) * self.inv_tau_obs[idx][:, None]
            for i, j in zip(*np.nonzero(inside), strict=True):
                gap = float(surface_clearance(c_w[i][None, :], ObstacleArrays.of_records(obs.rec[[j]]))[0, 0])
                self._violation(self.ids[idx[i]], obstacle_ids[j], float(own_m[i] - gap))
            h_all = np.concatenate([h_all, h], axis=1)
            seen_all = np.concatenate([seen_all, np.ones((m, o), dtype=bool)], axis=1)
        if h_all.shape[1]:
            h_seen = np.where(seen_all, h_all, math.inf)
            self.min_h[idx] = np.minimum(self.min_h[idx], h_seen.min(axis=1))
            self.negative[idx] += (h_seen < 0).any(axis=1)

    def _downwash(self, idx: np.ndarray, p: np.ndarray) -> None:
        """The pairs of ``idx`` inside their downwash keep-out, ``p`` (m, m, 3) their
        centres' differences [m]."""
        keep = self.downwash_m[idx][:, idx]  # (m, m, 2)
        iu = np.triu_indices(len(idx), 1)
        d = scaled_distance(p[iu], keep[iu][:, 0], keep[iu][:, 1])
        if not len(d):
            return
        self.min_downwash = min(self.min_downwash, float(d.min()))
        for k in np.flatnonzero(d < 1.0).tolist():
            self.downwash_ticks += 1
            self.downwash.add(f"{self.ids[idx[iu[0][k]]]}|{self.ids[idx[iu[1][k]]]}")

    def _violation(self, a: str, b: str, depth_m: float) -> None:
        self.violation_ticks += 1
        self.violations.add(f"{a}|{b}")
        self.depth_m = max(self.depth_m, depth_m)

    def agent(self, i: int) -> dict[str, Any]:
        return {
            "min_h": _finite_or_none(float(self.min_h[i])),
            "negative_h_ticks": int(self.negative[i]),
            "unseen_negative_h_ticks": int(self.unseen[i]),
        }


ACTION_NAMES = tuple(a.name.lower() for a in Action if a > Action.NONE)
"""The monitor's actions ``metrics.json`` counts, weakest first (warn, slow, hold, land)."""


class MonitorFigures:
    """The safety monitor's figures of one agent (see the module docstring), from its recorded
    commands: :meth:`see` each, then :meth:`figures`."""

    def __init__(self) -> None:
        self.action_ticks = dict.fromkeys(ACTION_NAMES, 0)
        self.breach_ticks = dict.fromkeys(BREACH_NAMES.values(), 0)
        self.first_action_s: float | None = None
        self.max_live_margin_m: float | None = None
        self.max_sd_m: float | None = None
        self.max_age_s: float | None = None

    def see(self, r: dict[str, Any]) -> None:
        action = int(r.get("monitor", 0))
        if action > Action.NONE:
            name = Action(min(action, Action.LAND)).name.lower()
            self.action_ticks[name] += 1
            if action >= Action.SLOW and (self.first_action_s is None or r["t"] < self.first_action_s):
                self.first_action_s = float(r["t"])
        bits = int(r.get("breaches", 0))
        if bits:
            for b, name in BREACH_NAMES.items():
                if bits & b:
                    self.breach_ticks[name] += 1
        self.max_live_margin_m = max(self.max_live_margin_m or 0.0, float(r.get("live_margin", 0.0)))
        est = r.get("est", ())
        if len(est) == 9:
            self.max_sd_m = max(self.max_sd_m or 0.0, float(est[6]))
            self.max_age_s = max(self.max_age_s or 0.0, float(est[8]))

    def figures(self) -> dict[str, Any]:
        return {
            "monitor": {
                "action_ticks": dict(self.action_ticks),
                "breach_ticks": dict(self.breach_ticks),
                "first_action_s": self.first_action_s,
                "landed_by_monitor": self.action_ticks["land"] > 0,
            },
            "max_live_margin_m": self.max_live_margin_m,
            "max_estimate_sd_m": self.max_sd_m,
            "max_estimate_age_s": self.max_age_s,
        }


def _monitor_totals(agents: dict[str, Any]) -> dict[str, Any]:
    """The run's monitor figures from its agents' (``metrics.json``'s run-level ``monitor``)."""
    mons = {aid: a["monitor"] for aid, a in agents.items()}
    return {
        "action_ticks": {n: sum(m["action_ticks"][n] for m in mons.values()) for n in ACTION_NAMES},
        "breach_ticks": {n: sum(m["breach_ticks"][n] for m in mons.values()) for n in BREACH_NAMES.values()},
        "acting_agents": sorted(aid for aid, m in mons.items() if m["first_action_s"] is not None),
        "landed_agents": sorted(aid for aid, m in mons.items() if m["landed_by_monitor"]),
    }


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) and abs(x) < 1e8 else None


TICK_WINDOW = 1000  # ticks: a tick's barrier figures are taken once measurements this much newer arrive


class _TickFigures:
    """The per-tick figures of :func:`compute` (the smallest separation and clearance, and
    :class:`SafetyFigures`), taken tick by tick in tick order as the measurements arrive."""

    def __init__(self, cfg: ScenarioConfig) -> None:
        self.bar = SafetyFigures(cfg)
        self.index = {aid: i for i, aid in enumerate(self.bar.ids)}
        self.min_sep, self.min_clear = math.inf, math.inf  # [m]
        self.items: list[dict[str, Any]] = []  # the obstacles last recorded

    def take(
        self,
        pending: dict[int, dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]],
        obstacles_at: dict[int, Any],
        before: int | None,
    ) -> None:
        """Take (and remove) the ticks of ``pending`` older than ``before`` (all: None), in
        tick order, with the obstacles recorded at each (removed with them)."""
        for k in sorted(k for k in pending if before is None or k < before):
            self.items = obstacles_at.pop(k, self.items)
            bodies = {aid: b for aid, b in pending.pop(k).items() if aid in self.index}
            if not bodies:
                continue
            obs = items_to_arrays(self.items)
            x, c, cd = (np.array([b[f] for b in bodies.values()]) for f in range(3))
            self.min_sep = min(self.min_sep, min_pair_distance(c))
            if len(obs):
                self.min_clear = min(self.min_clear, float(surface_clearance(c, obs).min()))
            ids = [str(i.get("id", j)) for j, i in enumerate(self.items)]
            self.bar.add([self.index[aid] for aid in bodies], x, c, cd, obs, ids)
        for k in [k for k in obstacles_at if before is None or k < before]:
            del obstacles_at[k]  # recorded at a tick without measurements: never used


def compute(
    cfg: ScenarioConfig,
    records: Iterable[dict[str, Any]],
    recorder_dropped: int = 0,
    said: dict[str, dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Metrics of one run. ``records`` are decoded messages (``swarm.net.messages.to_json``)
    in file order, read once: a stream (:class:`swarm.runs.runfiles.RecordingStream`) keeps
    an hour's recording out of memory. The barrier figures are taken a tick at a time once
    the measurements are :data:`TICK_WINDOW` ticks past it. ``said``: each process's summary
    line (:func:`swarm.ledger.summaries`): what it sent, to find what the recording lacks
    at the end of a stream, and what it dropped from whom, to name the offenders."""
    ledger = Ledger.of(cfg)
    silence = Silence()
    l_m = {a.id: a.airframe.params().l_m for a in cfg.agents}
    meas: dict[str, array] = defaultdict(lambda: array("d"))  # per agent: t [s], k, x (3) [m], v (3) [m/s]
    pending: dict[int, dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]] = defaultdict(dict)  # (x, c, c')
    obstacles_at: dict[int, Any] = {}
    last_report: dict[str, dict[str, Any]] = {}
    min_row_h: dict[str, float] = defaultdict(lambda: math.inf)
    solve_us: dict[str, array] = defaultdict(lambda: array("d"))
    estimates: dict[str, array] = defaultdict(lambda: array("d"))  # per agent: k, x (3) [m] (world.realism.sensing)
    monitors: dict[str, MonitorFigures] = defaultdict(MonitorFigures)  # per agent: its safety monitor's figures
    fallbacks: dict[str, dict[str, int]] = defaultdict(lambda: dict.fromkeys(FALLBACK_NAMES, 0))  # per agent, reason
    ctrl_fallbacks: dict[str, dict[str, int]] = defaultdict(lambda: dict.fromkeys(FALLBACK_NAMES, 0))
    final: dict[str, Any] = {}  # the last status
    live_ever: set[str] = set()
    collisions: list[dict[str, Any]] = []  # among live agents' drones and obstacles
    dead_contacts: list[dict[str, Any]] = []  # of a dead agent's drone
    stalls: list[dict[str, Any]] = []
    figures = _TickFigures(cfg)
    newest_k = -1
    orders = OrderFigures()
    skipped = 0  # ticks the world flew unpublished (realtime with real drones, behind the wall clock)
    for r in records:
        kind = r["kind"]
        if kind == "clock":
            skipped += int(r.get("skipped", 0))
        if "topic" in r and "seq" in r:  # as recorded (not one of the measurements a clock carries)
            ledger.see(kind, r["src"], r["seq"], r["k"], kind == "status" and bool(r.get("done")), r.get("skipped", 0))
            silence.see(r)
        if kind == "measurement":
            aid, k = measurement_agent(r), int(r["k"])
            x, v = np.asarray(r["x"], dtype=float), np.asarray(r["v"], dtype=float)
            meas[aid].extend((float(r["t"]), k, *x.tolist(), *v.tolist()))
            q, w = np.asarray(r["q"], dtype=float), np.asarray(r.get("w", (0.0, 0.0, 0.0)), dtype=float)
            c, cd, _ = body_centre(x, v, q, w, l_m.get(aid, 0.0))  # (no body rate recorded: taken as 0)
            pending[k][aid] = (x, c, cd)
            if k > newest_k:
                newest_k = k
                figures.take(pending, obstacles_at, before=k - TICK_WINDOW)
        elif kind == "obstacles":
            obstacles_at[r["k"]] = r["items"]
        elif kind == "command":
            last_report[r["src"]] = r
            min_row_h[r["src"]] = min(min_row_h[r["src"]], r["min_h"])
            solve_us[r["src"]].append(r["solve_us"])
            monitors[r["src"]].see(r)
            for key, counts in (("fallback", fallbacks), ("ctrl_fallback", ctrl_fallbacks)):
                why = r.get(key)
                if why:
                    fb = counts[r["src"]]
                    fb[why] = fb.get(why, 0) + 1
            if len(r.get("est", ())) in (6, 9):  # x, v (and since v10 the deviations and age)
                estimates[r["src"]].extend((int(r["k"]), *(float(e) for e in r["est"][:3])))
        elif kind == "status":
            final = r
            live_ever.update(r["live"])
        elif kind == "collision":
            (dead_contacts if r.get("dead") else collisions).append(r)
        elif kind == "stall":
            stalls.append({"t_s": r["t"], "k": r["k"], "agents": r["agents"], "wait_s": r["wait_s"]})
        elif kind == "report":
            orders.see(r)
    figures.take(pending, obstacles_at, before=None)
    bar, min_sep, min_clear, index = figures.bar, figures.min_sep, figures.min_clear, figures.index

    quiet = silence.longest_s
    agents: dict[str, Any] = {}
    for a in cfg.agents:
        m = np.frombuffer(meas.get(a.id, array("d")), dtype=float).reshape(-1, 8)
        m = m[np.argsort(m[:, 1], kind="stable")]  # (ticks, 8): t, k, x, v in tick order
        ts, ks, xs, vs = m[:, 0], m[:, 1].astype(int), m[:, 2:5], m[:, 5:8]
        goal = np.asarray(a.final_goal)
        motion = _motion(ts, vs, np.asarray(a.path(), dtype=float))
        dl = cfg.deadlock
        stuck = deadlock_at(ts, xs, vs, goal, cfg.goal_tolerance_m, speed_mps=dl.speed_mps, hold_s=dl.hold_s)
        us = np.asarray(solve_us.get(a.id, []))
        d = np.linalg.norm(xs - goal, axis=1) if len(xs) else np.zeros(0)
        hit = np.flatnonzero(d <= cfg.goal_tolerance_m)
        st = last_report.get(a.id, {})
        est = np.frombuffer(estimates.get(a.id, array("d")), dtype=float).reshape(-1, 4)  # k, x [m]
        at = np.searchsorted(ks, est[:, 0].astype(int), side="right") - 1  # the tick's (last) measurement
        known = (at >= 0) & (ks[np.maximum(at, 0)] == est[:, 0].astype(int)) if len(ks) else np.zeros(len(est), bool)
        est_err = np.linalg.norm(est[known, 1:] - xs[at[known]], axis=1)
        agents[a.id] = {
            "reached_goal": bool(hit.size),
            "time_to_goal_s": float(ts[hit[0]]) if hit.size else None,
            "path_length_m": float(np.sum(np.linalg.norm(np.diff(xs, axis=0), axis=1))) if len(xs) > 1 else 0.0,
            "straight_line_m": float(np.linalg.norm(goal - np.asarray(a.start))),
            "max_path_deviation_m": path_deviation(xs, np.asarray(a.path(), dtype=float)),
            **bar.agent(index[a.id]),
            "min_row_h": _finite_or_none(min_row_h[a.id]),
            "infeasible_ticks": int(st.get("infeasible", 0)),
            "plugin_fallbacks": {
                **fallbacks.get(a.id, dict.fromkeys(FALLBACK_NAMES, 0)),
                "total": max(int(st.get("fallbacks", 0)), sum(fallbacks.get(a.id, {}).values())),
            },
            "controller_fallbacks": {
                **ctrl_fallbacks.get(a.id, dict.fromkeys(FALLBACK_NAMES, 0)),
                "total": max(int(st.get("ctrl_fallbacks", 0)), sum(ctrl_fallbacks.get(a.id, {}).values())),
            },
            "dropped_messages": int(st.get("dropped", 0)),
            "last_tick": int(ks[-1]) if len(ks) else None,
            "deadlock_at_s": stuck,
            "longest_silence_s": quiet.get(a.id, 0.0),  # live without a command (sim time)
            "solve_us_mean": float(us.mean()) if us.size else None,  # filter call per tick [us]
            "solve_us_p99": float(np.percentile(us, 99)) if us.size else None,
            # world.realism.sensing: |estimate - true centre of mass| at the ticks it acted on [m]
            "estimate_error_p95_m": float(np.percentile(est_err, 95)) if est_err.size else None,
            "estimate_error_max_m": float(est_err.max()) if est_err.size else None,
            **(monitors[a.id] if a.id in monitors else MonitorFigures()).figures(),
            **motion,
        }
    gaps = ledger.gaps(sent_counts(said or {}), int(final["k"]) if final.get("done") else None)
    lost = sorted(live_ever - set(final.get("live", [])))
    return {
        "scenario": cfg.name,
        "mode": cfg.time.mode.value,
        "collisions": len(collisions),  # contacts: bodies touching (the world's contact test)
        "collision_pairs": sorted({f"{c['a']}|{c['b']}" for c in collisions}),
        "margin_violations": len(bar.violations),  # pairs and agent-obstacles ever inside the safety radius
        "margin_violation_pairs": sorted(bar.violations),
        "margin_violation_ticks": bar.violation_ticks,
        "max_margin_depth_m": bar.depth_m,  # deepest slip inside a safety radius (0: none)
        "downwash_pairs": len(bar.downwash),  # pairs ever inside their downwash keep-out ellipsoid
        "downwash_pair_names": sorted(bar.downwash),
        "downwash_pair_ticks": bar.downwash_ticks,
        "min_downwash_distance": _finite_or_none(bar.min_downwash),  # smallest scaled distance (below 1: inside)
        "min_h": _finite_or_none(min((float(v) for v in bar.min_h), default=math.inf)),
        "negative_h_ticks": int(bar.negative.sum()),  # agent ticks with a row's exact h < 0
        "unseen_negative_h_ticks": int(bar.unseen.sum()),  # agent ticks on course with an unseen neighbour
        "dead_agent_contacts": len(dead_contacts),  # a dead agent's drone touched something (apart from collisions)
        "dead_agent_contact_pairs": sorted({f"{c['a']}|{c['b']}" for c in dead_contacts}),
        "stalls": len(stalls),  # lockstep ticks that waited longer than time.stall_warn_fraction of the timeout
        "stall_events": stalls,
        "min_separation_m": _finite_or_none(min_sep),
        "min_obstacle_clearance_m": _finite_or_none(min_clear),
        "all_reached_goal": all(v["reached_goal"] for v in agents.values()),
        "deadlocked_agents": sorted(k for k, v in agents.items() if v["deadlock_at_s"] is not None),
        "duration_s": float(final.get("t", 0.0)),
        "finished": bool(final.get("done", False)),  # the world's last status said the run is over
        "real_time_factor": float(final.get("rtf", 0.0)),
        "late_ticks": int(final.get("late", 0)),
        "skipped_ticks": skipped,  # flown unpublished: the world fell time.max_lag_s behind real drones
        "dropped_messages": int(final.get("dropped", 0))
        + sum(v["dropped_messages"] for v in agents.values())
        + recorder_dropped,
        "lost_agents": lost,
        "recording_gaps": [g.as_dict() for g in gaps],  # what the recording lacks, stream by stream
        "lost_messages": sum(g.messages for g in gaps),
        "offenders": offenders(said or {}, quiet, cfg.failure.neighbour_hard_limit_s),
        "realism": _realism_applied(cfg, last_report),
        "estimate_error_max_m": max(
            (v["estimate_error_max_m"] for v in agents.values() if v["estimate_error_max_m"] is not None), default=None
        ),
        "monitor": _monitor_totals(agents),
        "orders": orders.rows,
        "plugin_fallbacks": sum(
            v["plugin_fallbacks"]["total"] + v["controller_fallbacks"]["total"] for v in agents.values()
        ),
        "fallback_agents": sorted(
            k for k, v in agents.items() if v["plugin_fallbacks"]["total"] or v["controller_fallbacks"]["total"]
        ),
        "agents": agents,
    }


class OrderFigures:
    """A script's orders as the agents reported them (``swarm.script``): per order, its drone,
    action, the goal flown [m, world], when it was taken and when it arrived [s, sim time]
    (None: not yet), or why it was refused."""

    def __init__(self) -> None:
        self.by: dict[tuple[str, int], dict[str, Any]] = {}

    def see(self, r: dict[str, Any]) -> None:
        row = self.by.setdefault(
            (r["src"], int(r["order"])),
            {"drone": r["src"], "order": int(r["order"]), "action": r["action"], "goal_m": None,
             "taken_s": None, "arrived_s": None, "refused": None},
        )  # fmt: skip
        if r["state"] == "taken":
            row["goal_m"], row["taken_s"] = [float(v) for v in r["x"]], float(r["t"])
        elif r["state"] == "arrived" and row["arrived_s"] is None:
            row["arrived_s"] = float(r["t"])
        elif r["state"] == "refused":
            row["refused"] = r["why"]

    @property
    def rows(self) -> list[dict[str, Any]]:
        return sorted(self.by.values(), key=lambda row: (row["taken_s"] or 0.0, row["drone"], row["order"]))


class Silence:
    """How long [s of sim time] each agent was live (in the clock's live list) without a
    command: fed the recorded messages in any order (the recorder writes a batch's clocks
    before its commands), then :attr:`longest_s`."""

    def __init__(self) -> None:
        self.commands: dict[str, array] = {}  # agent -> sim times [s] of its commands
        self.live: dict[str, list[float]] = {}  # agent -> [first, last] sim time [s] it was live

    def see(self, r: dict[str, Any]) -> None:
        if r["kind"] == "command":
            self.commands.setdefault(r["src"], array("d")).append(float(r["t"]))
        elif r["kind"] == "clock":
            t = float(r["t"])
            for a in r["live"]:
                span = self.live.setdefault(a, [t, t])
                span[0], span[1] = min(span[0], t), max(span[1], t)

    @property
    def longest_s(self) -> dict[str, float]:
        out = {}
        for a, (first, last) in self.live.items():
            ts = np.sort(np.frombuffer(self.commands.get(a, array("d")), dtype=float))
            ts = ts[(ts >= first) & (ts <= last)]
            edges = np.concatenate([[first], ts, [last]])
            out[a] = float(np.diff(edges).max())
        return out


def offenders(
    said: dict[str, dict[str, Any]], silence_s: dict[str, float], silent_after_s: float
) -> dict[str, dict[str, Any]]:
    """The run's agents that misbehaved, with what the others did about it: every sender
    whose messages a receiver dropped (``said``: the summaries' ``rejected``, per sender and
    reason: the relay's and each agent's), and every agent live for more than
    ``silent_after_s`` without a command (``silence_s``)."""
    out: dict[str, dict[str, Any]] = {}
    for receiver, summary in sorted(said.items()):
        for sender, reasons in (summary.get("rejected") or {}).items():
            o = out.setdefault(sender, {"dropped": 0, "reasons": {}, "dropped_by": [], "longest_silence_s": 0.0})
            for reason, n in reasons.items():
                o["reasons"][reason] = o["reasons"].get(reason, 0) + int(n)
                o["dropped"] += int(n)
            o["dropped_by"].append(receiver)
    for agent, quiet in silence_s.items():
        if quiet > silent_after_s or agent in out:
            o = out.setdefault(agent, {"dropped": 0, "reasons": {}, "dropped_by": [], "longest_silence_s": 0.0})
            o["longest_silence_s"] = quiet
    return dict(sorted(out.items()))


def _realism_applied(cfg: ScenarioConfig, last_report: dict[str, dict[str, Any]]) -> dict[str, Any] | None:
    """What ``world.realism`` did to this run's messages, from the seeded fates (a pure function of
    seed, sender, receiver and tick: ``swarm.realism.comms``) of the ticks the agents answered:
    commands lost and their mean delay [ticks], and the same for the states between every pair of
    agents. None in the ideal world."""
    r = cfg.world.realism
    if r.ideal:
        return None
    comms = r.comms_model(cfg.seed, 1.0 / cfg.time.control_hz)
    ids = [a.id for a in cfg.agents]
    last = max((int(rep.get("k", -1)) for rep in last_report.values()), default=-1)
    cmd, st = [], []
    for k in range(last + 1):
        cmd += [comms.fate(a, "world", MessageKind.COMMAND, k) for a in ids]
        st += comms.fate_matrix(ids, MessageKind.STATE, k)[~np.eye(len(ids), dtype=bool)].tolist()

    def applied(fates: list[int]) -> dict[str, Any]:
        f = np.asarray(fates)
        kept = f[f != LOST]
        return {
            "sent": int(f.size),
            "lost": int((f == LOST).sum()),
            "mean_delay_ticks": float(kept.mean()) if kept.size else None,
        }

    return {
        "preset": r.preset,
        "sensing": r.sensing.enabled,
        "commands": applied(cmd),
        "states": applied(st),
    }


def _motion(t_s: np.ndarray, v_w: np.ndarray, path_w: np.ndarray) -> dict[str, Any]:
    """How the agent moved along its first path leg (the direction it was sent).

    ``min_along_speed_mps`` and ``final_along_speed_mps`` are the velocity [m/s] along
    that direction (negative: backwards); ``backward_time_s`` [s] is how long it moved
    backwards faster than 2 cm/s; ``final_speed_mps`` is |v| at the last measurement.
    """
    if len(v_w) == 0:
        return {
            "min_along_speed_mps": None,
            "final_along_speed_mps": None,
            "backward_time_s": 0.0,
            "final_speed_mps": None,
        }
    leg = path_w[1] - path_w[0] if len(path_w) > 1 else np.zeros(3)
    n = float(np.linalg.norm(leg))
    along = v_w @ (leg / n) if n > 1e-9 else np.zeros(len(v_w))
    dt = np.diff(t_s, append=t_s[-1])
    return {
        "min_along_speed_mps": float(along.min()),
        "final_along_speed_mps": float(along[-1]),
        "backward_time_s": float(dt[along < -0.02].sum()),
        "final_speed_mps": float(np.linalg.norm(v_w[-1])),
    }
