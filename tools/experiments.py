"""Regenerate the measurements behind EXPERIMENTS.md (issue 4): every paper scenario under
C3BF and HO-CBF, a report of each C3BF run, and the obstacle-speed, approach-angle and
gain sweeps. Figures and tables are copied into ``docs/experiments/``.

    python -m tools.experiments [--out runs/experiments] [--jobs 2] [--only paper|sweeps]
"""

from __future__ import annotations

import argparse
import json
import shutil
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from swarm.config import load
from tools.compare import compare, markdown
from tools.launch import unpinned
from tools.report import make_report
from tools.sweep import parse_axes, sweep

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
DOCS = Path(__file__).resolve().parent.parent / "docs" / "experiments"

SWEEPS = {
    "speed": ["filter=c3bf,hocbf", "obstacle_speed=0.1,0.5,1,1.5,2,3"],
    "angle": ["filter=c3bf,hocbf", "obstacle_speed=1", "approach_angle_deg=0,45,90,135"],
    "gamma_c3bf": ["filter=c3bf", "obstacle_speed=1", "gamma=0.25,0.5,1,2,4"],
    "gamma_hocbf": ["filter=hocbf", "obstacle_speed=1", "gamma_ho=0.25,0.5,1,2,4"],
}


def paper(out: Path, jobs: int) -> None:
    names = sorted(p.stem for p in (CONFIGS / "paper").glob("*.yaml"))

    def one(name: str) -> tuple[str, list[dict]]:
        cfg = load(CONFIGS / "paper" / f"{name}.yaml")
        rows = compare(unpinned(cfg) if jobs > 1 else cfg, ["c3bf", "hocbf"], out / name)
        make_report(out / name / "c3bf")
        shutil.copy(out / name / "c3bf" / "report" / "views.png", DOCS / f"{name}_views.png")
        return name, rows

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        results = dict(pool.map(one, names))
    (DOCS / "paper.json").write_text(json.dumps(results, indent=2))
    (DOCS / "paper.md").write_text("\n".join(markdown(n, results[n]) for n in names))


def sweeps(out: Path, jobs: int) -> None:
    base = load(CONFIGS / "sweeps" / "head_on.yaml").model_dump(mode="json")
    for name, specs in SWEEPS.items():
        sweep(base, parse_axes(specs), out / f"sweep_{name}", jobs=jobs)
        dest = DOCS / f"sweep_{name}"
        dest.mkdir(parents=True, exist_ok=True)
        for f in [*(out / f"sweep_{name}").glob("*.png"), out / f"sweep_{name}" / "results.csv"]:
            shutil.copy(f, dest / f.name)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("runs/experiments"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--only", choices=["paper", "sweeps"])
    args = ap.parse_args()
    DOCS.mkdir(parents=True, exist_ok=True)
    if args.only in (None, "paper"):
        paper(args.out, args.jobs)
    if args.only in (None, "sweeps"):
        sweeps(args.out, args.jobs)
