"""One agent of a scenario, built the same way for every shell: the agent process
(``swarm agent``), the offline loop (``swarm.offline.closed_loop.fly_scenario``) and the
benchmarks that fly it. The config is read here, once; the core gets its plain values.

    step = agent_step(cfg, "cf1")                # its control step (swarm.step.AgentStep)
    table = agent_neighbour_table(cfg, "cf1")    # its neighbour table, with the run's limits
"""

from __future__ import annotations

from swarm.config import FailureSettings, ScenarioConfig
from swarm.model import QuadParams
from swarm.net.neighbours import NeighbourTable
from swarm.net.statewire import Plausible
from swarm.planning import StaticObstacles
from swarm.realism.settings import RealismSettings
from swarm.step import AgentStep
from swarm.tuning import NOISE_SIGMAS, prediction_bounds


def agent_step(cfg: ScenarioConfig, agent_id: str, still: StaticObstacles | None = None) -> AgentStep:
    """The control step of agent ``agent_id`` of ``cfg``: its airframe, yaw, path round the static
    obstacles ``still`` (default: the scenario's), filter, estimator (``world.realism.sensing``,
    a simulated drone), a real drone's disturbance observer, command lead at the scenario's
    control rate, and safety monitor with the scenario's failure settings."""
    still = StaticObstacles.of(list(cfg.obstacles)) if still is None else still
    return AgentStep.of_agent(
        cfg.agent(agent_id),
        still,
        cfg.goal_tolerance_m,
        realism=cfg.world.realism,
        control_hz=cfg.time.control_hz,
        monitor=cfg.monitor,
        failure=cfg.failure,
    )


def agent_neighbour_table(cfg: ScenarioConfig, agent_id: str) -> NeighbourTable:
    """The neighbour table of agent ``agent_id`` of ``cfg``: the scenario's failure settings,
    the prediction bounds of its airframe in ``world.realism`` (``swarm.tuning.neighbour_table``)
    and the run's plausibility limits on what a neighbour's state may say
    (``swarm.net.statewire.Plausible``)."""
    table = neighbour_table(cfg.failure, cfg.agent(agent_id).quad_params(), cfg.world.realism)
    table.limits = Plausible.of(cfg)
    return table


def neighbour_table(failure: FailureSettings, params: QuadParams, realism: RealismSettings | None) -> NeighbourTable:
    """The neighbour table of an agent flying an airframe like ``params``: its ``failure``
    settings, the prediction bounds of ``realism`` (:func:`prediction_bounds`), and with
    ``realism.sensing`` each row's velocity error :data:`NOISE_SIGMAS` times the deviation its
    state carries where that exceeds the bound (the one builder of every shell: :func:`agent_neighbour_table`)."""
    accel, vel_err = prediction_bounds(params, realism)
    sigmas = NOISE_SIGMAS if realism is not None and realism.sensing.enabled else 0.0
    f = failure
    return NeighbourTable(
        f.neighbour_timeout_s, f.neighbour_growth_mps, f.neighbour_hard_limit_s, f.on_lost, accel, vel_err, sigmas
    )
