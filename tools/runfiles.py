"""Reading a run folder: ``run.mcap``, ``config.yaml``, ``metrics.json``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from swarm.config import ScenarioConfig, load
from swarm.messages import expand_record
from swarm.metrics import compute


def read_records(path: Path) -> list[dict[str, Any]]:
    """Every recorded message as a dict (with its ``topic``), in file order; a clock is
    followed by the measurements and obstacles it carries (:func:`expand_record`)."""
    out = []
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages():
            if channel.topic == "/dropped":
                continue
            rec = json.loads(message.data)
            rec["topic"] = channel.topic
            out.extend(expand_record(rec))
    return out


def read_config(run_dir: Path) -> ScenarioConfig:
    return load(run_dir / "config.yaml")


def write_metrics(run_dir: Path) -> dict[str, Any]:
    cfg = read_config(run_dir)
    rec_info = run_dir / "recorder.json"
    dropped = json.loads(rec_info.read_text())["dropped"] if rec_info.exists() else 0
    metrics = compute(cfg, read_records(run_dir / "run.mcap"), dropped)
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics
