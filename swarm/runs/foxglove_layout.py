"""The Foxglove layout of a run (foxglove-sdk's ``foxglove.layouts``; no I/O).

A 3-D view of ``/scene`` and ``/tf`` (the world frame fixed), and per drone the plots a
user of a safety filter looks at first: the smallest value ``min_h`` of its filter's rows
so far in the run [m^2/s] (lower bounds of the exact barrier, escape rows left out) and the
filter's intervention ``|u - u_ref|`` [N], the filter status over time, its safety
monitor's action (0 none, 1 warn, 2 slow, 3 hold, 4 land: :class:`swarm.safety.monitor.Action`)
and the largest live noise margin a row kept [m], and the processes' log.
``docs/foxglove_layout.json`` is this layout for
``configs/swap_2.yaml`` (drones cf1 and cf2); every run folder gets its own
``foxglove_layout.json`` for its drones. Import it in Foxglove (Layouts, Import from file).
"""

from __future__ import annotations

from collections.abc import Sequence

import foxglove.layouts as fl

from swarm.runs.foxglove_scene import LOG_TOPIC, SCENE_TOPIC, WORLD_FRAME

ACTION_SCALE = "0 none, 1 warn, 2 slow, 3 hold, 4 land"  # the monitor's plot: its action's values


def _plot(title: str, field: str, agent_ids: Sequence[str], unit: str) -> fl.PlotPanel:
    series = [
        fl.PlotSeries(value=f"/agent/{a}/command.{field}", label=a, timestamp_method="receiveTime") for a in agent_ids
    ]
    return fl.PlotPanel(title=f"{title} [{unit}]", config=fl.PlotConfig(paths=series, show_legend=True))


def run_layout(agent_ids: Sequence[str]) -> fl.Layout:
    """The layout for a run of drones ``agent_ids`` (topics as the recorder names them)."""
    three_d = fl.ThreeDeePanel(
        title="swarm",
        config=fl.ThreeDeeConfig(
            follow_tf=WORLD_FRAME,
            fixed_frame=WORLD_FRAME,
            topics={SCENE_TOPIC: fl.BaseRendererSceneUpdateTopicSettings(visible=True)},
            camera_state=fl.ThreeDeeCameraState(
                distance=9.0, perspective=True, phi=55.0, theta_offset=45.0, target=(0.0, 0.0, 1.0)
            ),
        ),
    )
    status = fl.StateTransitionsPanel(
        title="filter status",
        config=fl.StateTransitionsConfig(
            paths=[fl.StateTransitionsSeries(value=f"/agent/{a}/command.status", label=a) for a in agent_ids]
        ),
    )
    log = fl.LogPanel(title="log", config=fl.LogConfig(topic_to_render=LOG_TOPIC))
    plots = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(content=_plot("smallest row h", "min_h", agent_ids, "m^2/s")),
            fl.SplitItem(content=_plot("filter intervention", "intervention", agent_ids, "N")),
            fl.SplitItem(content=status),
            fl.SplitItem(content=_plot("safety monitor", "monitor", agent_ids, ACTION_SCALE)),
            fl.SplitItem(content=_plot("live noise margin", "live_margin", agent_ids, "m")),
        ],
    )
    left = fl.SplitContainer(
        direction="column",
        items=[fl.SplitItem(proportion=3, content=three_d), fl.SplitItem(proportion=1, content=log)],
    )
    right = fl.SplitItem(proportion=2, content=plots)
    return fl.Layout(
        content=fl.SplitContainer(direction="row", items=[fl.SplitItem(proportion=3, content=left), right])
    )


def run_layout_json(agent_ids: Sequence[str]) -> str:
    """:func:`run_layout` as the JSON text Foxglove imports."""
    return run_layout(agent_ids).to_json()
