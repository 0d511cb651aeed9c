"""One agent's control step, the same in every shell (the agent process, ``fly_scenario``,
``simulate``): built once from the agent's settings, then called once per control tick
with what the agent knows at that tick (docs/design.md, "The control step").

    step = swarm.build.agent_step(cfg, agent_id)          # as every shell builds it
    result = step(t_s, state, obstacles, neighbours)       # -> StepResult

A call: the state acted on (the estimate, with its deviation and age) and its body centre; every
row widened by the live noise margin; the safety monitor's verdict (``swarm.safety.monitor``);
the route's rules (replan a stalled path, give way at a narrow passage, brake before turning away
from a wall: ``swarm.route``) and the monitor's action (slow, hold, land); the reference thrust
vector (the path tracker, with the right-hand tie-break); at the rotor level the rotor thrusts
that fly it; the C3BF-QP filter against the obstacles and the neighbours; the command the plant
flies (the Crazyflie setpoint at the attitude level, the rotor thrusts at the rotor level). No
I/O; the shell brings the states and carries the result.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from swarm.control import (
    YAW_GAIN_PER_S,
    AttitudeController,
    PathTracker,
    reference_thrust,
    right_hand_bias,
    setpoint_vector,
)
from swarm.model import CommandLevel, QuadModel, QuadState, body_centre
from swarm.realism.sensing import ATTITUDE_COAST_S, Estimator, EstimatorParams, MocapFrame
from swarm.reference import ContainedController, ControllerInput
from swarm.rotation import E3, FloatArray, norm, quat_to_R
from swarm.route import Route, follows
from swarm.safety.external import ContainedFilter, FilterInput, Rows
from swarm.safety.filter import FilterConfig, FilterResult, FilterStatus, SafetyFilter
from swarm.safety.monitor import CLEAR, Action, MonitorParams, Readings, SafetyMonitor, Verdict
from swarm.safety.obstacles import NamedObstacles, ObstacleArrays
from swarm.tuning import live_margin_m

_NO_ESTIMATE = np.zeros(0)


MAX_DISTURBANCE_FRACTION = 0.3
"""The largest disturbance an agent takes off its command, per axis, as a fraction of g: well over
the ``crazyflie_lab`` preset's 3-sigma thrust-to-mass departure (17 %), so an estimate gone
wrong cannot tip the drone over."""


class Sensing(NamedTuple):
    """How an agent knows its own state (:class:`AgentStep`'s ``sensing``). ``estimator``: it acts
    on its estimate from motion-capture frames (``world.realism.sensing``), never on the state it
    is given. ``lead_s`` [s]: its command acts this much later (``swarm.tuning.command_lead_s``),
    so it filters its state predicted to then (the estimate, or the given state moved by its last
    command) against rows the caller gives at the same time. ``observer``: a real drone's
    estimator of its disturbance alone, from the states it is given (it acts on them), run on the
    ticks the caller says it is airborne. ``fixed_sd``: without an estimator, the position [m] and
    velocity [m/s] deviations its states have (a real drone's motion capture in a world with
    sensing; 0: exact). ``offset_sd_m`` [m]: the deviation of the motion capture's constant offset
    of the drone's markers from its centre of mass (``world.realism.sensing.centroid_offset_std_m``),
    which no estimator sees: added in quadrature to the estimate's position deviation.
    ``publish_ahead``: with a lead, the state it publishes is the one it filters, predicted for
    when its command acts (it knows the commands in flight; its neighbours do not), so their rows
    of it are a lead younger (docs/design.md, "Delay")."""

    estimator: Estimator | None = None
    lead_s: float = 0.0
    observer: EstimatorParams | None = None
    fixed_sd: tuple[float, float] = (0.0, 0.0)
    offset_sd_m: float = 0.0
    publish_ahead: bool = False


EXACT = Sensing()
"""An agent that acts on the exact state it is given, at once."""


def _frozen(a: FloatArray) -> FloatArray:
    """A read-only copy of ``a`` (what a plugin is handed)."""
    out = np.array(a, dtype=float)
    out.flags.writeable = False
    return out


class _Sensed(NamedTuple):
    """What the sense stage of a step found."""

    now: QuadState  # the state at the tick's time (published)
    state: QuadState  # the state filtered: at the tick's time plus the lead
    d_w: FloatArray | None  # (3,) m/s^2, world: the disturbance taken off the command, or None
    sd_m: float  # m: the largest axis's position deviation of ``state`` (the live margins')
    sd_now: tuple[float, float]  # the position [m] and velocity [m/s] deviations of ``now`` (published)
    age_s: float  # s: since the capture of the last frame fused (0 without an estimator)
    est: FloatArray  # (9,) the estimate reported (StepResult.est), or (0,)
    clip_mps2: float  # m/s^2: the disturbance's clip per axis


@dataclass(frozen=True)
class StepResult:
    """What one control step decided, and the agent's running tallies after it."""

    level: CommandLevel
    command: FloatArray  # (4,): attitude level roll [rad], pitch [rad], yaw rate [rad/s], thrust [N]; rotors f [N]
    # what is flown: F (3,) [N, world] at the attitude level (the filter's, less m x the estimated
    # disturbance), f (4,) [N] at the rotor level
    u: FloatArray
    status: FilterStatus  # OK also when the agent flies unfiltered
    filter: FilterResult | None  # None: unfiltered (filter.enabled false) or motors off
    row_ids: list[str]  # the name of each filter row, in the filter's row order
    held_w: FloatArray | None  # (3,) m/s, world: the velocity the route held in place of the path, or None
    x_b_w: FloatArray  # (3,) m, world: body centre at the step's state at its time (before any lead)
    v_b_w: FloatArray  # (3,) m/s, world: its velocity
    solo: bool  # the agent is not doing its share of a pair's avoidance now (unfiltered, or not a clean solve)
    arrived: bool  # it has been within the goal tolerance of its goal at some step
    min_h: float  # m^2/s: smallest exact h of its rows over every step so far (inf: none yet)
    infeasible_ticks: int  # steps so far whose filter call was not a clean solve
    # (9,) with an estimate: centre of mass [m] and velocity [m/s], world, the largest axis's position [m] and
    # velocity [m/s] standard deviations, and its age [s] (since the last frame fused); else (0,)
    est: FloatArray
    sd: tuple[float, float] = (0.0, 0.0)  # the published state's position [m] and velocity [m/s] deviations
    verdict: Verdict = CLEAR  # the safety monitor's at this step
    live_margin_m: float = 0.0  # m: the largest extra radius a row kept for the estimates' noise (live margins)
    # s: the state to publish (x_b_w, v_b_w, sd) is the one predicted for this long after the tick, when the
    # command acts (a delay-aware agent's, ``publish_ahead``); 0: the state at the tick
    ahead_s: float = 0.0
    fallback: str = ""  # a plugin filter's command replaced at this step, why (swarm.safety.external.Fallback); ""
    fallbacks: int = 0  # steps so far whose plugin filter's command was replaced by the built-in safe command
    controller_fallback: str = ""  # a reference controller plugin's replaced at this step, why; ""
    controller_fallbacks: int = 0  # steps so far whose controller plugin's reference was replaced by the tracker's

    @property
    def intervention(self) -> float:
        """``|u - u_ref|`` in input units (0 unfiltered)."""
        return 0.0 if self.filter is None else self.filter.intervention

    @property
    def solve_us(self) -> float:
        """The filter call's time [us] (0 unfiltered)."""
        return 0.0 if self.filter is None else self.filter.solve_time_s * 1e6

    @property
    def h_rows(self) -> FloatArray:
        """(n,) m^2/s: h of each row (``row_ids`` order)."""
        return np.zeros(0) if self.filter is None else self.filter.h


class AgentStep:
    """One agent's control step; holds what persists between ticks (its path tracker and
    route, the filter's QP workspace, the running tallies). Built from a scenario's agent by
    ``swarm.build.agent_step`` (every shell), or from its parts (``simulate``, tests)."""

    def __init__(
        self,
        model: QuadModel,
        config: FilterConfig,
        tracker: PathTracker,
        *,
        goal_w: FloatArray | None = None,
        route: Route | None = None,
        tiebreak: tuple[float, float] | None = None,
        filtered: bool = True,
        yaw_rad: float = 0.0,
        goal_tolerance_m: float = 0.15,
        landing: bool = False,
        sensing: Sensing = EXACT,
        monitor: MonitorParams | None = None,
        plugin: ContainedFilter | None = None,
        controller: ContainedController | None = None,
    ) -> None:
        """``goal_w`` (3,) [m, world] (default: the tracker's last waypoint); ``route`` replans
        and gives way on the tracker's path; ``tiebreak`` (trigger [m], speed [m/s]) or None;
        ``filtered`` False flies the reference unfiltered; ``yaw_rad`` the yaw it holds;
        ``landing`` also builds the filter a real drone lands with (its floor off);
        ``sensing``: how it knows its own state (:class:`Sensing`: its estimator, command lead,
        observer, deviations and whether it publishes its state ahead); with an estimator or a
        deviation every row grows by the live noise margin (``swarm.tuning.live_margin_m``) of the
        agent's deviation now and the one the row's state carries. ``monitor``: the safety
        monitor's parameters (None: no monitor). ``plugin``: a safety filter plugin
        (``swarm.safety.external``) flown in place of the C3BF-QP of ``config``, which is its
        fallback; ``controller``: a reference controller plugin (``swarm.reference``) whose
        reference replaces the path tracker's on a mission's ticks."""
        self.model, self.config, self.level = model, config, config.level
        self.plugin, self.controller = plugin, controller
        self.tracker, self.route, self.tiebreak = tracker, route, tiebreak
        self.filtered, self.yaw_rad, self.goal_tolerance_m = filtered, yaw_rad, goal_tolerance_m
        self.goal_w = np.asarray(tracker.goal_w if goal_w is None else goal_w, dtype=float)
        self.filt = SafetyFilter(model, config)
        self.filt_land = SafetyFilter(model, replace(config, floor_z_m=None)) if landing else None
        self.att = AttitudeController(model)
        self.estimator = sensing.estimator
        self.lead_s = sensing.lead_s
        self.observer = sensing.observer
        self.monitor = None if monitor is None or not monitor.enabled else SafetyMonitor(monitor)
        self.fixed_sd = (float(sensing.fixed_sd[0]), float(sensing.fixed_sd[1]))
        self.offset_sd_m = float(sensing.offset_sd_m)
        self.publish_ahead = sensing.publish_ahead and self.lead_s > 0.0
        self.live = self.estimator is not None or self.fixed_sd[0] > 0.0
        self._observed: Estimator | None = None  # the observer's filter since the drone is airborne
        self._frames = 0  # states fed to it
        self._a_w = np.zeros(3)  # m/s^2, world: the last command's acceleration (gravity included) (no estimator)
        self._follows = follows(route)
        self.min_h = math.inf
        self.infeasible = 0
        self.arrived = False
        self.solo = not filtered

    def follow(self, goal_w: FloatArray, tracker: PathTracker, route: Route | None, config: FilterConfig) -> None:
        """Fly a new course from this tick on (a goal from ROS 2): to ``goal_w`` [m, world] along
        ``tracker``'s path with its ``route``, filtered with ``config`` (a new filter only where
        its settings differ)."""
        self.goal_w, self.tracker, self.route, self.arrived = np.asarray(goal_w, dtype=float), tracker, route, False
        self._follows = follows(route)
        if config != self.config:
            self.config = config
            self.filt = SafetyFilter(self.model, config)
            if self.filt_land is not None:
                self.filt_land = SafetyFilter(self.model, replace(config, floor_z_m=None))

    def _held(self, t_s: float, state: QuadState, neighbours: ObstacleArrays) -> FloatArray | None:
        """The route at this tick: a new path from where the agent is if it has made no
        progress along its own for a while; then the velocity it holds in place of its path
        to give way at a narrow passage, or to brake before it turns away from a wall, or None."""
        route = self.route
        if route is None:
            return None
        remaining = self.tracker.reference(state.x_w)[2]
        new = route.update(t_s, state.x_w, self.goal_w, remaining)
        if new is not None:
            self.tracker = PathTracker(new.waypoints_w, self.tracker.speed_mps, cut_m=route.cut_m)
            remaining = self.tracker.reference(state.x_w)[2]
        v_path = self.tracker.command(state.x_w)[0]
        return route.hold(t_s, remaining, state.x_w, neighbours.c_w, neighbours.c_dot_w, state.v_w, v_path)

    def __call__(
        self,
        t_s: float,
        state: QuadState,
        obstacles: NamedObstacles,
        neighbours: NamedObstacles,
        *,
        tracker: PathTracker | None = None,
        landing: bool = False,
        frames: list[MocapFrame] | None = None,
        airborne: bool = True,
        world_late_s: float = 0.0,
        tick_overrun: bool = False,
    ) -> StepResult:
        """The step at sim time ``t_s`` [s] from ``state`` (centre of mass, world), among
        ``obstacles`` and ``neighbours`` (rows at ``t_s``, with their names). ``tracker``:
        a real drone's take-off or landing path, flown in place of the mission's (no route
        rules); ``landing``: filter with the floor off (a real drone landing through it).
        With an estimator the state is its estimate at ``t_s`` from the motion-capture
        ``frames`` that arrived since the last step (``state`` is not read). With a lead the
        neighbours' rows are the caller's at ``t_s + lead_s``. ``airborne`` False (a real drone
        taking off): its observer rests, and starts afresh from the state of its next airborne tick.
        ``world_late_s`` [s] (how far the world's clock is behind the wall clock) and
        ``tick_overrun`` (the agent's last tick took longer than a tick) are the shell's readings
        for the safety monitor, whose action changes the reference of a mission, not of a real
        drone's take-off (``airborne`` False) or landing (``landing``): its agent lands it by its
        flight plan on ``land`` (``swarm.agents.agent``).

        Stages: sense (the state acted on, and its deviation), widen (every row by the live noise
        margin), monitor (the verdict on what the margins assume), reference (the tracker's, or
        the velocity the route or the monitor holds), filter, command."""
        model, level = self.model, self.level
        sensed = self._sense(t_s, state, frames, airborne)
        now, state, d_w = sensed.now, sensed.state, sensed.d_w
        x_b, v_b, yaw = body_centre(state.x_w, state.v_w, state.q, state.Omega_b, model.params.l_m)
        nb = neighbours.arrays
        obs = obstacles.arrays
        extra_nb = extra_obs = _NO_ESTIMATE
        nb_sd = _NO_ESTIMATE if neighbours.sd_m is None else neighbours.sd_m  # (len 0: no row carries one)
        if self.live and len(nb_sd) != len(nb):
            nb_sd = np.zeros(len(nb))
        if self.live:
            extra_nb, extra_obs = live_margin_m(sensed.sd_m, nb_sd), live_margin_m(sensed.sd_m, np.zeros(len(obs)))
            nb, obs = nb.widened(extra_nb), obs.widened(extra_obs)
        verdict = self._monitor(t_s, sensed, x_b, nb, nb_sd, neighbours.age_s, d_w, world_late_s, tick_overrun)
        held = None
        if tracker is None:
            held = self._held(t_s, state, nb)
            tracker = self.tracker
        if airborne and not landing:  # (a real drone's take-off and landing are its flight plan's)
            held = self._act(verdict.action, held, tracker, state)
        if held is not None:
            F_ref = tracker.thrust_vector(model, state.x_w, state.v_w, held)  # hover, or back out of the passage
        else:
            others_v = nb.c_dot_w if self._follows else None  # a lane's queue is followed
            F_ref = reference_thrust(model, tracker, state.x_w, state.v_w, x_b, nb.c_w, self.tiebreak, others_v)
            if self.controller is not None and tracker is self.tracker and airborne and not landing:
                F_ref = self.controller.run(
                    ControllerInput(
                        t_s, state.copy(), x_b.copy(), v_b.copy(), _frozen(tracker.W), self.goal_w.copy(),
                        Rows.of(obs, obstacles), Rows.of(nb, neighbours), F_ref,
                    )
                )  # fmt: skip
        u_ref = self.att.from_thrust_vector(state, F_ref, self.yaw_rad) if level is CommandLevel.ROTORS else F_ref
        res: FilterResult | None = None
        row_ids: list[str] = []
        if self.plugin is not None:
            self.plugin.last = ""
        if self.filtered:
            rows = ObstacleArrays.concat([obs, nb]) if len(obs) else nb
            filt = self.filt_land if landing and self.filt_land is not None else self.filt
            if self.plugin is None:
                res = filt.filter(state, u_ref, rows)
            else:
                res = self.plugin.run(
                    FilterInput(
                        t_s, state.copy(), x_b.copy(), v_b.copy(), sensed.sd_m, u_ref.copy(),
                        Rows.of(obs, obstacles), Rows.of(nb, neighbours), self.goal_w.copy(),
                    ),
                    lambda: filt.filter(state, u_ref, rows),
                    lambda: self._brake(state),
                )  # fmt: skip
            names = obstacles.ids + neighbours.ids
            row_ids = [names[i] for i in res.row_index.tolist()]
            u, status = res.u, res.status
            if status is not FilterStatus.OK:
                self.infeasible += 1
            self.solo = status is not FilterStatus.OK
            self.min_h = min(self.min_h, res.min_cone_h)
        else:
            u, status = u_ref, FilterStatus.OK
        if not self.arrived:
            self.arrived = math.dist(now.x_w.tolist(), self.goal_w.tolist()) <= self.goal_tolerance_m
        sd_pub = sensed.sd_now
        if self.publish_ahead:
            pub_x, pub_v, sd_pub = x_b, v_b, (sensed.sd_m, sensed.sd_now[1])
        elif now is state:
            pub_x, pub_v = x_b, v_b
        else:
            pub_x, pub_v = body_centre(now.x_w, now.v_w, now.q, now.Omega_b, model.params.l_m)[:2]
        if d_w is not None:
            u = u - model.params.mass_kg * d_w  # the thrust vector that gives the filtered acceleration
        command = setpoint_vector(u, yaw, self.yaw_rad, YAW_GAIN_PER_S) if level is CommandLevel.ATTITUDE else u
        self._commanded(t_s, state, u, d_w, airborne, sensed.age_s)
        live_m = max(float(extra_nb.max(initial=0.0)), float(extra_obs.max(initial=0.0)))
        return StepResult(
            level=level,
            command=command,
            u=u,
            status=status,
            filter=res,
            row_ids=row_ids,
            held_w=held,
            x_b_w=pub_x,
            v_b_w=pub_v,
            solo=self.solo,
            arrived=self.arrived,
            min_h=self.min_h,
            infeasible_ticks=self.infeasible,
            est=sensed.est,
            sd=sd_pub,
            verdict=verdict,
            live_margin_m=live_m,
            ahead_s=self.lead_s if self.publish_ahead else 0.0,
            fallback="" if self.plugin is None or res is None else self.plugin.last,
            fallbacks=0 if self.plugin is None else self.plugin.fallbacks,
            controller_fallback="" if self.controller is None else self.controller.last,
            controller_fallbacks=0 if self.controller is None else self.controller.fallbacks,
        )

    def _sense(self, t_s: float, state: QuadState, frames: list[MocapFrame] | None, airborne: bool) -> _Sensed:
        """The state the step acts on (at ``t_s + lead_s``), the one it publishes (at ``t_s``),
        their deviations, and the disturbance taken off the command: the estimator's, from the
        ``frames`` (``state`` unread); a real drone's observer's on ``state``; or ``state`` moved
        by the last command over the lead."""
        model, level, est, lead = self.model, self.level, self.estimator, self.lead_s
        now = state
        d_w: FloatArray | None = None  # m/s^2, world: the disturbance taken off the command
        lim = MAX_DISTURBANCE_FRACTION * model.params.g_mps2
        if self.observer is not None and airborne and est is None:  # (a real drone, on the state it is given)
            seen = self._observed
            if seen is None:
                seen = self._observed = Estimator(self.observer, state.x_w, state.q, t_s, state.v_w)
            self._frames += 1
            seen.frame(MocapFrame(0, self._frames, t_s, t_s, state.x_w, state.q))
            if level is CommandLevel.ATTITUDE:
                d_w = np.clip(seen.estimate(t_s).d_w, -lim, lim)
        if est is None:
            if self.lead_s > 0.0:
                a = self._a_w
                x_w = state.x_w + state.v_w * lead + 0.5 * a * lead * lead
                state = QuadState(x_w, state.v_w + a * lead, state.q, state.Omega_b)
            sd = self.fixed_sd
            return _Sensed(now, state, d_w, sd[0], sd, 0.0, _NO_ESTIMATE, lim)
        for f in frames or ():
            est.frame(f)
        e = est.estimate(t_s)
        off2 = self.offset_sd_m * self.offset_sd_m
        sd_now = (math.sqrt(float(e.pos_std_m.max()) ** 2 + off2), float(e.vel_std_mps.max()))
        est_out = np.array([*e.x_w, *e.v_w, *sd_now, e.age_s])  # (reported at the tick's time)
        if level is CommandLevel.ATTITUDE:
            d_w = np.clip(e.d_w, -lim, lim)
        state = now = QuadState(e.x_w, e.v_w, e.q, e.Omega_b)
        sd_m = sd_now[0]
        if lead > 0.0:
            e = est.estimate(t_s + lead)
            state = QuadState(e.x_w, e.v_w, e.q, e.Omega_b)
            sd_m = math.sqrt(float(e.pos_std_m.max()) ** 2 + off2)
        return _Sensed(now, state, d_w, sd_m, sd_now, e.age_s, est_out, lim)

    def _monitor(
        self,
        t_s: float,
        sensed: _Sensed,
        x_b_w: FloatArray,
        nb: ObstacleArrays,
        nb_sd_m: FloatArray,
        nb_age_s: FloatArray | None,
        d_w: FloatArray | None,
        world_late_s: float,
        tick_overrun: bool,
    ) -> Verdict:
        """The safety monitor's verdict on this step's readings (CLEAR without a monitor): the
        own deviation and age, the largest deviation and age of the neighbours within the
        filter's sensing radius, the last filter call, the disturbance at its clip, and the
        shell's readings."""
        mon = self.monitor
        if mon is None:
            return CLEAR
        nb_sd = nb_age = 0.0
        p = mon.p
        if len(nb):  # (the neighbours in range only where some reading could breach)
            top_sd = float(nb_sd_m.max()) if self.live else 0.0
            top_age = 0.0 if nb_age_s is None else float(nb_age_s.max())
            nb_env = p.std_envelope_m if p.neighbour_std_envelope_m is None else p.neighbour_std_envelope_m
            if top_sd > nb_env or top_age > p.neighbour_age_s:
                d = nb.c_w - x_b_w
                near = np.einsum("ij,ij->i", d, d) <= self.config.sensing_radius_m**2
                if near.any():
                    nb_sd = float(nb_sd_m[near].max()) if self.live else 0.0
                    nb_age = 0.0 if nb_age_s is None else float(nb_age_s[near].max())
            else:
                nb_sd, nb_age = top_sd, top_age
        clipped = d_w is not None and bool((np.abs(d_w) >= sensed.clip_mps2 * (1.0 - 1e-9)).any())
        return mon.check(
            Readings(
                t_s=t_s,
                own_std_m=sensed.sd_now[0],
                own_age_s=sensed.age_s,
                neighbour_std_m=nb_sd,
                neighbour_age_s=nb_age,
                clean_solve=not (self.filtered and self.solo),
                disturbance_clipped=clipped,
                world_late_s=world_late_s,
                tick_overrun=tick_overrun,
            )
        )

    def _act(
        self, action: Action, held: FloatArray | None, tracker: PathTracker, state: QuadState
    ) -> FloatArray | None:
        """The velocity [m/s, world] the step holds under the monitor's ``action``: the route's
        or the path's at ``slow_fraction`` of it (SLOW), zero (HOLD), down at the landing speed
        to the filter's floor, then zero (LAND); ``held`` unchanged below SLOW."""
        if action < Action.SLOW or self.monitor is None:
            return held
        p = self.monitor.p
        if action is Action.SLOW:
            v = tracker.command(state.x_w)[0] if held is None else held
            return p.slow_fraction * v
        if action is Action.LAND:
            floor = self.config.floor_z_m
            if floor is None or state.x_w[2] > floor + 0.05:
                return np.array([0.0, 0.0, -p.land_speed_mps])
        return np.zeros(3)

    def _commanded(
        self, t_s: float, state: QuadState, u: FloatArray, d_w: FloatArray | None, airborne: bool, age_s: float
    ) -> None:
        """Tell the estimator (or the observer) the acceleration the command ``u`` asks from
        when it acts, and keep it for the next tick's lead without one. At the attitude level
        it is the thrust along the body axis the estimate has (:meth:`_tilted_accel_w`) while its
        attitude is measured, and the thrust vector itself once the estimate is older than
        ``ATTITUDE_COAST_S`` (a gap of motion capture: the attitude loop has flown the tilt asked
        by then, and a held attitude would have the estimate accelerate along a tilt long gone)."""
        est, lead = self.estimator, self.lead_s
        if not airborne:
            self._observed = None
        tracked = est if est is not None else self._observed
        if tracked is not None:
            tilted = self.level is CommandLevel.ATTITUDE and age_s <= ATTITUDE_COAST_S
            a_w = self._tilted_accel_w(state, u) if tilted else self._accel_w(state, u)
            tracked.command(t_s + lead, a_w)
        if est is None and lead > 0.0:
            self._a_w = self._accel_w(state, u)  # (the next tick's lead moves the state by it)
            if d_w is not None:
                self._a_w = self._a_w + d_w  # (what the drone does with it: the filtered acceleration)

    def _accel_w(self, state: QuadState, u: FloatArray) -> FloatArray:
        """The acceleration [m/s^2, world] the command ``u`` asks of the nominal airframe at
        ``state``, gravity included: ``F / m - g e3`` (at the rotor level ``F = (B u)_0 R e3``)."""
        p = self.model.params
        F = u if self.level is CommandLevel.ATTITUDE else (self.model.B[0] @ u) * quat_to_R(state.q)[:, 2]
        return F / p.mass_kg - p.g_mps2 * E3

    def _tilted_accel_w(self, state: QuadState, F_w: FloatArray) -> FloatArray:
        """The acceleration [m/s^2, world] the thrust vector ``F_w`` gives at once: its magnitude
        (the collective thrust the setpoint asks, the motors' lag left out) along the body axis
        ``state`` has now (``|F| / m R e3 - g e3``). The tilt the setpoint asks comes later (the
        attitude loop's lag, about 0.09 s); so the estimator is predicted with what the drone
        can do now, and its disturbance state takes no part of the lag for a disturbance."""
        p = self.model.params
        return norm(F_w) / p.mass_kg * quat_to_R(state.q)[:, 2] - p.g_mps2 * E3

    def motors_off(self, state: QuadState) -> StepResult:
        """The result of a tick with the motors off (a real drone that has landed or been
        stopped): a zero command, the filter not called."""
        x_b, v_b, _ = body_centre(state.x_w, state.v_w, state.q, state.Omega_b, self.model.params.l_m)
        zero = np.zeros(4)
        return StepResult(
            level=self.level,
            command=zero,
            u=zero,
            status=FilterStatus.OK,
            filter=None,
            row_ids=[],
            held_w=None,
            x_b_w=x_b,
            v_b_w=v_b,
            solo=self.solo,
            arrived=self.arrived,
            min_h=self.min_h,
            infeasible_ticks=self.infeasible,
            est=_NO_ESTIMATE,
            sd=self.fixed_sd,
        )

    def reset_tallies(self) -> None:
        """Forget the running tallies (after a warm-up call)."""
        self.min_h, self.infeasible, self.arrived = math.inf, 0, False
        self.solo = not self.filtered
        if self.plugin is not None:
            self.plugin.reset()
        if self.controller is not None:
            self.controller.reset()

    def _brake(self, state: QuadState) -> FloatArray:
        """A command of the level that brakes to a hover where the drone is (a plugin's last resort)."""
        F = self.tracker.thrust_vector(self.model, state.x_w, state.v_w, np.zeros(3))
        u = self.att.from_thrust_vector(state, F, self.yaw_rad) if self.level is CommandLevel.ROTORS else F
        ins = self.filt.input_set
        return np.clip(u, ins.lb, ins.ub)

    def warm_up(self, start_w: FloatArray) -> None:
        """Load every compiled path of the step now: one step at rest at ``start_w`` [m, world],
        then the filter's QP with active rows, its least-violation QP and the landing filter. A
        first use mid-flight stalls that tick for up to a second on a busy machine, long enough
        to look like a lost drone. The tallies are reset after."""
        none = NamedObstacles.none()
        est, self.estimator = self.estimator, None  # (its own warm-up below, on a copy)
        self(0.0, QuadState.hover(start_w), none, none)
        self.estimator, self._observed = est, None
        start = np.asarray(start_w, float)
        observer = None if self.observer is None else Estimator(self.observer, start, np.array([0.0, 0.0, 0.0, 1.0]))
        for e in (est, observer):  # their compiled prediction and update (a step at rest calls no prediction)
            if e is not None:
                c = copy.deepcopy(e)
                c.command(0.0, np.zeros(3))
                c.frame(MocapFrame(0, 0, 0.0, c.p.latency_s + 0.005, start, c.q0))
                c.estimate(0.01)
        if self.tiebreak is not None:  # the tie-break's kernel, on neighbours' rows ahead as the table gives them:
            for n in (1, 2):  # one row is a contiguous array to numba, two a strided one
                nb = ObstacleArrays.build([start + [0.5, 0.1 * i, 0.0] for i in range(n)], [0.1] * n)
                right_hand_bias(start, np.array([1.0, 0.0, 0.0]), nb.c_w, *self.tiebreak, 1.0, nb.c_dot_w)
        state = QuadState.hover([0.0, 0.0, 1.0])
        state.v_w = np.array([2.0, 0.0, 0.0])  # m/s, straight at the obstacles below
        weight = np.array([0.0, 0.0, self.model.params.weight_N])
        u = self.att.from_thrust_vector(state, weight) if self.level is CommandLevel.ROTORS else weight
        ahead = ObstacleArrays.build([[1.5, 0.0, 1.0]], [0.2])  # active: the QP
        wall = ObstacleArrays.build([[0.4, 0.0, 1.0], [0.4, 0.3, 1.0], [0.4, -0.3, 1.0]], [0.25, 0.25, 0.25])
        for filt in (self.filt, self.filt_land):
            if filt is not None:
                for obstacles in (ahead, wall):  # the wall at 2 m/s is infeasible: the slack QP
                    filt.filter(state, u, obstacles)
        self.reset_tallies()
