"""``swarm report RUN_DIR``: PNG plots and a markdown summary of a recorded run.

Writes into ``RUN_DIR/report/``: ``trajectory_3d.png`` (paths with obstacles to scale),
``views.png`` (top and side views), ``clearance.png`` (distance of each body centre to
each obstacle surface and between agents, with the safety radii marked), ``h.png``
(h of every filter row), ``speed.png``, ``intervention.png`` (|u - u_ref|) and
``summary.md`` (the metrics table and the plots).
"""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Circle, Polygon

from swarm.config import ScenarioConfig
from swarm.geometry import items_to_arrays, surface_clearance
from swarm.net.messages import measurement_agent
from swarm.offline.metrics import SUMMARY_KEYS
from swarm.rotation import quat_to_R
from swarm.runs.readable import fig as cell
from swarm.runs.readable import markdown_table, notes
from swarm.runs.runfiles import RecordingStream, read_config, write_metrics


def _series(cfg: ScenarioConfig, records: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """Per-agent time series from the recorded messages."""
    l_m = {a.id: a.airframe.params().l_m for a in cfg.agents}
    out: dict[str, Any] = {
        "t": defaultdict(list),
        "x": defaultdict(list),
        "xb": defaultdict(list),
        "speed": defaultdict(list),
        "h": defaultdict(lambda: defaultdict(list)),
        "iv": defaultdict(list),
        "obstacles": {},
    }
    for r in records:
        kind = r["kind"]
        if kind == "measurement":
            aid = measurement_agent(r)
            x, q = np.asarray(r["x"]), np.asarray(r["q"])
            out["t"][aid].append(r["t"])
            out["x"][aid].append(x)
            out["xb"][aid].append(x + l_m.get(aid, 0.0) * quat_to_R(q)[:, 2])
            out["speed"][aid].append(float(np.linalg.norm(r["v"])))
        elif kind == "command":
            for rid, h in zip(r.get("row_ids", []), r.get("h_rows", []), strict=False):
                out["h"][r["src"]][rid].append((r["t"], h))
            out["iv"][r["src"]].append((r["t"], r["intervention"]))
        elif kind == "obstacles":
            out["obstacles"][r["k"]] = (r["t"], r["items"])
    return out


def _equal_3d(ax: Any, lo: np.ndarray, hi: np.ndarray, min_span_m: float = 1.0) -> None:
    """Limits ``lo..hi`` (each axis at least ``min_span_m``) drawn at one scale."""
    mid, span = (lo + hi) / 2, np.maximum(hi - lo, min_span_m)
    ax.set_xlim(mid[0] - span[0] / 2, mid[0] + span[0] / 2)
    ax.set_ylim(mid[1] - span[1] / 2, mid[1] + span[1] / 2)
    ax.set_zlim(mid[2] - span[2] / 2, mid[2] + span[2] / 2)
    ax.set_box_aspect(span)


def _obstacle_patch(item: dict[str, Any], plane: tuple[int, int], length_m: float, **kw: Any) -> Any:
    """The obstacle's outline projected on a coordinate plane, to scale."""
    c, r = np.asarray(item["c"]), item["r"]
    i, j = plane
    a = np.asarray(item["a"])
    ap = np.array([a[i], a[j]])
    if item["shape"] == "sphere" or np.linalg.norm(ap) < 1e-6:
        return Circle((c[i], c[j]), r, **kw)
    half = 0.5 * length_m * ap  # the projected axis, half length
    n = np.array([-ap[1], ap[0]]) / np.linalg.norm(ap) * r
    ctr = np.array([c[i], c[j]])
    return Polygon([ctr - half - n, ctr + half - n, ctr + half + n, ctr - half + n], closed=True, **kw)


LEGEND_MAX = 12
"""Above this many lines a plot names its agents on a colour key, not in a legend."""
WORST = 3
"""How many of the closest pairs and lowest rows a crowded plot names."""
MARKS = ("v", "^", "s")
"""Their markers, closest (lowest) first."""


def agent_colours(agents: list[str]) -> dict[str, Any]:
    """One colour per agent: matplotlib's ten distinct ones up to ten agents, else evenly
    spread along a colormap (no two agents alike, as the swarms we fly have 32 and more)."""
    if len(agents) <= 10:
        cycle = plt.get_cmap("tab10")
        return {a: cycle(i) for i, a in enumerate(agents)}
    cmap = plt.get_cmap("turbo")
    return {a: cmap(v) for a, v in zip(agents, np.linspace(0.05, 0.95, len(agents)), strict=True)}


def agent_key(fig: Any, ax: Any, agents: list[str], colours: dict[str, Any], extra: list[Any] | None = None) -> None:
    """Name the agents beside ``ax``: a legend outside the axes for a few, a colour key
    (a colour bar ticked with agent ids) for many; the ``extra`` handles (markers, lines)
    in the legend, or in a legend of their own inside the axes."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import ListedColormap

    if len(agents) <= LEGEND_MAX:
        handles = [plt.Line2D([], [], color=colours[a], label=a) for a in agents] + list(extra or [])
        ax.legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
        return
    if extra:
        ax.legend(handles=extra, fontsize=7, loc="upper left")
    sm = ScalarMappable(cmap=ListedColormap([colours[a] for a in agents]))
    sm.set_array(np.arange(len(agents)))
    sm.set_clim(-0.5, len(agents) - 0.5)
    bar = fig.colorbar(sm, ax=ax, pad=0.12 if ax.name == "3d" else 0.02, fraction=0.04)  # (clear of a z label)
    step = max(1, len(agents) // 16)
    bar.set_ticks(np.arange(0, len(agents), step))
    bar.set_ticklabels([agents[i] for i in range(0, len(agents), step)], fontsize=7)
    bar.set_label("agent")


def scene_title(cfg: ScenarioConfig, n_agents: int) -> str:
    """What the run is: its name, how many drones, and its obstacles (if any) and world."""
    obs = len(cfg.obstacles)
    what = f"{n_agents} drone{'s' if n_agents != 1 else ''}"
    what += f", {obs} obstacle{'s' if obs != 1 else ''}" if obs else ", no obstacles"
    return f"{cfg.name} ({what}; world {cfg.world.realism.preset})"


class Report:
    """One run's report: :meth:`write` draws each figure (one method each) into
    ``run_dir/report/`` and writes ``summary.md``."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        cfg = self.cfg = read_config(run_dir)
        metrics_path = run_dir / "metrics.json"
        self.metrics = json.loads(metrics_path.read_text()) if metrics_path.exists() else write_metrics(run_dir)
        s = self.s = _series(cfg, RecordingStream(run_dir / "run.mcap"))
        self.out = run_dir / "report"
        self.agents = [a.id for a in cfg.agents if s["x"].get(a.id)]
        self.lengths = {o.id: o.length_m for o in cfg.obstacles}
        ks = self.ks = sorted(s["obstacles"])
        self.first = s["obstacles"][ks[0]][1] if ks else []  # obstacle items at the start
        self.last = s["obstacles"][ks[-1]][1] if ks else []  # ... and at the end
        self.body = {a.id: a.airframe.params().body_radius_m for a in cfg.agents}
        self.margin = {a.id: a.filter.margin_m for a in cfg.agents}
        self.colours = agent_colours(self.agents)

    def write(self) -> Path:
        self.out.mkdir(exist_ok=True)
        self.trajectory_3d()
        self.views()
        self.clearance()
        self.h_rows()
        self.time_series()
        self.summary()
        return self.out

    def trajectory_3d(self) -> None:
        """trajectory_3d.png: the 3-D trajectories and the obstacles at t = 0."""
        cfg, s, out, agents, lengths, first = self.cfg, self.s, self.out, self.agents, self.lengths, self.first
        colours = self.colours
        fig = plt.figure(figsize=(9, 6.5))
        ax = fig.add_subplot(projection="3d")
        allpts = [np.array(s["x"][a]) for a in agents]
        lo = np.vstack(allpts).min(axis=0) - 0.2
        hi = np.vstack(allpts).max(axis=0) + 0.2
        for a, pts in zip(agents, allpts, strict=True):
            ax.plot(pts[:, 0], pts[:, 1], pts[:, 2], color=colours[a], lw=1.0)
            ax.scatter(*pts[0], marker="o", s=16, color=colours[a])
            ax.scatter(*cfg.agent(a).final_goal, marker="x", s=30, color=colours[a])
        u, v = np.mgrid[0 : 2 * np.pi : 24j, 0 : np.pi : 12j]
        for item in first:
            c, r = np.asarray(item["c"]), item["r"]
            if item["shape"] == "sphere":
                ax.plot_wireframe(
                    c[0] + r * np.cos(u) * np.sin(v),
                    c[1] + r * np.sin(u) * np.sin(v),
                    c[2] + r * np.cos(v),
                    color="tab:red",
                    alpha=0.35,
                    linewidth=0.5,
                )
            else:
                a_ = np.asarray(item["a"])
                e1 = np.cross(a_, [1.0, 0, 0] if abs(a_[0]) < 0.9 else [0, 1.0, 0])
                e1 /= np.linalg.norm(e1)
                e2 = np.cross(a_, e1)
                span = min(lengths.get(item["id"], 4.0), 2.0 * max(np.ptp(np.vstack(allpts), axis=0).max(), 1.0))
                th, z = np.mgrid[0 : 2 * np.pi : 24j, -span / 2 : span / 2 : 8j]
                pts = (
                    c[:, None, None]
                    + r * (np.cos(th) * e1[:, None, None] + np.sin(th) * e2[:, None, None])
                    + z * a_[:, None, None]
                )
                ax.plot_wireframe(pts[0], pts[1], pts[2], color="tab:orange", alpha=0.35, linewidth=0.5)
            if item["shape"] == "sphere":  # keep whole spheres in view (cylinders are long)
                lo = np.minimum(lo, np.asarray(item["c"]) - item["r"])
                hi = np.maximum(hi, np.asarray(item["c"]) + item["r"])
        _equal_3d(ax, lo, hi)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
        ax.set_title(f"{scene_title(cfg, len(agents))}: paths in 3-D", fontsize=10)
        marks = [
            plt.Line2D([], [], marker="o", ls="", color="0.3", label="start"),
            plt.Line2D([], [], marker="x", ls="", color="0.3", label="goal"),
        ]
        if first:
            marks.append(plt.Line2D([], [], color="tab:red", alpha=0.5, label="obstacle at t = 0"))
        agent_key(fig, ax, agents, colours, marks)
        fig.savefig(out / "trajectory_3d.png", dpi=110, bbox_inches="tight")
        plt.close(fig)

    def views(self) -> None:
        """views.png: top and side views, obstacles to scale at the start and the end."""
        s, out, agents, lengths, first, last = self.s, self.out, self.agents, self.lengths, self.first, self.last
        colours = self.colours
        fig, axs = plt.subplots(1, 2, figsize=(13, 5.5))
        moving = False
        for axv, (i, j), name in ((axs[0], (0, 1), "top view (x-y)"), (axs[1], (0, 2), "side view (x-z)")):
            for item in first:
                axv.add_patch(_obstacle_patch(item, (i, j), lengths.get(item["id"], 4.0), color="tab:red", alpha=0.3))
            for item0, item1 in zip(first, last, strict=True):
                if np.any(item0["cd"]):  # moving: outline at the end too, and the path
                    moving = True
                    axv.add_patch(
                        _obstacle_patch(
                            item1, (i, j), lengths.get(item1["id"], 4.0), fill=False, ls="--", color="tab:red"
                        )
                    )
                    axv.plot([item0["c"][i], item1["c"][i]], [item0["c"][j], item1["c"][j]], ":", color="tab:red")
            for a in agents:
                pts = np.array(s["x"][a])
                axv.plot(pts[:, i], pts[:, j], color=colours[a], lw=1.0)
                axv.plot(pts[0, i], pts[0, j], "o", ms=3.5, color=colours[a])
                axv.plot(*(np.asarray(self.cfg.agent(a).final_goal)[[i, j]]), "x", ms=5, color=colours[a])
            axv.set_aspect("equal", adjustable="datalim")
            axv.set_xlabel("xyz"[i] + " [m]")
            axv.set_ylabel("xyz"[j] + " [m]")
            axv.set_title(name)
            axv.grid(alpha=0.3)
        marks: list[Any] = [
            plt.Line2D([], [], marker="o", ls="", color="0.3", label="start"),
            plt.Line2D([], [], marker="x", ls="", color="0.3", label="goal"),
        ]
        if first:
            marks.append(Circle((0, 0), 1, color="tab:red", alpha=0.3, label="obstacle at t = 0"))
        if moving:
            marks.append(plt.Line2D([], [], color="tab:red", ls="--", label="moving obstacle at the end"))
        fig.suptitle(scene_title(self.cfg, len(agents)), fontsize=11)
        agent_key(fig, axs[1], agents, colours, marks)
        fig.savefig(out / "views.png", dpi=110, bbox_inches="tight")
        plt.close(fig)

    def _obstacle_clearance(self, a: str) -> np.ndarray:
        """(len(t), n_obstacles) m: agent ``a``'s body centre to each obstacle's surface."""
        s, ks = self.s, self.ks
        t, xb = np.array(self.s["t"][a]), np.array(s["xb"][a])
        obs_t = np.array([s["obstacles"][k][0] for k in ks])
        rows = []
        for tt, p in zip(t, xb, strict=True):
            k = ks[int(np.argmin(np.abs(obs_t - tt)))]
            rows.append(surface_clearance(p[None, :], items_to_arrays(s["obstacles"][k][1]))[0])
        return np.array(rows)

    def clearance(self) -> None:
        """clearance.png: each drone's body centre to the obstacle surfaces (nearest, or each
        for a few), and between drones (each pair for a few; for many each drone's nearest
        neighbour, with the closest pairs named); the safety radii and contact marked."""
        s, out, agents, first, body, margin = self.s, self.out, self.agents, self.first, self.body, self.margin
        colours = self.colours
        panels = (["obstacles"] if first and self.ks else []) + (["agents"] if len(agents) > 1 else [])
        fig, axes = plt.subplots(len(panels) or 1, 1, figsize=(10, 3.6 * max(1, len(panels))), squeeze=False)
        few = len(agents) <= 4
        for ax, panel in zip(axes[:, 0], panels, strict=False):
            if panel == "obstacles":
                for a in agents:
                    t, clear = np.array(s["t"][a]), self._obstacle_clearance(a)
                    if few and len(first) <= 3:
                        for n, item in enumerate(first):
                            ls = ("-", "--", ":")[n]
                            ax.plot(t, clear[:, n], ls, color=colours[a], label=f"{a} to {item['id']}")
                    else:
                        ax.plot(t, clear.min(axis=1), color=colours[a], lw=1.0)
                a0 = agents[0]
                ax.axhline(body[a0] + margin[a0], color="k", lw=1, label="safety radius (body + margin)")
                ax.set_title("body centre to the nearest obstacle surface" if not few or len(first) > 3
                             else "body centre to each obstacle surface", fontsize=10)  # fmt: skip
            else:
                pairs = self._pair_distances()
                closest = sorted(pairs, key=lambda p: float(pairs[p][1].min()))[:WORST]
                if few:
                    for a, b in pairs:
                        t, d = pairs[(a, b)]
                        ax.plot(t, d, color=colours[a], lw=1.0, label=f"{a} to {b}")
                else:
                    nearest = self._nearest(pairs)
                    for a in agents:
                        if a in nearest:
                            ax.plot(*nearest[a], color=colours[a], lw=0.8, alpha=0.8)
                    for n, (a, b) in enumerate(closest):
                        t, d = pairs[(a, b)]
                        i = int(np.argmin(d))
                        ax.plot(t[i], d[i], MARKS[n], color="k", ms=6, ls="",
                                label=f"{a} and {b}: {d[i]:.3f} m at t = {t[i]:.2f} s")  # fmt: skip
                a0 = agents[0]
                ax.axhline(2 * body[a0] + margin[a0], color="k", lw=1, ls="--", label="safety radius between drones")
                ax.set_title("between drones, body centre to body centre" + ("" if few else
                             " (each drone to its nearest neighbour)"), fontsize=10)  # fmt: skip
            touch = body[agents[0]] * (1 if panel == "obstacles" else 2)
            radii = "one body radius" if panel == "obstacles" else "two body radii"
            ax.axhline(touch, color="tab:red", lw=0.8, label=f"contact ({radii}, {touch:.3f} m)")
            ax.set_ylabel("distance [m]")
            ax.set_ylim(bottom=min(0.0, ax.get_ylim()[0]))
            ax.grid(alpha=0.3)
            if few or ax is not axes[0, 0]:
                ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
            else:  # the agents' key beside the first panel, with its lines
                agent_key(fig, ax, agents, colours, ax.get_legend_handles_labels()[0])
        if not panels:
            axes[0, 0].text(0.5, 0.5, "one drone, no obstacles: nothing to keep clear of", ha="center",
                            transform=axes[0, 0].transAxes)  # fmt: skip
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{scene_title(self.cfg, len(agents))}: clearance", fontsize=11)
        fig.savefig(out / "clearance.png", dpi=110, bbox_inches="tight")
        plt.close(fig)

    def _pair_distances(self) -> dict[tuple[str, str], tuple[np.ndarray, np.ndarray]]:
        """Every pair's body-centre distance [m] at their common measurement times [s]."""
        s, agents = self.s, self.agents
        out = {}
        for i, a in enumerate(agents):
            ta = np.array(s["t"][a])
            for b in agents[i + 1 :]:
                tb = np.array(s["t"][b])
                common = np.intersect1d(ta, tb)
                if len(common) == 0:
                    continue
                xa = np.array(s["xb"][a])[np.isin(ta, common)]
                xbb = np.array(s["xb"][b])[np.isin(tb, common)]
                out[(a, b)] = (common, np.linalg.norm(xa - xbb, axis=1))
        return out

    @staticmethod
    def _nearest(
        pairs: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]],
    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Each drone's distance [m] to its nearest neighbour over time [s]."""
        per: dict[str, dict[float, float]] = defaultdict(dict)
        for (a, b), (t, d) in pairs.items():
            for who in (a, b):
                row = per[who]
                for tt, dd in zip(t.tolist(), d.tolist(), strict=True):
                    if dd < row.get(tt, np.inf):
                        row[tt] = dd
        return {a: (np.array(sorted(r)), np.array([r[k] for k in sorted(r)])) for a, r in per.items()}

    def h_rows(self) -> None:
        """h.png: the barrier value h of the filter rows: each row for a few, each agent's
        lowest row for many (the lowest rows named)."""
        s, out, agents, colours = self.s, self.out, self.agents, self.colours
        fig, ax = plt.subplots(figsize=(10, 4.5))
        rows = [(a, rid, np.array(pts)) for a in agents for rid, pts in s["h"][a].items()]
        if not rows:
            ax.text(0.5, 0.5, "no per-row h in this recording", ha="center", transform=ax.transAxes)
        elif len(rows) <= LEGEND_MAX:
            styles = ("-", "--", ":", "-.")
            for n, (a, rid, arr) in enumerate(rows):
                ax.plot(arr[:, 0], arr[:, 1], styles[n % 4], color=colours[a], label=f"{a}: row {rid}")
        else:
            for a in agents:
                series: dict[float, float] = {}
                for pts in s["h"][a].values():
                    for t, h in pts:
                        series[t] = min(h, series.get(t, np.inf))
                if series:
                    ts = sorted(series)
                    ax.plot(ts, [series[t] for t in ts], color=colours[a], lw=0.8)
            worst = sorted(rows, key=lambda r: float(r[2][:, 1].min()))[:WORST]
            for n, (a, rid, arr) in enumerate(worst):
                i = int(np.argmin(arr[:, 1]))
                ax.plot(arr[i, 0], arr[i, 1], MARKS[n], color="k", ms=6, ls="",
                        label=f"{a}'s row {rid}: {arr[i, 1]:.3g} at t = {arr[i, 0]:.2f} s")  # fmt: skip
        ax.axhline(0.0, color="k", lw=0.8, label="h = 0: the edge of the collision cone")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("h [m^2/s]")
        many = len(rows) > LEGEND_MAX
        ax.set_title(
            f"{scene_title(self.cfg, len(agents))}: barrier h of "
            + ("each agent's lowest filter row" if many else "every filter row")
            + "\n(h >= 0: outside the cone; below 0 the filter steers back out, no contact by itself)",
            fontsize=10,
        )
        ax.grid(alpha=0.3)
        if many:
            agent_key(fig, ax, agents, colours, ax.get_legend_handles_labels()[0])
        else:
            ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
        fig.savefig(out / "h.png", dpi=110, bbox_inches="tight")
        plt.close(fig)

    def time_series(self) -> None:
        """speed.png and intervention.png (the filter's change of the command, in the units of
        the agents' command level)."""
        s, out, agents, colours = self.s, self.out, self.agents, self.colours
        levels = sorted({self.cfg.agent(a).command_level.value for a in agents})
        what = {
            "attitude": "the commanded force F [N, world] (attitude level: it becomes roll, pitch and thrust)",
            "rotors": "the four rotor thrusts [N] (rotor level)",
        }
        for name, key, ylabel, title in (
            ("speed.png", "speed", "speed [m/s]", "speed of each drone"),
            (
                "intervention.png",
                "iv",
                "|u - u_ref| [N]",
                "safety filter intervention |u - u_ref|; u: " + "; ".join(what.get(lv, lv) for lv in levels),
            ),
        ):
            fig, ax = plt.subplots(figsize=(10, 4))
            for a in agents:
                if key == "speed":
                    ax.plot(s["t"][a], s["speed"][a], color=colours[a], lw=0.9)
                elif s["iv"][a]:
                    arr = np.array(s["iv"][a])
                    ax.plot(arr[:, 0], arr[:, 1], color=colours[a], lw=0.9)
            ax.set_xlabel("t [s]")
            ax.set_ylabel(ylabel)
            ax.set_title(f"{scene_title(self.cfg, len(agents))}:\n{title}", fontsize=10)
            ax.grid(alpha=0.3)
            agent_key(fig, ax, agents, colours)
            fig.savefig(out / name, dpi=110, bbox_inches="tight")
            plt.close(fig)

    def summary(self) -> None:
        """summary.md: the metrics, one row per agent, each table with its metrics' meanings,
        and the figures."""
        cfg, out, metrics, run_dir = self.cfg, self.out, self.metrics, self.run_dir
        lines = [f"# Run report: {scene_title(cfg, len(self.agents))}", "", f"Run folder: `{run_dir}`", ""]
        lines.append(markdown_table(["metric", "value"], [[k, cell(metrics.get(k), k)] for k in SUMMARY_KEYS]))
        lines += ["", *(f"* {n}" for n in notes(SUMMARY_KEYS)), ""]
        cols = ("reached_goal", "time_to_goal_s", "path_length_m", "straight_line_m", "min_h", "negative_h_ticks",
                "min_row_h", "infeasible_ticks")  # fmt: skip
        rows = [[a, *(cell(m.get(k), k) for k in cols)] for a, m in metrics.get("agents", {}).items()]
        lines.append(markdown_table(["agent", *cols], rows))
        lines += ["", *(f"* {n}" for n in notes(cols)), "* straight_line_m: distance from start to goal [m]", ""]
        for png in ("trajectory_3d", "views", "clearance", "h", "speed", "intervention"):
            lines += [f"![{png}]({png}.png)", ""]
        (out / "summary.md").write_text("\n".join(lines))


def make_report(run_dir: Path) -> Path:
    """Draw the report of the run in ``run_dir``; returns its folder (``run_dir/report``)."""
    return Report(run_dir).write()
