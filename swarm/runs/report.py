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
        fig = plt.figure(figsize=(8, 6))
        ax = fig.add_subplot(projection="3d")
        allpts = [np.array(s["x"][a]) for a in agents]
        lo = np.vstack(allpts).min(axis=0) - 0.2
        hi = np.vstack(allpts).max(axis=0) + 0.2
        for a, pts in zip(agents, allpts, strict=True):
            ax.plot(pts[:, 0], pts[:, 1], pts[:, 2], label=a)
            ax.scatter(*pts[0], marker="o", s=20)
            ax.scatter(*cfg.agent(a).final_goal, marker="x", s=40)
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
        ax.set_title(f"{cfg.name}: 3-D trajectories (o start, x goal; obstacles at t = 0)")
        ax.legend(loc="upper left", fontsize=7)
        fig.savefig(out / "trajectory_3d.png", dpi=110)
        plt.close(fig)

    def views(self) -> None:
        """views.png: top and side views, obstacles to scale at the start and the end."""
        s, out, agents, lengths, first, last = self.s, self.out, self.agents, self.lengths, self.first, self.last
        fig, axs = plt.subplots(1, 2, figsize=(12, 5))
        for axv, (i, j), name in ((axs[0], (0, 1), "top view (x-y)"), (axs[1], (0, 2), "side view (x-z)")):
            for item in first:
                axv.add_patch(_obstacle_patch(item, (i, j), lengths.get(item["id"], 4.0), color="tab:red", alpha=0.3))
            for item0, item1 in zip(first, last, strict=True):
                if np.any(item0["cd"]):  # moving: outline at the end too, and the path
                    axv.add_patch(
                        _obstacle_patch(
                            item1, (i, j), lengths.get(item1["id"], 4.0), fill=False, ls="--", color="tab:red"
                        )
                    )
                    axv.plot([item0["c"][i], item1["c"][i]], [item0["c"][j], item1["c"][j]], ":", color="tab:red")
            for a in agents:
                pts = np.array(s["x"][a])
                axv.plot(pts[:, i], pts[:, j], label=a)
                axv.plot(pts[0, i], pts[0, j], "o", ms=4, color="k")
            axv.set_aspect("equal", adjustable="datalim")
            axv.set_xlabel("xyz"[i] + " [m]")
            axv.set_ylabel("xyz"[j] + " [m]")
            axv.set_title(f"{name}; obstacles at t = 0 (dashed: at the end)")
            axv.grid(alpha=0.3)
        axs[0].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / "views.png", dpi=110)
        plt.close(fig)

    def clearance(self) -> None:
        """clearance.png: body centre to every obstacle surface, and between agents."""
        s, out, agents, ks, first, body, margin = (
            self.s,
            self.out,
            self.agents,
            self.ks,
            self.first,
            self.body,
            self.margin,
        )
        fig, ax = plt.subplots(figsize=(9, 4.5))
        for a in agents:
            t = np.array(s["t"][a])
            xb = np.array(s["xb"][a])
            if ks:
                rows = []
                for tt, p in zip(t, xb, strict=True):
                    k = min(ks, key=lambda kk: abs(s["obstacles"][kk][0] - tt))
                    rows.append(surface_clearance(p[None, :], items_to_arrays(s["obstacles"][k][1]))[0])
                clear = np.array(rows)
                for n, item in enumerate(first):
                    ax.plot(t, clear[:, n], label=f"{a} to {item['id']}")
        for i, a in enumerate(agents):
            for b in agents[i + 1 :]:
                ta, tb = np.array(s["t"][a]), np.array(s["t"][b])
                common = np.intersect1d(ta, tb)
                xa = np.array(s["xb"][a])[np.isin(ta, common)]
                xbb = np.array(s["xb"][b])[np.isin(tb, common)]
                ax.plot(common, np.linalg.norm(xa - xbb, axis=1), "--", label=f"{a} to {b} (centres)")
        if agents:
            a0 = agents[0]
            if first:
                ax.axhline(body[a0] + margin[a0], color="k", lw=1, label="safety radius to a surface (body + margin)")
            if len(agents) > 1:
                ax.axhline(2 * body[a0] + margin[a0], color="k", lw=1, ls="--", label="safety radius between agents")
            ax.axhline(0.0, color="tab:red", lw=0.8)
        ax.set_xlabel("t [s]")
        ax.set_ylabel("distance [m]")
        ax.set_title("Clearance: body centre to obstacle surface, and between agents")
        ax.set_ylim(bottom=min(0.0, ax.get_ylim()[0]))
        ax.legend(fontsize=7, ncol=2)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(out / "clearance.png", dpi=110)
        plt.close(fig)

    def h_rows(self) -> None:
        """h.png: the barrier value of every filter row."""
        s, out, agents = self.s, self.out, self.agents
        fig, ax = plt.subplots(figsize=(9, 4.5))
        for a in agents:
            for rid, pts in s["h"][a].items():
                arr = np.array(pts)
                ax.plot(arr[:, 0], arr[:, 1], label=f"{a}: row {rid}")
        if not any(s["h"][a] for a in agents):
            ax.text(0.5, 0.5, "no per-row h in this recording", ha="center", transform=ax.transAxes)
        else:
            ax.legend(fontsize=7, ncol=2)
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xlabel("t [s]")
        ax.set_ylabel("h [m^2/s]")
        ax.set_title("Barrier value h of every filter row (h >= 0: outside the collision cone)")
        ax.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(out / "h.png", dpi=110)
        plt.close(fig)

    def time_series(self) -> None:
        """speed.png and intervention.png."""
        s, out, agents = self.s, self.out, self.agents
        for name, key, ylabel, title in (
            ("speed.png", "speed", "speed [m/s]", "Speed of each agent"),
            ("intervention.png", "iv", "|u - u_ref| [N]", "Safety filter intervention |u - u_ref|"),
        ):
            fig, ax = plt.subplots(figsize=(9, 4))
            for a in agents:
                if key == "speed":
                    ax.plot(s["t"][a], s["speed"][a], label=a)
                elif s["iv"][a]:
                    arr = np.array(s["iv"][a])
                    ax.plot(arr[:, 0], arr[:, 1], label=a)
            ax.set_xlabel("t [s]")
            ax.set_ylabel(ylabel)
            ax.set_title(title)
            ax.legend(fontsize=7)
            ax.grid(alpha=0.3)
            fig.tight_layout()
            fig.savefig(out / name, dpi=110)
            plt.close(fig)

    def summary(self) -> None:
        """summary.md: the metrics, one row per agent, and the figures."""
        cfg, out, metrics, run_dir = self.cfg, self.out, self.metrics, self.run_dir
        lines = [f"# Run report: {cfg.name}", "", f"Run folder: `{run_dir}`", "", "| metric | value |", "|---|---|"]
        for k in SUMMARY_KEYS:
            lines.append(f"| {k} | {metrics.get(k)} |")
        lines += [
            "",
            "| agent | reached goal | time to goal [s] | path [m] | straight line [m] | min exact h | ticks h < 0 "
            "| min row h | infeasible ticks |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for a, m in metrics.get("agents", {}).items():
            lines.append(
                f"| {a} | {m['reached_goal']} | {m['time_to_goal_s']} | {m['path_length_m']:.2f} | "
                f"{m['straight_line_m']:.2f} | {m['min_h']} | {m['negative_h_ticks']} | {m['min_row_h']} | "
                f"{m['infeasible_ticks']} |"
            )
        lines.append("")
        for png in ("trajectory_3d", "views", "clearance", "h", "speed", "intervention"):
            lines += [f"![{png}]({png}.png)", ""]
        (out / "summary.md").write_text("\n".join(lines))


def make_report(run_dir: Path) -> Path:
    """Draw the report of the run in ``run_dir``; returns its folder (``run_dir/report``)."""
    return Report(run_dir).write()
