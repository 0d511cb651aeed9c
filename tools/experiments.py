"""Regenerate the measurements that EXPERIMENTS.md, the README and docs/benchmarks.md quote,
from the current code, into ``docs/experiments/`` (each data file stamped with the commit
and the settings that made it, ``stamp.json`` per part):

* ``paper``: every paper scenario under C3BF and HO-CBF, a report of each C3BF run;
* ``sweeps``: the obstacle-speed, approach-angle and gain sweeps;
* ``compare``: the README's table (``swarm compare`` on ``single_static_sphere.yaml``);
* ``liveness``: EXPERIMENTS.md section 4 (``tools.bench_liveness``, with ORCA);
* ``liveness_variants``: its variants (the paper's gain, horizon and contact allowances);
* ``faults``: docs/benchmarks.md's fault table (``tools.bench_faults``);
* ``filter``, ``swarm``, ``access``, ``scaling``: docs/benchmarks.md's filter, swarm,
  access-control and scaling tables (``tools.bench_filter``, ``tools.bench_swarm``,
  ``tools.bench_scaling``, with ``docs/scaling.png``): timings, so a rerun gives other
  figures within the machine's noise.

    python -m tools.experiments [--out runs/experiments] [--jobs 2] [--only PART ...] [--allow-dirty]
    python -m tools.experiments --only sweeps --only liveness --engine ray [--address HEAD:6379]

``--engine ray`` flies the sweeps' runs and the liveness benchmark's scenes as Ray tasks (on
the cluster at ``--address``, or a local one; ``docs/cluster.md``); the other parts are
single scenarios or timings of this machine and run here whatever the engine.

Each part's stamp names the commit the code ran from, taken when the tool starts; it refuses
to run from a tree with uncommitted code unless ``--allow-dirty`` (the stamp then says so).

Tables in the documents that quote a data file say so (``<!-- data: FILE -->`` above them);
``tests/unit/test_docs_figures.py`` checks that every number in such a table is in its file.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from swarm.config import load
from swarm.model import CommandLevel
from swarm.runs.compare import compare, markdown
from swarm.runs.launch import unpinned
from swarm.runs.report import make_report
from swarm.runs.sweep import parse_axes, sweep

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
DOCS = Path(__file__).resolve().parent.parent / "docs" / "experiments"

SWEEPS = {
    "speed": ["filter=c3bf,hocbf", "obstacle_speed=0.1,0.5,1,1.5,2,3"],
    "angle": ["filter=c3bf,hocbf", "obstacle_speed=1", "approach_angle_deg=0,45,90,135"],
    "gamma_c3bf": ["filter=c3bf", "obstacle_speed=1", "gamma=0.25,0.5,1,2,4"],
    "gamma_hocbf": ["filter=hocbf", "obstacle_speed=1", "gamma_ho=0.25,0.5,1,2,4"],
}


ROOT = Path(__file__).resolve().parent.parent


def source_state() -> dict[str, object]:
    """The commit the code runs from and whether the code's tree had uncommitted changes,
    taken before a part starts (a commit made while it runs does not relabel its data)."""
    git = ["git", "-C", str(ROOT)]
    commit = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    dirty = bool(
        subprocess.run(
            [*git, "status", "--porcelain", "--", "swarm", "agents", "world", "tools"], capture_output=True, text=True
        ).stdout.strip()
    )
    return {"commit": commit, "uncommitted_changes": dirty, "started": time.strftime("%Y-%m-%d %H:%M")}


SOURCE: dict[str, object] = {}
"""What :func:`source_state` said when this run of the tool started (set by ``__main__``)."""


@dataclass(frozen=True)
class Engine:
    """Where the sweeps' runs and the liveness scenes fly: ``local`` (a pool of ``--jobs``)
    or ``ray`` (the cluster at ``address``, or a local one)."""

    name: str = "local"
    address: str | None = None

    def flags(self) -> list[str]:
        """The same choice as a benchmark's command-line flags."""
        if self.name != "ray":
            return []
        return ["--engine", "ray", *(["--address", self.address] if self.address else [])]


ENGINE = Engine()
"""The engine this run of the tool was given (set by ``__main__``)."""


def stamp(part: str, **settings: object) -> None:
    """``docs/experiments/<part>.stamp.json``: the commit the part's data were made from
    (taken when the tool started), when it ended, and the settings."""
    info = {"part": part, **(SOURCE or source_state()), "made": time.strftime("%Y-%m-%d %H:%M"), **settings}
    (DOCS / f"{part}.stamp.json").write_text(json.dumps(info, indent=2) + "\n")


def compare_table(out: Path, jobs: int) -> None:
    """The README's table: one scenario, C3BF, HO-CBF and no filter, in the ideal world and in the
    Crazyflie lab's."""
    del jobs
    cfg = load(CONFIGS / "single_static_sphere.yaml")
    worlds = ["ideal", "crazyflie_lab"]
    rows = compare(cfg, ["c3bf", "hocbf", "none"], out / "compare", worlds)
    (DOCS / "compare.json").write_text(json.dumps(rows, indent=2))
    (DOCS / "compare.md").write_text(markdown(cfg.name, rows))
    stamp("compare", config="configs/single_static_sphere.yaml", filters=["c3bf", "hocbf", "none"], worlds=worlds)


def _tool_lines(module: str, args: list[str], dest: Path) -> None:
    """Run ``python -m module args`` and keep its JSON lines in ``dest``."""
    p = subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, cwd=ROOT, check=True)
    dest.write_text("".join(ln + "\n" for ln in p.stdout.splitlines() if ln.startswith("{")))


def liveness(out: Path, jobs: int) -> None:
    args = ["--seeds", "2", "--jobs", str(jobs)]
    _tool_lines("tools.bench_liveness", [*args, *ENGINE.flags()], DOCS / "liveness.jsonl")
    stamp("liveness", command=["python", "-m", "tools.bench_liveness", *args], engine=ENGINE.name)


LIVENESS_VARIANTS = {
    "gamma1": ["--gamma", "1"],
    "gamma1_r3": ["--gamma", "1", "--sensing-radius-m", "3"],
    "horizon2": ["--horizon-s", "2"],
    "contact075": ["--contact-s", "0.75"],
}
"""EXPERIMENTS.md section 4's variants of the liveness benchmark (without ORCA), each into
``liveness_<name>.jsonl``: the paper's gain, with its sensing radius, the horizon allowance
and the contact horizon."""


def liveness_variants(out: Path, jobs: int) -> None:
    del out
    for name, knobs in LIVENESS_VARIANTS.items():
        args = ["--seeds", "2", "--jobs", str(jobs), "--no-orca", *knobs]
        dest = DOCS / f"liveness_{name}.jsonl"
        _tool_lines("tools.bench_liveness", [*args, *ENGINE.flags()], dest)
        stamp(
            f"liveness_{name}",
            file=str(dest.relative_to(ROOT)),
            command=["python", "-m", "tools.bench_liveness", *args],
            engine=ENGINE.name,
        )


def liveness_lab(out: Path, jobs: int) -> None:
    """The liveness benchmark's points (section 4's: two seeds per perturbed scene) in the Crazyflie
    lab's world (``world.realism: crazyflie_lab``) and, from the same code, in the ideal world, side
    by side."""
    del out
    for realism, name in (
        ("crazyflie_lab", "liveness_lab"),
        ("ideal", "liveness_lab_ideal"),
        ("crazyflie_lab_bad_day", "liveness_bad_day"),
    ):
        args = ["--seeds", "2", "--jobs", str(jobs), "--no-orca", "--realism", realism]
        _tool_lines("tools.bench_liveness", [*args, *ENGINE.flags()], DOCS / f"{name}.jsonl")
        stamp(name, command=["python", "-m", "tools.bench_liveness", *args], engine=ENGINE.name)


LAB_AXES = ("noise", "gusts", "mass")
BAD_DAY_AXES = ("occlusion", "swap", "radio", "battery", "turbulence")
DELAY_AXES = ("latency", "jitter")
"""``tools.bench_imperfections``' axes: the lab's imperfections, the bad day's failures and the
loop's delays (each part its own file, table and plot)."""


def _imperfections(jobs: int, axes: tuple[str, ...], name: str) -> None:
    dest = DOCS / f"{name}.jsonl"
    args = ["--jobs", str(jobs), *(f"--axis={a}" for a in axes)]
    _tool_lines("tools.bench_imperfections", args, dest)
    subprocess.run([sys.executable, "-m", "tools.bench_imperfections", "--plot", str(dest)], cwd=ROOT, check=True)
    stamp(name, command=["python", "-m", "tools.bench_imperfections", *args])


def imperfections(out: Path, jobs: int) -> None:
    """Each imperfection alone, raised until contact (``tools.bench_imperfections``), and its plot."""
    del out
    _imperfections(jobs, LAB_AXES, "imperfections")


def imperfections_bad_day(out: Path, jobs: int) -> None:
    """Each failure of the lab's bad day alone, raised until contact, and its plot."""
    del out
    _imperfections(jobs, BAD_DAY_AXES, "imperfections_bad_day")


def imperfections_delay(out: Path, jobs: int) -> None:
    """The loop's delay alone, fixed and jittered, raised until contact (C3BF with and without its
    delay contract, HO-CBF, ORCA with the same delays), and its plot."""
    del out
    _imperfections(jobs, DELAY_AXES, "imperfections_delay")


def faults(out: Path, jobs: int) -> None:
    del jobs
    args = ["--out", str(out / "faults")]
    _tool_lines("tools.bench_faults", args, DOCS / "bench_faults.jsonl")
    stamp("faults", command=["python", "-m", "tools.bench_faults"])


def filter_bench(out: Path, jobs: int) -> None:
    del out, jobs
    _tool_lines("tools.bench_filter", [], DOCS / "bench_filter.jsonl")
    stamp("filter", command=["python", "-m", "tools.bench_filter"])


def swarm_bench(out: Path, jobs: int) -> None:
    del jobs
    args = ["--out", str(out / "bench_swarm")]
    _tool_lines("tools.bench_swarm", args, DOCS / "bench_swarm.jsonl")
    stamp("swarm", command=["python", "-m", "tools.bench_swarm"])


SCALING_ARGS = ["--agents", "4,8,16,32,64", "--interest", "bundle,cells,all", "--plot", "docs/scaling.png"]


def scaling(out: Path, jobs: int) -> None:
    """Agent CPU and bytes received per tick against N at constant density (the relay's bundles,
    the default; cells through the router; every agent hearing every other), with the figure
    ``docs/scaling.png``."""
    del jobs
    _tool_lines("tools.bench_scaling", [*SCALING_ARGS, "--out", str(out / "scaling")], DOCS / "bench_scaling.jsonl")
    stamp("scaling", command=["python", "-m", "tools.bench_scaling", *SCALING_ARGS])


def access_cost(out: Path, jobs: int) -> None:
    """Access control on and off, 16 agents with the world's roster, in ABBA order (this
    machine's speed drifts: only interleaved runs compare)."""
    del jobs
    lines: list[str] = []
    for i, ac in enumerate(("on", "off", "off", "on")):
        args = ["--agents", "16", "--sources", "world", "--access-control", ac, "--out", str(out / f"access_{i}")]
        p = subprocess.run(
            [sys.executable, "-m", "tools.bench_swarm", *args], capture_output=True, text=True, cwd=ROOT, check=True
        )
        lines += [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    (DOCS / "bench_access.jsonl").write_text("".join(ln + "\n" for ln in lines))
    stamp(
        "access",
        command=[
            "python",
            "-m",
            "tools.bench_swarm",
            "--agents",
            "16",
            "--sources",
            "world",
            "--access-control",
            "on|off",
        ],
        order="on, off, off, on",
    )


def paper(out: Path, jobs: int) -> None:
    names = sorted(p.stem for p in (CONFIGS / "paper").glob("*.yaml"))

    def one(name: str) -> tuple[str, list[dict]]:
        cfg = load(CONFIGS / "paper" / f"{name}.yaml")
        cfg = unpinned(cfg) if jobs > 1 else cfg
        rows = [{**r, "level": "rotors"} for r in compare(cfg, ["c3bf", "hocbf"], out / name)]
        make_report(out / name / "c3bf")
        shutil.copy(out / name / "c3bf" / "report" / "views.png", DOCS / f"{name}_views.png")
        # the same scenario with this project's departure, the attitude command level, beside it
        att = cfg.model_copy(
            update={"agents": [a.model_copy(update={"command_level": CommandLevel.ATTITUDE}) for a in cfg.agents]}
        )
        rows += [{**r, "level": "attitude"} for r in compare(att, ["c3bf"], out / name / "attitude")]
        return name, rows

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        results = dict(pool.map(one, names))
    (DOCS / "paper.json").write_text(json.dumps(results, indent=2))
    named = {n: [{**r, "filter": f"{r['filter']} ({r['level']})"} for r in results[n]] for n in names}
    (DOCS / "paper.md").write_text("\n".join(markdown(n, named[n]) for n in names))
    stamp("paper", configs="configs/paper/*.yaml", filters=["c3bf", "hocbf"], levels=["rotors", "attitude (c3bf)"])


def paper_lab(out: Path, jobs: int) -> None:
    """Section 1's scenarios with C3BF and HO-CBF at the attitude level (the firmware closes the
    attitude loop on board, as on a real Crazyflie) in the ideal world and in the Crazyflie lab's
    (``world.realism: crazyflie_lab``), side by side."""
    names = sorted(p.stem for p in (CONFIGS / "paper").glob("*.yaml"))
    worlds = ["ideal", "crazyflie_lab"]

    def one(name: str) -> tuple[str, list[dict]]:
        cfg = load(CONFIGS / "paper" / f"{name}.yaml")
        cfg = unpinned(cfg) if jobs > 1 else cfg
        att = cfg.model_copy(
            update={"agents": [a.model_copy(update={"command_level": CommandLevel.ATTITUDE}) for a in cfg.agents]}
        )
        return name, compare(att, ["c3bf", "hocbf"], out / "paper_lab" / name, worlds)

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        results = dict(pool.map(one, names))
    (DOCS / "paper_lab.json").write_text(json.dumps(results, indent=2))
    stamp("paper_lab", configs="configs/paper/*.yaml", filters=["c3bf", "hocbf"], level="attitude", worlds=worlds)


def sweeps(out: Path, jobs: int) -> None:
    base = load(CONFIGS / "sweeps" / "head_on.yaml").model_dump(mode="json")
    for name, specs in SWEEPS.items():
        sweep(base, parse_axes(specs), out / f"sweep_{name}", jobs=jobs, engine=ENGINE.name, address=ENGINE.address)
        dest = DOCS / f"sweep_{name}"
        dest.mkdir(parents=True, exist_ok=True)
        for f in [*(out / f"sweep_{name}").glob("*.png"), out / f"sweep_{name}" / "results.csv"]:
            shutil.copy(f, dest / f.name)
    stamp("sweeps", config="configs/sweeps/head_on.yaml", axes=SWEEPS, engine=ENGINE.name)


def _jsonl(path: Path) -> list[dict]:
    return [json.loads(ln) for ln in path.read_text().splitlines() if ln.strip()]


def _compare_table(path: Path) -> str:
    return "\n".join(markdown("", json.loads(path.read_text())).splitlines()[2:]).strip()


def _faults_table(path: Path) -> str:
    from tools.bench_faults import table

    return table(_jsonl(path))


def _paper_table(path: Path) -> str:
    """EXPERIMENTS.md section 1's figures: per scenario, C3BF and HO-CBF side by side."""
    data = json.loads(path.read_text())

    def num(v: object, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    head = (
        "| scenario | C3BF contacts / inside the safety radius | C3BF closest to an obstacle [m] | "
        "C3BF closest between agents [m] | C3BF time to goal [s] | C3BF infeasible ticks | "
        "HO-CBF contacts / inside the safety radius | HO-CBF closest to an obstacle [m] | "
        "HO-CBF closest between agents [m] | HO-CBF time to goal [s] | HO-CBF infeasible ticks |"
    )
    out = [head, "|" + "---|" * 11]
    for name in sorted(data):
        cells = [name]
        rotors = [r for r in data[name] if r["level"] == "rotors"]
        for r in sorted(rotors, key=lambda r: r["filter"]):  # c3bf, hocbf
            cells += [
                f"{r['collisions']} / {r.get('margin_violations', '-')}",
                num(r["min_clearance_m"], ".3f"),
                num(r["min_separation_m"], ".3f"),
                num(r["max_time_to_goal_s"], ".2f"),
                num(r["infeasible_ticks"], "d"),
            ]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def _outcome_cells(r: dict) -> list[str]:
    """A compare row's contacts / inside the safety radius, closest approach (to an obstacle, else
    between agents) [m], latest time to goal [s] and infeasible ticks, as table cells."""
    closest = r["min_clearance_m"] if r["min_clearance_m"] is not None else r["min_separation_m"]
    return [
        f"{r['collisions']} / {r['margin_violations']}",
        _maybe(closest, ".3f"),
        _maybe(r["max_time_to_goal_s"], ".2f"),
        str(r["infeasible_ticks"]),
    ]


def _paper_lab_table(path: Path) -> str:
    """EXPERIMENTS.md section 5's paper scenarios: per scenario and filter (attitude level), the
    ideal world's run beside the lab's."""
    data = json.loads(path.read_text())
    head = ["scenario", "filter"] + [
        f"{w} {col}"
        for w in ("ideal", "lab")
        for col in ("contacts / inside", "closest [m]", "time to goal [s]", "infeasible ticks")
    ]
    rows = []
    for name in sorted(data):
        for f in ("c3bf", "hocbf"):
            cells = [name, f]
            for world in ("ideal", "crazyflie_lab"):
                (x,) = [r for r in data[name] if r["filter"] == f and r["world"] == world]
                cells += _outcome_cells(x)
            rows.append(cells)
    return _table(head, rows)


def _levels_table(path: Path) -> str:
    """EXPERIMENTS.md section 1's comparison of the command levels: per scenario, C3BF with the
    paper's rotor thrusts as inputs against the attitude level (roll, pitch, yaw rate, thrust)."""
    data = json.loads(path.read_text())
    head = ["scenario"] + [
        f"{lv} {col}"
        for lv in ("rotors", "attitude")
        for col in ("contacts / inside", "closest [m]", "time to goal [s]", "infeasible ticks", "min h [m^2/s]")
    ]
    rows = []
    for name in sorted(data):
        cells = [name]
        for lv in ("rotors", "attitude"):
            (r,) = [r for r in data[name] if r["filter"] == "c3bf" and r["level"] == lv]
            cells += [*_outcome_cells(r), _maybe(r["min_h"], ".4f")]
        rows.append(cells)
    return _table(head, rows)


def _liveness_table(path: Path) -> str:
    """EXPERIMENTS.md section 4's table, one row per line of ``tools.bench_liveness``."""
    out = [
        "| family | scene | rho | start | runs | success | contacts | inside the safety radius | min exact h | "
        "deadlocks | infeasible ticks | mean / worst time ratio | mean / worst free-path ratio | "
        "ORCA: success, deadlocks, inside the safety radius, mean ratio | ORCA along the path: success, "
        "deadlocks, mean free-path ratio |",
        "|" + "---|" * 15,
    ]

    def pair(mean: float | None, worst: float | None) -> str:
        return "-" if mean is None else f"{mean:.2f} / {worst:.2f}"

    for r in _jsonl(path):
        random = r["family"] in ("sphere_field", "forest")
        start = "random field" if random else ("exact" if r["exact"] else "perturbed")
        rho = f"{r['rho']:g}"
        o = r["orca"]
        orca = (
            "-"
            if o is None
            else (
                f"{o['success_rate']:.2f}, {o['deadlocks']}, {o.get('margin_violations', '-')}, "
                + ("-" if o["mean_time_ratio"] is None else f"{o['mean_time_ratio']:.2f}")
            )
        )
        op = r.get("orca_path")
        orca_path = (
            "-"
            if op is None
            else f"{op['success_rate']:.2f}, {op['deadlocks']}, "
            + ("-" if op["mean_free_time_ratio"] is None else f"{op['mean_free_time_ratio']:.2f}")
        )
        cells = [
            r["family"],
            r["scene"],
            rho,
            start,
            str(r["runs"]),
            f"{r['success_rate']:.2f}",
            str(r["collisions"]),
            str(r.get("margin_violations", "-")),
            "-" if r.get("min_h") is None else f"{r['min_h']:.3f}",
            str(r["deadlocks"]),
            str(r["infeasible_ticks"]),
            pair(r["mean_time_ratio"], r["worst_time_ratio"]),
            pair(r.get("mean_free_time_ratio"), r.get("worst_free_time_ratio")),
            orca,
            orca_path,
        ]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


VARIANT_SCENES = [
    ("circle_32", 1.0, False),
    ("circle_32", 0.5, False),
    ("circle_32", 1.0, True),
    ("circle_32", 0.5, True),
    ("circle_8", 0.5, True),
    ("sphere_12_r1.5", 1.0, True),
    ("sphere_16_r1.5", 1.0, True),
    ("sphere_16_r1.5", 0.5, True),
    ("sphere_32_r2", 1.0, True),
    ("sphere_32_r1.5", 1.0, True),
    ("sphere_32_r2", 0.5, True),
    ("sphere_32_r1.5", 0.5, True),
    ("pillar_8", 0.5, True),
    ("doorway_8", 1.0, True),
    ("corridor_4x2", 1.0, True),
]
"""The scenes a variant's table sets beside the defaults (scene, rho, exact start)."""


def _variant_table(path: Path) -> str:
    """A variant of the liveness benchmark (``path``) beside the defaults (``liveness.jsonl``):
    its whole count of failed points and infeasible ticks, then the scenes of
    :data:`VARIANT_SCENES`, each with its mean / worst time ratio and infeasible ticks."""
    base = {(r["scene"], r["rho"], r["exact"]): r for r in _jsonl(path.parent / "liveness.jsonl")}
    var = {(r["scene"], r["rho"], r["exact"]): r for r in _jsonl(path)}

    def ratio(r: dict | None) -> str:
        if r is None:
            return "-"
        pair = "-" if r["mean_time_ratio"] is None else f"{r['mean_time_ratio']:.2f} / {r['worst_time_ratio']:.2f}"
        return pair if r["success_rate"] == 1.0 else f"fails ({r['success_rate']:.2f}), {pair}"

    def whole(rows: dict) -> str:
        failed = sum(r["success_rate"] < 1.0 for r in rows.values())
        ticks = sum(r["infeasible_ticks"] or 0 for r in rows.values())
        return f"{failed} of {len(rows)} points fail, {ticks} infeasible ticks"

    out = [
        "| scene | rho | start | mean / worst time ratio, defaults | same, this variant | "
        "infeasible ticks, defaults | same, this variant |",
        "|---|---|---|---|---|---|---|",
        f"| whole benchmark | | | {whole(base)} | {whole(var)} | | |",
    ]
    for key in VARIANT_SCENES:
        b, v = base.get(key), var.get(key)
        if b is None and v is None:
            continue
        ticks = [str(r["infeasible_ticks"]) if r is not None else "-" for r in (b, v)]
        start = "exact" if key[2] else "perturbed"
        out.append(f"| {key[0]} | {key[1]:g} | {start} | {ratio(b)} | {ratio(v)} | {ticks[0]} | {ticks[1]} |")
    return "\n".join(out)


def _sweep_table(path: Path) -> str:
    """One sweep's ``results.csv`` as a table: its axes, then the outcome of each run."""
    import csv

    rows = list(csv.DictReader(path.open()))
    header = list(rows[0])
    axes = header[1 : header.index("success")]

    def num(v: str, fmt: str) -> str:
        return "-" if v in ("", "None") else format(float(v), fmt)

    out = [
        "| "
        + " | ".join(
            [
                *axes,
                "success",
                "contacts / inside the safety radius",
                "closest to the obstacle [m]",
                "time to goal [s]",
                "largest path deviation [m]",
                "infeasible ticks",
            ]
        )
        + " |",
        "|" + "---|" * (len(axes) + 6),
    ]
    for r in rows:
        cells = [r[a] for a in axes] + [
            "yes" if r["success"] == "1" else "no",
            f"{r['collisions']} / {r.get('margin_violations') or '-'}",
            num(r["min_clearance_m"], ".3f"),
            num(r.get("mean_time_to_goal_s", r.get("time_to_goal_s", "")), ".2f"),  # (older results: time_to_goal_s)
            num(r["max_path_deviation_m"], ".2f"),
            r["infeasible_ticks"],
        ]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def _lab_table(path: Path) -> str:
    """EXPERIMENTS.md section 5's table: each point of the liveness benchmark in the lab's world
    (``path``) beside the same point in the ideal world, same code (``liveness_lab_ideal.jsonl``),
    and on the lab's bad day (``liveness_bad_day.jsonl``), with what the safety monitor did."""
    ideal = {(r["scene"], r["rho"], r["exact"]): r for r in _jsonl(path.parent / "liveness_lab_ideal.jsonl")}
    bad_path = path.parent / "liveness_bad_day.jsonl"
    bad = {(r["scene"], r["rho"], r["exact"]): r for r in _jsonl(bad_path)} if bad_path.exists() else {}
    out = [
        "| scene | rho | start | ideal: success, contacts, inside the safety radius, downwash pair-ticks, "
        "mean ratio | lab: success, contacts, inside the safety radius, downwash pair-ticks, mean ratio | "
        "lab: estimate p95 / max [mm], commands lost | bad day: home or landed, contacts, inside the safety "
        "radius, mean ratio | bad day: monitor slow / hold / land ticks, landed, unguarded ticks, estimate max [mm] |",
        "|" + "---|" * 8,
    ]

    def bad_cells(r: dict | None) -> tuple[str, str]:
        if r is None:
            return "-", "-"
        ratio = "-" if r["mean_time_ratio"] is None else f"{r['mean_time_ratio']:.2f}"
        m = r.get("monitor_ticks", {})
        err = r.get("estimate_error_max_m")
        return (
            f"{r.get('home_or_landed_rate', r['success_rate']):.2f}, {r['collisions']}, {r['margin_violations']}, "
            f"{ratio}",
            f"{m.get('slow', 0)} / {m.get('hold', 0)} / {m.get('land', 0)}, {r.get('landed_by_monitor', 0)}, "
            f"{r.get('unguarded_ticks', 0)}, {'-' if err is None else f'{1000 * err:.0f}'}",
        )

    def cells(r: dict | None) -> str:
        if r is None:
            return "-"
        ratio = "-" if r["mean_time_ratio"] is None else f"{r['mean_time_ratio']:.2f}"
        dw = r.get("downwash_pair_ticks", "-")
        return f"{r['success_rate']:.2f}, {r['collisions']}, {r['margin_violations']}, {dw}, {ratio}"

    for r in _jsonl(path):
        random = r["family"] in ("sphere_field", "forest")
        start = "random field" if random else ("exact" if r["exact"] else "perturbed")
        err, top = r.get("estimate_error_p95_m"), r.get("estimate_error_max_m")
        lost = sum(run.get("commands_lost", 0) for run in r["per_run"])
        lab = "-" if err is None else f"{1000 * err:.1f} / {'-' if top is None else f'{1000 * top:.1f}'}, {lost}"
        key = (r["scene"], r["rho"], r["exact"])
        row = [r["scene"], f"{r['rho']:g}", start, cells(ideal.get(key)), cells(r), lab, *bad_cells(bad.get(key))]
        out.append("| " + " | ".join(row) + " |")
    return "\n".join(out)


def _sep(r: dict | None) -> str:
    return "-" if r is None else f"{r['min_separation_m']:.3f}" + (" x" if r["collisions"] else "")


def _axis_tables(path: Path, axes: list[str], cell: Callable[[dict | None], str], what: str) -> str:
    """One table per axis of ``axes`` (``tools.bench_imperfections``' points in ``path``): per
    method and scene, ``cell`` of the point at each level, and the first level with a contact."""
    from tools.bench_imperfections import AXES

    lines = _jsonl(path)
    scale = {
        "s": (1000.0, "ms"),
        "m": (1000.0, "mm"),
        "m/s": (1.0, "m/s"),
        "fraction": (100.0, "%"),
        "drones": (1.0, "drones"),
        "fraction/min": (100.0, "%/min"),
    }
    out = []
    for axis in axes:
        unit, levels = AXES[axis]
        k, name = scale[unit]
        head = ["method", "scene", *(f"{lv * k:g} {name}" for lv in levels), "first contact"]
        rows = []
        for method in sorted({r["method"] for r in lines}):
            for scene in sorted({r["scene"] for r in lines}):
                got = {r["level"]: r for r in lines if (r["axis"], r["method"], r["scene"]) == (axis, method, scene)}
                if not got:
                    continue
                hits = [lv for lv in levels if lv in got and got[lv]["collisions"]]
                first = f"{hits[0] * k:g} {name}" if hits else "none" if len(got) == len(levels) else "-"
                rows.append([method, scene, *(cell(got.get(lv)) for lv in levels), first])
        if rows:
            note = ""
            if any(r[0] == "orca" for r in rows):
                late = axis in DELAY_AXES
                note = "; orca: what it sees and flies as late" if late else "; orca: the ideal world, first level"
            out.append(f"**{axis}** ({what}; x: a contact{note})\n\n" + _table(head, rows))
    return "\n\n".join(out)


def _imperfection_table(path: Path) -> str:
    """EXPERIMENTS.md section 5's sweep table: per imperfection, method and scene, the closest
    centres at each level and the first level with a contact."""
    from tools.bench_imperfections import AXES

    return _axis_tables(path, list(AXES), _sep, "closest centres [m]")


def _sep_and_time(r: dict | None) -> str:
    """The closest centres (:func:`_sep`) and the mean time to goal over the straight line at the
    configured speed, or "not home" where some drone did not arrive in the run."""
    if r is None:
        return "-"
    if not r["success"] and not r["collisions"]:
        return f"{_sep(r)} / not home"
    return _sep(r) + ("" if r["mean_time_ratio"] is None else f" / {r['mean_time_ratio']:.2f}")


def _delay_table(path: Path) -> str:
    """EXPERIMENTS.md's delay table: per delay axis, method and scene, at each level the closest
    centres [m] (x: a contact) and the mean time to goal over the straight line (:func:`_sep_and_time`)."""
    return _axis_tables(
        path, list(DELAY_AXES), _sep_and_time, "closest centres [m] / time to goal over the straight line"
    )


def _filter_table(path: Path) -> str:
    """docs/benchmarks.md's filter table: median / p99 [us] per row count, backend and level."""
    lines = _jsonl(path)
    cols = [(b, lv) for b in ("daqp", "osqp") for lv in ("rotors", "attitude")]
    cell = {(r["rows"], r["backend"], r["level"]): r for r in lines}
    out = [
        "| rows | " + " | ".join(f"{b} {lv}" for b, lv in cols) + " | largest violation of an OK command |",
        "|" + "---|" * (len(cols) + 2),
    ]
    for n in sorted({r["rows"] for r in lines}):
        got = [cell.get((n, b, lv)) for b, lv in cols]
        worst = max(r["max_violation"] for r in got if r)
        out.append(
            f"| {n} | "
            + " | ".join("-" if r is None else f"{r['median_us']:.0f} / {r['p99_us']:.0f}" for r in got)
            + f" | {worst:.1e} |"
        )
    return "\n".join(out)


def _table(head: list[str], rows: list[list[str]]) -> str:
    """A markdown table."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def _maybe(v: float | None, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def _swarm_table(path: Path) -> str:
    """docs/benchmarks.md's swarm table, one row per line of ``tools.bench_swarm``."""
    head = [
        "agents",
        "mode",
        "neighbours (topology)",
        "real-time factor",
        "on time",
        "CPU per agent (% of a core)",
        "CPU per agent tick (us)",
        "received per agent tick (bytes)",
        "p99 tick latency (ms)",
        "contacts / inside the safety radius",
    ]
    rows = [
        [
            str(r["agents"]),
            r["mode"],
            f"{r['neighbour_source']} ({r['topology']})",
            f"{r['real_time_factor']:.2f}",
            _maybe(r["on_time_fraction"], ".4f"),
            f"{r['cpu_percent_per_agent']:.0f}",
            _maybe(r.get("cpu_us_per_agent_tick"), ".0f"),
            _maybe(r.get("rx_bytes_per_agent_tick"), ".0f"),
            _maybe(r["p99_tick_latency_ms"], ".1f"),
            f"{r['collisions']} / {r.get('margin_violations', '-')}",
        ]
        for r in _jsonl(path)
    ]
    return _table(head, rows)


def _scaling_table(path: Path) -> str:
    """docs/benchmarks.md's scaling table: one row per swarm size and interest."""
    head = [
        "agents",
        "interest",
        "CPU per agent tick (us)",
        "received per agent tick (bytes)",
        "real-time factor",
        "missed neighbours",
        "collisions",
    ]
    rows = [
        [
            str(r["agents"]),
            r["interest"],
            f"{r['cpu_us_per_agent_tick']:.0f}",
            f"{r['rx_bytes_per_agent_tick']:.0f}",
            f"{r['real_time_factor']:.3f}",
            str(r["missed_neighbours"]),
            str(r["collisions"]),
        ]
        for r in sorted(_jsonl(path), key=lambda r: (r["interest"], r["agents"]))
    ]
    return _table(head, rows)


def _access_table(path: Path) -> str:
    """docs/benchmarks.md's access-control table: each run of the ABBA rounds, in order."""
    head = [
        "access control",
        "mode",
        "real-time factor",
        "on time",
        "CPU per agent (% of a core)",
        "p99 tick latency (ms)",
    ]
    rows = [
        [
            "on" if r["access_control"] else "off",
            r["mode"],
            f"{r['real_time_factor']:.2f}",
            _maybe(r["on_time_fraction"], ".4f"),
            f"{r['cpu_percent_per_agent']:.1f}",
            f"{r['p99_tick_latency_ms']:.1f}",
        ]
        for r in _jsonl(path)
    ]
    return _table(head, rows)


# generated blocks of the documents: <!-- generated: NAME --> ... <!-- end generated -->
GENERATED = {
    "compare": (DOCS / "compare.json", _compare_table),
    "faults": (DOCS / "bench_faults.jsonl", _faults_table),
    "paper": (DOCS / "paper.json", _paper_table),
    "paper_levels": (DOCS / "paper.json", _levels_table),
    "liveness": (DOCS / "liveness.jsonl", _liveness_table),
    **{f"liveness_{n}": (DOCS / f"liveness_{n}.jsonl", _variant_table) for n in LIVENESS_VARIANTS},
    "liveness_lab": (DOCS / "liveness_lab.jsonl", _lab_table),
    "paper_lab": (DOCS / "paper_lab.json", _paper_lab_table),
    "imperfections": (DOCS / "imperfections.jsonl", _imperfection_table),
    "imperfections_bad_day": (DOCS / "imperfections_bad_day.jsonl", _imperfection_table),
    "imperfections_delay": (DOCS / "imperfections_delay.jsonl", _delay_table),
    "filter": (DOCS / "bench_filter.jsonl", _filter_table),
    "swarm": (DOCS / "bench_swarm.jsonl", _swarm_table),
    "access": (DOCS / "bench_access.jsonl", _access_table),
    "scaling": (DOCS / "bench_scaling.jsonl", _scaling_table),
    **{f"sweep_{n}": (DOCS / f"sweep_{n}" / "results.csv", _sweep_table) for n in SWEEPS},
}
DOCUMENTS = [ROOT / "README.md", ROOT / "EXPERIMENTS.md", ROOT / "docs" / "benchmarks.md"]
_BLOCK = r"(<!-- generated: (\w+) -->\n)(.*?)\n?<!-- end generated -->"


def documents(write: bool) -> list[str]:
    """Each generated block of the documents against its data; with ``write`` the blocks are
    rewritten from the data. Returns the blocks that differ (before any rewrite)."""
    import re

    stale = []
    for doc in DOCUMENTS:
        text = doc.read_text()

        def fill(m: re.Match[str], doc: Path = doc) -> str:
            path, render = GENERATED[m.group(2)]
            fresh = render(path)
            if fresh != m.group(3).strip():
                stale.append(f"{doc.name}: {m.group(2)}")
            return m.group(1) + fresh + "\n<!-- end generated -->"

        new = re.sub(_BLOCK, fill, text, flags=re.S)
        if write and new != text:
            doc.write_text(new)
    return stale


PARTS = {
    "paper": paper,
    "sweeps": sweeps,
    "compare": compare_table,
    "liveness": liveness,
    "liveness_variants": liveness_variants,
    "liveness_lab": liveness_lab,
    "paper_lab": paper_lab,
    "imperfections": imperfections,
    "imperfections_bad_day": imperfections_bad_day,
    "imperfections_delay": imperfections_delay,
    "faults": faults,
    "filter": filter_bench,
    "swarm": swarm_bench,
    "access": access_cost,
    "scaling": scaling,
}

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("runs/experiments"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--only", choices=sorted(PARTS), action="append", help="default: every part")
    ap.add_argument(
        "--engine",
        choices=["local", "ray"],
        default="local",
        help="ray: the sweeps' runs and liveness scenes as Ray tasks",
    )
    ap.add_argument("--address", help="--engine ray: the Ray cluster's address (default: a local cluster)")
    ap.add_argument(
        "--allow-dirty", action="store_true", help="run from uncommitted code (its stamps say so); refused otherwise"
    )
    args = ap.parse_args()
    ENGINE = Engine(args.engine, args.address)
    SOURCE.update(source_state())
    if SOURCE["uncommitted_changes"] and not args.allow_dirty:
        sys.exit("tools.experiments: swarm/, agents/, world/ or tools/ has uncommitted changes; commit them first "
                 "(the data are stamped with the commit) or pass --allow-dirty")  # fmt: skip
    DOCS.mkdir(parents=True, exist_ok=True)
    for part in args.only or list(PARTS):
        PARTS[part](args.out, args.jobs)
    documents(write=True)  # the documents' generated tables from the new data
