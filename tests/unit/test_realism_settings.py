"""``world.realism``: presets, overrides, and bad values refused with their field named,
through the scenario loader as a user meets them."""

from __future__ import annotations

import pytest
import yaml

from swarm.config import ConfigError, dump, load, resolve
from swarm.realism.settings import PRESETS, RealismSettings


def scenario(realism: object = None) -> dict:
    raw = {"version": 1, "name": "t", "duration_s": 1.0, "agents": [{"id": "a", "start": [0, 0, 1]}]}
    if realism is not None:
        raw["world"] = {"realism": realism}
    return raw


def test_a_hand_written_config_is_the_ideal_world():
    r = resolve(scenario()).world.realism
    assert r.preset == "ideal" and r.ideal
    assert r == RealismSettings() == RealismSettings.model_validate("ideal")


def test_the_lab_preset_turns_every_imperfection_on():
    r = resolve(scenario("crazyflie_lab")).world.realism
    assert not r.ideal
    assert r.aero.downwash and r.aero.drag and r.aero.ground_effect
    assert (r.motors.time_constant_up_s, r.motors.time_constant_down_s) == (0.0125, 0.025)
    assert r.wind.gust_std_mps > 0 and r.sensing.enabled
    assert (r.sensing.rate_hz, r.sensing.latency_s) == (100.0, 0.010)
    assert not r.comms.params().perfect
    assert r.aero.downwash_model == "measured"
    assert set(PRESETS) == {"ideal", "crazyflie_lab", "crazyflie_lab_bad_day"}


def test_the_bad_day_is_the_lab_and_every_failure_of_a_bad_day():
    lab = RealismSettings.model_validate("crazyflie_lab")
    bad = resolve(scenario("crazyflie_lab_bad_day")).world.realism
    s = bad.sensing
    assert s.occlusion_rate_hz > 0 and s.swap_rate_hz > 0 and s.outlier_fraction > 0 and s.centroid_offset_std_m > 0
    assert s.estimator.gate_sigmas > 0  # the agents refuse implausible frames
    assert bad.motors.battery_sag_fraction_per_min > 0 and bad.wind.relative_gust_std_mps > 0
    assert bad.comms.shared_radio.drones_per_radio > 1 and bad.comms.command.burst_enter_probability > 0
    assert (bad.aero, bad.motors.time_constant_up_s, s.rate_hz) == (
        lab.aero,
        lab.motors.time_constant_up_s,
        lab.sensing.rate_hz,
    )


def test_a_field_beside_the_preset_overrides_it_and_keeps_the_rest():
    r = resolve(scenario({"preset": "crazyflie_lab", "sensing": {"position_noise_m": 0.002}})).world.realism
    lab = RealismSettings.model_validate("crazyflie_lab")
    assert r.sensing.position_noise_m == 0.002
    assert r.sensing.latency_s == lab.sensing.latency_s and r.aero == lab.aero and r.comms == lab.comms
    assert r.sensing.estimator_params().position_noise_m == 0.002  # the agent assumes what it gets
    ideal_with_wind = resolve(scenario({"wind": {"steady_mps": [1.0, 0.0, 0.0]}})).world.realism
    assert ideal_with_wind.preset == "ideal" and not ideal_with_wind.ideal and not ideal_with_wind.sensing.enabled


@pytest.mark.parametrize(
    "realism, field",
    [
        ({"sensing": {"position_noise_m": -0.001}}, "world.realism.sensing.position_noise_m"),
        ({"sensing": {"drop_fraction": 1.0}}, "world.realism.sensing.drop_fraction"),
        ({"sensing": {"latency_s": "10ms"}}, "world.realism.sensing.latency_s"),
        ({"sensing": {"rate_hz": True}}, "world.realism.sensing.rate_hz"),
        ({"sensing": {"estimator": {"latency_s": -1}}}, "world.realism.sensing.estimator.latency_s"),
        ({"motors": {"time_constant_up_s": float("nan")}}, "world.realism.motors.time_constant_up_s"),
        ({"motors": {"mass_offset_fraction": 0.9}}, "world.realism.motors.mass_offset_fraction"),
        ({"wind": {"steady_mps": [1.0, 0.0]}}, "world.realism.wind.steady_mps"),
        ({"wind": {"steady_mps": [1.0, "0", 0.0]}}, "world.realism.wind.steady_mps.1"),
        ({"wind": {"gust_field": "each"}}, "world.realism.wind.gust_field"),
        ({"comms": {"command": {"loss_fraction": 1.5}}}, "world.realism.comms.command.loss_fraction"),
        ({"comms": {"radio": {}}}, "world.realism.comms.radio"),
        ({"preset": "vicon_lab"}, "world.realism.preset"),
        ("crazyflie", "world.realism.preset"),
    ],
)
def test_a_bad_value_is_refused_with_its_field_named(realism, field):
    with pytest.raises(ConfigError) as e:
        resolve(scenario(realism), "lab.yaml")
    assert f"lab.yaml: {field}:" in str(e.value)


def test_a_yaml_file_with_the_section_loads_and_round_trips(tmp_path):
    raw = scenario({"preset": "crazyflie_lab", "sensing": {"position_noise_m": 0.002}, "wind": {"gust_std_mps": 0.5}})
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(raw))
    cfg = load(tmp_path / "s.yaml")
    assert cfg.world.realism.wind.gust_std_mps == 0.5
    (tmp_path / "again.yaml").write_text(dump(cfg))
    assert load(tmp_path / "again.yaml") == cfg
    bad = scenario({"preset": "crazyflie_lab", "motors": {"time_constant_down_s": -0.025}})
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(bad))
    with pytest.raises(ConfigError, match=r"bad.yaml:\d+: world.realism.motors.time_constant_down_s: "):
        load(tmp_path / "bad.yaml")


def test_settings_build_the_core_objects():
    r = RealismSettings.model_validate({"preset": "crazyflie_lab", "sensing": {"estimator": {"latency_s": 0.02}}})
    assert r.sensing.estimator_params().latency_s == 0.02 and r.sensing.mocap_params().latency_s == 0.010
    assert r.wind.params().shared and r.wind.params().gust_std_mps == 0.1
    assert r.comms_model(1, 1 / 120).p.command.loss_fraction == 0.1
    assert r.mocap(3, 1).n == 3


def test_swarm_compare_moves_a_scenario_into_another_world_and_refuses_what_it_cannot_fly():
    """``swarm compare --realism``: the same scenario in each preset's world (the rest of the config
    unchanged, back and forth exactly); an unknown preset, or the lab's motion capture with the
    world's roster, refused with the field named, by the command line before anything flies."""
    from click.testing import CliRunner

    from swarm.cli import cli
    from swarm.runs.compare import in_world

    ideal = load("configs/single_static_sphere.yaml")
    lab = in_world(ideal, "crazyflie_lab")
    assert lab.world.realism == RealismSettings.model_validate("crazyflie_lab") and not lab.world.realism.ideal
    assert lab.model_copy(update={"world": ideal.world}) == ideal
    assert in_world(lab, "ideal") == ideal
    with pytest.raises(ConfigError, match="realism"):
        in_world(ideal, "mars")
    roster = load("configs/single_static_sphere.yaml", {"neighbours": {"source": "world"}})
    with pytest.raises(ConfigError, match="neighbours.source: agents"):
        in_world(roster, "crazyflie_lab")
    for args, says in (
        (["--realism", "ideal,mars"], "choose presets from"),
        (["--realism", ","], "choose presets from"),
    ):
        r = CliRunner().invoke(cli, ["compare", "configs/single_static_sphere.yaml", *args])
        assert r.exit_code == 2 and says in r.output, r.output


def test_the_rotor_level_is_refused_where_agents_act_on_motion_capture():
    """The rotor level closes the attitude loop in the agent: on the motion capture's attitude
    (``world.realism.sensing``), without a gyro, the drones crashed in each of four paper
    scenarios flown (1-16 contacts; with the lab's other imperfections and ground truth, none).
    Such a config is refused with the field named, and by ``swarm compare --realism``."""
    from click.testing import CliRunner

    from swarm.cli import cli

    paper = "configs/paper/static_brake.yaml"
    assert load(paper).agents[0].command_level.value == "rotors"
    with pytest.raises(ConfigError, match=r"agents\.cf1\.command_level: rotors closes the attitude loop"):
        load(paper, {"world": {"realism": "crazyflie_lab"}})
    ground_truth = load(paper, {"world": {"realism": {"preset": "crazyflie_lab", "sensing": {"enabled": False}}}})
    assert not ground_truth.world.realism.ideal
    r = CliRunner().invoke(cli, ["compare", paper, "--realism", "ideal,crazyflie_lab"])
    assert r.exit_code == 2 and "command_level: rotors" in r.output, r.output
