"""A reciprocal velocity-obstacle safety filter for c3swarm (``filter: {kind: c3swarm_vo.vo}``).

Each tick it turns the reference thrust vector into the velocity it would give after ``react_s``
seconds, and moves that velocity out of every obstacle's and neighbour's velocity obstacle
truncated at ``horizon_s`` seconds: for each row the smallest change ``u`` of the relative
velocity that leaves the obstacle (van den Berg et al., "Reciprocal n-body collision avoidance",
ISRR 2011: RVO2-3D's ``Agent::computeNewVelocity``) gives the half-space
``(v - (v_now + share u)) . n >= 0``; a neighbour takes ``share`` of the change, an obstacle all of it.
The velocity is projected onto the half-spaces in turn (``passes`` sweeps), turned back into a
thrust vector and moved into the airframe's limits (``into_limits``). No QP: this is a plain projection filter,
shown beside the C3BF-QP in ``swarm compare``.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from swarm.safety.external import FilterInput, FilterOutput, FilterSpec, into_limits
from swarm.safety.filter import FilterStatus

E3 = np.array([0.0, 0.0, 1.0])


class Options(BaseModel):
    """``filter.options`` of ``c3swarm_vo.vo``."""

    model_config = ConfigDict(extra="forbid")

    horizon_s: float = Field(1.5, gt=0)  # s: the velocity obstacle's time horizon
    react_s: float = Field(0.3, gt=0)  # s: the velocity change is asked of this much time (acceleration = dv / react_s)
    share: float = Field(0.5, gt=0, le=1)  # the share of a pair's avoidance each drone takes (0.5: reciprocal)
    passes: int = Field(3, ge=1, le=20)  # sweeps of projection onto the half-spaces


def velocity_change(
    p: np.ndarray, w: np.ndarray, r: float, horizon_s: float, step_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """The smallest change ``u`` [m/s] of the relative velocity ``w`` (own less other's) out of the
    velocity obstacle of an obstacle at relative position ``p`` [m] (other's less own) with
    combined radius ``r`` [m], truncated at ``horizon_s``; and the outward normal ``n`` of the
    obstacle's boundary there. Inside the radius: out within ``step_s``. (RVO2-3D's rule.)"""
    dist2 = float(p @ p)
    if dist2 > r * r:
        wc = w - p / horizon_s  # from the cut-off sphere's centre
        wl2 = float(wc @ wc)
        dot = float(wc @ p)
        if dot < 0.0 and dot * dot > r * r * wl2:  # on the cut-off sphere
            wl = np.sqrt(wl2)
            n = wc / wl if wl > 1e-12 else -p / np.sqrt(dist2)
            return (r / horizon_s - wl) * n, n
        a, b = dist2, float(p @ w)  # on the cone
        c = float(w @ w) - float(np.cross(p, w) @ np.cross(p, w)) / (dist2 - r * r)
        t = (b + np.sqrt(max(b * b - a * c, 0.0))) / a
        ww = w - t * p
        wl = float(np.linalg.norm(ww))
        n = ww / wl if wl > 1e-12 else -p / np.sqrt(dist2)
        return (r * t - wl) * n, n
    wc = w - p / step_s  # already inside: leave within a step
    wl = float(np.linalg.norm(wc))
    n = wc / wl if wl > 1e-12 else -p / max(np.sqrt(dist2), 1e-12)
    return (r / step_s - wl) * n, n


class VelocityObstacle:
    """The filter (see the module docstring); the attitude level only: ``u`` is the thrust
    vector F (3,) [N, world]."""

    levels = ("attitude",)
    Options = Options

    def __init__(self, spec: FilterSpec) -> None:
        self.spec = spec
        self.opt = spec.options if isinstance(spec.options, Options) else Options()
        self.r_own_m = spec.params.body_radius_m + spec.margin_m

    def filter(self, inp: FilterInput) -> FilterOutput:
        p, o = self.spec.params, self.opt
        m, g = p.mass_kg, p.g_mps2
        v = inp.v_b_w
        v_des = v + (inp.u_ref / m - g * E3) * o.react_s  # the reference's velocity after react_s
        planes = []
        for rows, share in ((inp.obstacles, 1.0), (inp.neighbours, o.share)):
            for i in range(len(rows.ids)):
                rel_p = rows.c_w[i] - inp.x_b_w
                rel_v = v - rows.v_w[i]
                ax = rows.axis_w[i]
                if ax.any():  # a cylinder: the problem across its axis
                    rel_p = rel_p - (rel_p @ ax) * ax
                    rel_v = rel_v - (rel_v @ ax) * ax
                u, n = velocity_change(rel_p, rel_v, rows.radius_m[i] + self.r_own_m, o.horizon_s, o.react_s)
                planes.append((v + share * u, n))
        vn = v_des
        for _ in range(o.passes):
            for point, n in planes:
                gap = float((vn - point) @ n)
                if gap < 0.0:
                    vn = vn - gap * n
        F = m * ((vn - v) / o.react_s + g * E3)
        return FilterOutput(into_limits(F, self.spec.limits), FilterStatus.OK)
