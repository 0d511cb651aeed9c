"""Generated scenarios: swaps (circle, sphere, random, formations) and scenes among walls
(doorway, corridor, trap, forest, pillars), as raw config dicts."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarm.rotation import FloatArray


@dataclass(frozen=True)
class SwapSettings:
    """What every generated swap scenario shares. Units in the names."""

    altitude_m: float = 1.0  # circle and random sets: flight altitude; sphere: lowest point + 0.5 m
    speed_mps: float = 0.8  # target speed along the straight path
    perturb_m: float = 0.0  # uniform random offset (per axis, in the swap's plane or space) of starts and goals
    rotation_rad: float = 0.0  # turn the whole pattern about the vertical
    seed: int = 0
    control_hz: float = 100.0
    physics_hz: float = 300.0
    mode: str = "lockstep"
    # agents: each agent publishes its state and hears its neighbours' (the mission's shape, by the
    # relay's bundles on one machine); world: the world's roster of every drone, as motion capture gives it
    neighbours: str = "agents"
    # world.realism: the lab's imperfections (downwash, drag, motors, wind, motion capture, links),
    # or ideal: the perfect world
    realism: str = "crazyflie_lab"
    sensing_radius_m: float = 2.5
    duration_s: float | None = None  # default: 2.5 x the longest straight path / speed + 5 s
    # 1/s and m/s: the filter's class-K gain and velocity buffer (the default buffer, written out).
    # Twice the paper's gain takes crowds from rest to their goals sooner with about as many
    # least-violation ticks (EXPERIMENTS.md section 4)
    gamma: float = 2.0
    buffer_mps: float = 0.1


def _scenario(name: str, starts: FloatArray, goals: FloatArray, s: SwapSettings, *, planar: bool) -> dict:
    rng = np.random.default_rng(s.seed)
    if s.perturb_m > 0:
        d = 2 if planar else 3
        starts, goals = starts.copy(), goals.copy()
        starts[:, :d] += rng.uniform(-s.perturb_m, s.perturb_m, (len(starts), d))
        goals[:, :d] += rng.uniform(-s.perturb_m, s.perturb_m, (len(goals), d))
    longest = float(np.linalg.norm(goals - starts, axis=1).max()) if len(starts) else 0.0
    duration = s.duration_s or round(2.5 * longest / s.speed_mps + 5.0, 1)
    agents = [
        {"id": f"cf{i + 1}", "start": [round(float(c), 6) for c in a], "goal": [round(float(c), 6) for c in b]}
        for i, (a, b) in enumerate(zip(starts, goals, strict=True))
    ]
    return {
        "version": 1,
        "name": name,
        "seed": s.seed,
        "duration_s": duration,
        "goal_tolerance_m": 0.15,
        "time": {"mode": s.mode, "physics_hz": s.physics_hz, "control_hz": s.control_hz},
        "neighbours": {"source": s.neighbours},
        "world": {"realism": s.realism},
        "defaults": {
            "speed_mps": s.speed_mps,
            "command_level": "attitude",
            "filter": {
                "kind": "c3bf",
                "gamma": s.gamma,
                "buffer_mps": s.buffer_mps,
                "rho": 1.0,
                "sensing_radius_m": s.sensing_radius_m,
            },
        },
        "agents": agents,
    }


def _turn(points: FloatArray, rotation_rad: float) -> FloatArray:
    c, si = math.cos(rotation_rad), math.sin(rotation_rad)
    out = points.copy()
    out[:, 0], out[:, 1] = c * points[:, 0] - si * points[:, 1], si * points[:, 0] + c * points[:, 1]
    return out


def circle_swap(n: int, radius_m: float = 2.0, settings: SwapSettings | None = None, name: str | None = None) -> dict:
    """A raw scenario (as :func:`swarm.config.resolve` takes it): ``n`` agents on a
    horizontal circle, each flying to the antipodal point. With no perturbation and no
    rotation the swap is exactly symmetric (every path crosses the centre)."""
    s = settings or SwapSettings()
    th = 2 * math.pi * np.arange(n) / n
    starts = np.column_stack([radius_m * np.cos(th), radius_m * np.sin(th), np.full(n, s.altitude_m)])
    starts = _turn(starts, s.rotation_rad)
    goals = starts * [-1.0, -1.0, 1.0]
    return _scenario(name or f"circle_{n}", starts, goals, s, planar=True)


def sphere_swap(n: int, radius_m: float = 2.0, settings: SwapSettings | None = None, name: str | None = None) -> dict:
    """``n`` agents on a sphere (Fibonacci lattice, so evenly spread), each flying to the
    antipodal point through the centre. The sphere's lowest point is ``altitude_m`` +
    0.5 m up."""
    s = settings or SwapSettings()
    i = np.arange(n) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / n)
    azim = math.pi * (1.0 + 5**0.5) * i
    unit = np.column_stack([np.sin(polar) * np.cos(azim), np.sin(polar) * np.sin(azim), np.cos(polar)])
    centre = np.array([0.0, 0.0, s.altitude_m + 0.5 + radius_m])
    starts = _turn(centre + radius_m * unit, s.rotation_rad)
    goals = 2 * centre - starts
    return _scenario(name or f"sphere_{n}", starts, goals, s, planar=False)


def random_swap(
    n: int,
    density_per_m2: float = 0.5,
    settings: SwapSettings | None = None,
    name: str | None = None,
    min_spacing_m: float = 0.5,
) -> dict:
    """``n`` agents with random starts and random goals (seeded) in a square at one
    altitude whose side makes ``n / side^2 = density_per_m2``; starts are at least
    ``min_spacing_m`` apart, and so are goals."""
    s = settings or SwapSettings()
    side = math.sqrt(n / density_per_m2)
    rng = np.random.default_rng(s.seed)

    def spaced() -> FloatArray:
        pts: list[FloatArray] = []
        for _ in range(200 * n):
            p = rng.uniform(-side / 2, side / 2, 2)
            if all(np.linalg.norm(p - q) >= min_spacing_m for q in pts):
                pts.append(p)
                if len(pts) == n:
                    return np.column_stack([np.array(pts), np.full(n, s.altitude_m)])
        raise ValueError(
            f"random_swap: cannot place {n} agents {min_spacing_m} m apart at {density_per_m2} per m^2; "
            "lower the density"
        )

    starts = spaced()
    goals = spaced()
    return _scenario(name or f"random_{n}", starts, goals, s, planar=True)


def sphere_field(
    n_spheres: int = 8,
    settings: SwapSettings | None = None,
    name: str | None = None,
    *,
    length_m: float = 7.0,
    half_width_m: float = 1.0,
    radius_range_m: tuple[float, float] = (0.15, 0.3),
    clear_m: float = 0.8,
) -> dict:
    """One drone at rest at (0, 0, altitude), its goal ``length_m`` ahead along x, and
    ``n_spheres`` static spheres (seeded radii in ``radius_range_m``) scattered in the box
    x in [1, length - 1], |y| <= half_width, |z - altitude| <= 0.5 m, none within
    ``clear_m`` of the start or the goal."""
    s = settings or SwapSettings()
    rng = np.random.default_rng(s.seed)
    start = np.array([0.0, 0.0, s.altitude_m])
    goal = np.array([length_m, 0.0, s.altitude_m])
    centres: list[FloatArray] = []
    radii: list[float] = []
    for _ in range(1000 * max(n_spheres, 1)):
        if len(centres) == n_spheres:
            break
        c = np.array(
            [
                rng.uniform(1.0, length_m - 1.0),
                rng.uniform(-half_width_m, half_width_m),
                s.altitude_m + rng.uniform(-0.5, 0.5),
            ]
        )
        r = float(rng.uniform(*radius_range_m))
        if min(np.linalg.norm(c - start), np.linalg.norm(c - goal)) - r >= clear_m:
            centres.append(c)
            radii.append(r)
    raw = _scenario(name or f"sphere_field_{n_spheres}", start[None], goal[None], s, planar=True)
    raw["obstacles"] = [
        {"id": f"s{i}", "shape": "sphere", "center": [round(float(v), 6) for v in c], "radius_m": round(r, 6)}
        for i, (c, r) in enumerate(zip(centres, radii, strict=True))
    ]
    return raw


def formation(
    n: int = 4,
    spacing_m: float = 0.5,
    settings: SwapSettings | None = None,
    name: str | None = None,
    *,
    run_m: float = 3.0,
    spread_m: float = 1.5,
    start_speed_mps: float | None = None,
) -> dict:
    """``n`` drones side by side along y, ``spacing_m`` apart, all with the same velocity
    along x (``start_speed_mps``, default the target speed), then diverging goals:
    ``run_m`` ahead and fanned out ``spread_m`` per place from the middle, so every
    neighbour pair starts at zero relative velocity and ends up apart."""
    s = settings or SwapSettings()
    y = (np.arange(n) - (n - 1) / 2) * spacing_m
    starts = np.column_stack([np.zeros(n), y, np.full(n, s.altitude_m)])
    goals = np.column_stack([np.full(n, run_m), y + (np.arange(n) - (n - 1) / 2) * spread_m, np.full(n, s.altitude_m)])
    raw = _scenario(name or f"formation_{n}", starts, goals, s, planar=True)
    v0 = s.speed_mps if start_speed_mps is None else start_speed_mps
    for a in raw["agents"]:
        a["start_velocity"] = [v0, 0.0, 0.0]
    return raw


def pillar_swap(
    n: int = 8,
    radius_m: float = 2.0,
    pillar_radius_m: float = 0.3,
    settings: SwapSettings | None = None,
    name: str | None = None,
) -> dict:
    """:func:`circle_swap` around a vertical cylinder of ``pillar_radius_m`` at the centre."""
    raw = circle_swap(n, radius_m, settings, name or f"pillar_{n}")
    alt = (settings or SwapSettings()).altitude_m
    raw["obstacles"] = [
        {
            "id": "pillar",
            "shape": "cylinder",
            "center": [0.0, 0.0, alt],
            "axis": [0.0, 0.0, 1.0],
            "radius_m": pillar_radius_m,
            "length_m": 4.0,
        }
    ]
    return raw


# Scenes among walls (docs/design.md, "Reference paths"): walls are rows of touching vertical
# pillars, as a lab builds them from poles; every scene is planar at the settings' altitude.

PILLAR_LENGTH_M = 4.0  # physics length of a wall's pillars (the barrier treats them as infinite)


def _pillar(name: str, x: float, y: float, r: float, alt: float) -> dict:
    return {
        "id": name,
        "shape": "cylinder",
        "center": [round(x, 6), round(y, 6), alt],
        "axis": [0.0, 0.0, 1.0],
        "radius_m": r,
        "length_m": PILLAR_LENGTH_M,
    }


def _abreast(x_m: float, y_m: np.ndarray, alt_m: float) -> FloatArray:
    """Points (k, 3) [m, world] at ``x_m``, each ``y_m`` (k,), at altitude ``alt_m``."""
    return np.column_stack([np.full(len(y_m), x_m), y_m, np.full(len(y_m), alt_m)])


def _wall(prefix: str, a: tuple[float, float], b: tuple[float, float], r: float, alt: float) -> list[dict]:
    """Touching pillars of radius ``r`` [m] whose surfaces span the segment from ``a`` to
    ``b`` [m] (centres ``2 r`` apart, the first and last ``r`` inside the ends)."""
    p, q = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    length = float(np.linalg.norm(q - p))
    k = max(1, round(length / (2 * r)))
    u = (q - p) / max(length, 1e-9)
    step = (length - 2 * r) / max(k - 1, 1)
    centres = [p + u * (r + i * step) for i in range(k)]
    return [_pillar(f"{prefix}{i}", float(c[0]), float(c[1]), r, alt) for i, c in enumerate(centres)]


def doorway(
    n: int = 6,
    gap_m: float = 0.8,
    settings: SwapSettings | None = None,
    name: str | None = None,
    *,
    spacing_m: float = 0.6,
    distance_m: float = 3.0,
    half_width_m: float = 4.0,
    pillar_radius_m: float = 0.15,
) -> dict:
    """``n`` drones abreast ``spacing_m`` apart, ``distance_m`` before a wall across their
    way (along y, ``half_width_m`` each side) with one doorway ``gap_m`` wide between its
    pillars' surfaces; each goal is its start mirrored through the doorway's centre, so
    every straight line runs through the doorway."""
    s = settings or SwapSettings()
    y = (np.arange(n) - (n - 1) / 2) * spacing_m
    starts, goals = _abreast(-distance_m, y, s.altitude_m), _abreast(distance_m, -y, s.altitude_m)
    raw = _scenario(name or f"doorway_{n}", starts, goals, s, planar=True)
    half = gap_m / 2
    raw["obstacles"] = _wall("wall_l", (0.0, half), (0.0, half_width_m), pillar_radius_m, s.altitude_m) + _wall(
        "wall_r", (0.0, -half), (0.0, -half_width_m), pillar_radius_m, s.altitude_m
    )
    return raw


def corridor(
    n_per_side: int = 4,
    width_m: float = 0.5,
    settings: SwapSettings | None = None,
    name: str | None = None,
    *,
    length_m: float = 2.0,
    spacing_m: float = 0.6,
    distance_m: float = 3.0,
    half_width_m: float = 3.0,
    pillar_radius_m: float = 0.15,
) -> dict:
    """Two opposing flows of ``n_per_side`` drones through one corridor along x, ``length_m``
    long and ``width_m`` wide between its pillars' surfaces (too narrow for two drones side
    by side with their clearance): a wall across the way at each end (``half_width_m``
    each side) opens into it. Each flow starts abreast ``distance_m`` from the middle and
    flies to the other flow's starts."""
    s = settings or SwapSettings()
    y = (np.arange(n_per_side) - (n_per_side - 1) / 2) * spacing_m
    left, right = _abreast(-distance_m, y, s.altitude_m), _abreast(distance_m, y, s.altitude_m)
    starts = np.vstack([left, right])
    goals = np.vstack([right[::-1], left[::-1]])
    raw = _scenario(name or f"corridor_{n_per_side}x2", starts, goals, s, planar=True)
    r, alt, half, x0 = pillar_radius_m, s.altitude_m, width_m / 2, length_m / 2
    big = 2.0 * r  # the end walls' pillars: fewer rows for the filter
    raw["obstacles"] = (
        _wall("side_l", (-x0, half + 0.0), (x0, half), r, alt)
        + _wall("side_r", (-x0, -half), (x0, -half), r, alt)
        + _wall("end_wl", (-x0 - big, half), (-x0 - big, half_width_m), big, alt)
        + _wall("end_wr", (-x0 - big, -half), (-x0 - big, -half_width_m), big, alt)
        + _wall("end_el", (x0 + big, half), (x0 + big, half_width_m), big, alt)
        + _wall("end_er", (x0 + big, -half), (x0 + big, -half_width_m), big, alt)
    )
    for o in raw["obstacles"]:  # each wall's pillars stand off its line by their radius, away from the way
        side = 1.0 if o["center"][1] > 0 else -1.0
        if o["id"].startswith("side"):
            o["center"][1] = round(o["center"][1] + side * o["radius_m"], 6)
    return raw


def trap(
    settings: SwapSettings | None = None,
    name: str | None = None,
    *,
    width_m: float = 2.0,
    depth_m: float = 2.0,
    distance_m: float = 3.0,
    pillar_radius_m: float = 0.15,
) -> dict:
    """One drone at rest inside a U-shaped wall (``width_m`` across, ``depth_m`` deep, its
    back across the x axis at x = 0, open towards +x) with its goal behind the U's back,
    ``distance_m`` away: the straight line runs into the back, and the way out is the
    opening on the far side and round an arm (the classic local minimum)."""
    s = settings or SwapSettings()
    start = np.array([[depth_m / 2, 0.0, s.altitude_m]])
    goal = np.array([[-distance_m, 0.0, s.altitude_m]])
    raw = _scenario(name or "trap", start, goal, s, planar=True)
    r, alt, w = pillar_radius_m, s.altitude_m, width_m / 2
    raw["obstacles"] = (
        _wall("back", (-r, -w - r), (-r, w + r), r, alt)
        + _wall("arm_l", (r, w + r), (depth_m, w + r), r, alt)
        + _wall("arm_r", (r, -w - r), (depth_m, -w - r), r, alt)
    )
    return raw


def forest(
    n: int = 4,
    density_per_m2: float = 0.3,
    settings: SwapSettings | None = None,
    name: str | None = None,
    *,
    depth_m: float = 4.0,
    spacing_m: float = 0.8,
    distance_m: float = 3.5,
    radius_range_m: tuple[float, float] = (0.1, 0.25),
    gap_m: float = 0.7,
) -> dict:
    """``n`` drones abreast ``spacing_m`` apart crossing a forest: random vertical pillars
    (seeded radii in ``radius_range_m``) at ``density_per_m2`` over a band ``depth_m`` deep
    across their way, as wide as the flight, every two pillars at least ``gap_m`` apart
    between surfaces (so a way through exists). Goals straight across, ``2 distance_m``
    away."""
    s = settings or SwapSettings()
    rng = np.random.default_rng(s.seed)
    y = (np.arange(n) - (n - 1) / 2) * spacing_m
    starts, goals = _abreast(-distance_m, y, s.altitude_m), _abreast(distance_m, y, s.altitude_m)
    raw = _scenario(name or f"forest_{n}", starts, goals, s, planar=True)
    half_w = float(np.abs(y).max()) + 1.5
    count = round(density_per_m2 * depth_m * 2 * half_w)
    placed: list[tuple[float, float, float]] = []
    for _ in range(2000 * max(count, 1)):
        if len(placed) == count:
            break
        x, yy, r = rng.uniform(-depth_m / 2, depth_m / 2), rng.uniform(-half_w, half_w), rng.uniform(*radius_range_m)
        if all(math.hypot(x - px, yy - py) >= r + pr + gap_m for px, py, pr in placed):
            placed.append((float(x), float(yy), float(r)))
    raw["obstacles"] = [_pillar(f"tree{i}", x, yy, round(r, 4), s.altitude_m) for i, (x, yy, r) in enumerate(placed)]
    return raw


def default_radius(kind: str, n: int) -> float:
    """Swap radius [m] for ``n`` agents: 2 m, growing so that neighbours start >= 0.6 m apart."""
    if kind == "sphere":
        return max(2.0, math.sqrt(n * 0.6**2 / (4 * math.pi)) * 2)
    return max(2.0, n * 0.6 / (2 * math.pi))


def generate(
    kind: str,
    n: int,
    settings: SwapSettings | None = None,
    *,
    radius_m: float | None = None,
    density: float | None = None,
    gap_m: float | None = None,
) -> dict:
    """A raw scenario of ``kind``: ``circle``, ``sphere`` (``radius_m``, default growing
    with ``n``), ``random`` (``density`` agents per m^2), ``doorway`` (``gap_m`` wide),
    ``corridor`` (``n`` per side, ``gap_m`` wide), ``trap`` (one drone) or ``forest``
    (``density`` pillars per m^2). None: each generator's default."""
    s = settings or SwapSettings()
    if kind in ("circle", "sphere"):
        return (circle_swap if kind == "circle" else sphere_swap)(n, radius_m or default_radius(kind, n), s)
    if kind == "random":
        return random_swap(n, 0.5 if density is None else density, s)
    if kind == "doorway":
        return doorway(n, 0.8 if gap_m is None else gap_m, s)
    if kind == "corridor":
        return corridor(n, 0.5 if gap_m is None else gap_m, s)
    if kind == "trap":
        return trap(s)
    if kind == "forest":
        return forest(n, 0.3 if density is None else density, s)
    raise ValueError(f"scenario kind {kind!r}: choose circle, sphere, random, doorway, corridor, trap or forest")


@dataclass(frozen=True)
class Room:
    """The volume a generated scene must fit (``swarm scenario --room``): ``size_m`` its x, y
    and z extents [m], centred on the origin in x and y, floor at z = 0; starts, goals and
    waypoints kept ``wall_m`` inside its walls and ceiling and, when squeezed down, no lower
    than ``low_m``. The default is a motion-capture lab's flight volume."""

    size_m: tuple[float, float, float] = (8.0, 8.0, 3.0)
    wall_m: float = 0.3
    low_m: float = 0.5


def fit_room(raw: dict, room: Room) -> dict:
    """``raw`` with its agents' starts, goals and waypoints inside ``room``: heights above its
    ceiling less ``wall_m`` squeezed (linearly, keeping their order) between ``low_m`` (or
    the lowest, if lower) and it. Raises ValueError, saying how to fix it, when the scene
    is wider than the room (horizontally nothing is moved)."""
    agents = raw["agents"]
    keys = [k for k in ("start", "goal") if any(k in a for a in agents)]
    pts = np.array([p for a in agents for p in [*(a[k] for k in keys if k in a), *a.get("waypoints", [])]], dtype=float)
    half = np.array(room.size_m[:2]) / 2 - room.wall_m
    wide = np.abs(pts[:, :2]).max(axis=0)
    if np.any(wide > half):
        raise ValueError(
            f"the scene spans x and y to +-{wide[0]:.2f}, +-{wide[1]:.2f} m, wider than the room "
            f"({room.size_m[0]:g} x {room.size_m[1]:g} m less {room.wall_m:g} m from each wall): "
            "give a larger --room or a smaller --radius (or a higher --density)"
        )
    top = room.size_m[2] - room.wall_m
    z_lo, z_hi = float(pts[:, 2].min()), float(pts[:, 2].max())
    if z_hi <= top:
        return raw
    low = min(z_lo, room.low_m)
    if top <= low:
        raise ValueError(f"the room is {room.size_m[2]:g} m high: too low to fly in (give a higher --room)")

    def squeeze(p: list[float]) -> list[float]:
        z = low + (p[2] - z_lo) * (top - low) / (z_hi - z_lo) if z_hi > z_lo else top
        return [p[0], p[1], round(float(z), 6)]

    out = dict(raw)
    out["agents"] = [
        {
            **a,
            **{k: squeeze(a[k]) for k in keys if k in a},
            **({"waypoints": [squeeze(w) for w in a["waypoints"]]} if "waypoints" in a else {}),
        }
        for a in agents
    ]
    return out
