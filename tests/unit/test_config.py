"""The config: shipped files, layering, errors that name file, field and reason."""

import math
from pathlib import Path

import numpy as np
import pytest

from swarm.config import ConfigError, dump, load, resolve
from swarm.offline.scenario import circle_swap

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.mark.parametrize("name", ["single_static_sphere.yaml", "swap_2.yaml", "circle_8.yaml"])
def test_shipped_configs_validate_and_round_trip(name, tmp_path):
    cfg = load(CONFIGS / name)
    (tmp_path / "c.yaml").write_text(dump(cfg))
    assert load(tmp_path / "c.yaml") == cfg


def test_layers_defaults_then_type_then_agent():
    cfg = resolve(
        {
            "version": 1,
            "name": "t",
            "duration_s": 1.0,
            "defaults": {"speed_mps": 0.5, "filter": {"gamma": 2.0, "rho": 0.5}},
            "agent_types": {"fast": {"speed_mps": 2.0, "filter": {"gamma": 3.0}}},
            "agents": [
                {"id": "a", "start": [0, 0, 1], "type": "fast", "filter": {"rho": 1.0}},
                {"id": "b", "start": [1, 0, 1]},
            ],
        }
    )
    a, b = cfg.agents
    assert (a.speed_mps, a.filter.gamma, a.filter.rho) == (2.0, 3.0, 1.0)
    assert (b.speed_mps, b.filter.gamma, b.filter.rho) == (0.5, 2.0, 0.5)


@pytest.mark.parametrize(
    "patch, field",
    [
        ({"agents": [{"id": "a", "start": [0, 0]}]}, "agents.0.start"),
        ({"agents": [{"id": "a", "start": [0, 0, 1], "speed_mps": -1}]}, "agents.0.speed_mps"),
        ({"agents": [{"id": "a", "start": [0, 0, 1], "filter": {"rho": 2}}]}, "agents.0.filter.rho"),
        ({"agents": [{"id": "a", "start": [0, 0, 1], "filter": {"horizon_s": 0}}]}, "agents.0.filter.horizon_s"),
        ({"agents": [{"id": "a", "start": [0, 0, 1], "filter": {"buffer_mps": -0.1}}]}, "agents.0.filter.buffer_mps"),
        ({"agents": [{"id": "a", "start": [0, 0, 1], "filter": {"contact_s": -1.0}}]}, "agents.0.filter.contact_s"),
        ({"agents": [{"id": "a", "start": [0, 0, 1]}, {"id": "a", "start": [1, 0, 1]}]}, "duplicate agents id"),
        ({"agents": [{"id": "a", "start": [0, 0, 1], "type": "nope"}]}, "agents.0.type"),
        ({"time": {"physics_hz": 240, "control_hz": 100}}, "time"),
        ({"obstacles": [{"id": "o", "shape": "cylinder", "center": [0, 0, 0], "radius_m": 0.1}]}, "obstacles.0"),
        (
            {"obstacles": [{"id": "o", "shape": "sphere", "center": [0, 0, 0], "radius_m": -0.1}]},
            "obstacles.0.radius_m",
        ),
        ({"version": 2}, "version"),
        ({"surprise": 1}, "surprise"),
    ],
)
def test_config_errors_name_file_field_and_reason(patch, field):
    raw = {"version": 1, "name": "t", "duration_s": 1.0, "agents": [{"id": "a", "start": [0, 0, 1]}]}
    raw.update(patch)
    with pytest.raises(ConfigError) as err:
        resolve(raw, "my.yaml")
    assert str(err.value).startswith("my.yaml: ") and field in str(err.value)


def test_unreadable_and_invalid_yaml_files(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load(tmp_path / "missing.yaml")
    (tmp_path / "bad.yaml").write_text("agents: [\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load(tmp_path / "bad.yaml")


def test_generated_circle_is_antipodal_and_valid():
    cfg = resolve(circle_swap(6, 2.0))
    for a in cfg.agents:
        np.testing.assert_allclose(np.add(a.start[:2], a.goal[:2]), 0.0, atol=1e-9)
        assert math.hypot(*a.start[:2]) == pytest.approx(2.0)


@pytest.mark.parametrize("path", sorted(Path(__file__).resolve().parents[2].glob("configs/**/*.yaml")), ids=str)
def test_every_shipped_config_validates(path):
    cfg = load(path)
    assert cfg.agents
