"""Real-drone pieces without processes: thrust calibration, setpoint units, flight
phases, and the motion-capture relay's estimates against known motion."""

import math

import numpy as np
import pytest

from swarm.agents.crazyflie import FlightPlan, Phase, rpyt, thrust_command
from swarm.config import ConfigError, ThrustCalibration, resolve
from swarm.rotation import FloatArray
from swarm.world.mocap import MocapRelay, PoseDifferentiator

from .helpers import real_drone_raw


def _quat_z(yaw: float) -> FloatArray:
    return np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])


def _quat_axis(axis: FloatArray, angle: float) -> FloatArray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.array([*(a * math.sin(angle / 2)), math.cos(angle / 2)])


def _qmul(a: FloatArray, b: FloatArray) -> FloatArray:  # scalar-last Hamilton product
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


def test_thrust_calibration_and_setpoint_units():
    cal = ThrustCalibration(pwm_offset=1000.0, pwm_per_newton=150_000.0, max_pwm=60_000)
    assert thrust_command(0.2, cal) == 31_000
    assert thrust_command(10.0, cal) == 60_000 and thrust_command(-1.0, cal) == 0
    assert thrust_command(float("nan"), cal) == 0  # never a NaN on the wire
    r, p, y, t = rpyt(math.radians(5), math.radians(-3), math.radians(30), 0.2, cal)
    assert (r, p, y, t) == pytest.approx((5.0, -3.0, -30.0, 31_000))  # the firmware inverts the yaw rate


def _real_agent(**cf):
    return resolve(real_drone_raw(**cf)).agents[0]


def test_flight_phases_take_off_fly_and_land():
    plan = FlightPlan(_real_agent())
    on_ground = np.array([0.0, 0.0, 0.02])
    assert plan.tracker(on_ground) is not None and plan.phase is Phase.TAKEOFF
    assert plan.tracker(np.array([0.0, 0.0, 0.5])) is not None and plan.phase is Phase.TAKEOFF
    assert plan.tracker(np.array([0.0, 0.0, 0.97])) is plan.mission and plan.phase is Phase.MISSION
    assert plan.tracker(np.array([0.5, 0.0, 0.6])) is plan.mission  # a dip mid-mission is not a new takeoff
    plan.land()
    assert plan.tracker(np.array([1.0, 0.0, 1.0])) is not None and plan.phase is Phase.LAND
    assert plan.tracker(np.array([1.0, 0.0, 0.05])) is None and plan.phase is Phase.LANDED
    assert plan.outside_geofence(np.array([0.0, 0.0, 3.0])) and not plan.outside_geofence(np.zeros(3))


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"agents": [{"id": "a", "backend": "crazyflie", "start": [0, 0, 1]}]}, "crazyflie: {uri"),
        ({"time": {"mode": "lockstep"}}, "realtime"),
        ({"mocap": None}, "mocap"),
    ],
)
def test_real_drone_configs_are_checked(change, needle):
    raw = real_drone_raw()
    raw.update(change)
    with pytest.raises(ConfigError, match=needle):
        resolve(raw)


def test_a_goal_outside_the_geofence_is_refused():
    with pytest.raises(ConfigError, match="geofence"):
        _real_agent(geofence_max_m=[0.5, 3.0, 2.0])


def test_velocity_and_body_rates_match_a_known_motion():
    """A body on a 1 m circle at 0.5 rad/s, yawing at 0.5 rad/s and rolling at 0.3 rad/s."""
    rate, w_orbit, roll_rate = 100.0, 0.5, 0.3
    diff = PoseDifferentiator(1.0 / rate, filter_s=0.0)
    for i in range(200):
        t = i / rate
        x = np.array([math.cos(w_orbit * t), math.sin(w_orbit * t), 1.0])
        q = _qmul(_quat_z(w_orbit * t), _quat_axis([1, 0, 0], roll_rate * t))  # R = Rz(yaw) Rx(roll)
        est = diff.update(t, x, q)
    t_mid = (199 - 0.5) / rate  # a backward difference is the velocity half a period back
    v_true = w_orbit * np.array([-math.sin(w_orbit * t_mid), math.cos(w_orbit * t_mid), 0.0])
    np.testing.assert_allclose(est.v_w, v_true, atol=1e-6)
    # body rates of R = Rz(a t) Rx(b t): Omega = Rx(-b t) (0, 0, a) + (b, 0, 0)
    th = roll_rate * (199 - 0.5) / rate
    omega_true = np.array([roll_rate, w_orbit * math.sin(th), w_orbit * math.cos(th)])
    np.testing.assert_allclose(est.Omega_b, omega_true, atol=1e-4)
    assert diff.dropped == 0


class _Body:
    def __init__(self, p, q):
        self.position = np.asarray(p, dtype=np.float32)
        self.rotation = type("Q", (), {"x": q[0], "y": q[1], "z": q[2], "w": q[3]})()


class _ScriptedSource:
    """libmotioncapture's interface over a script: frame i has the bodies script(i)."""

    def __init__(self, script):
        self.script, self.i, self.rigidBodies = script, -1, {}

    def waitForNextFrame(self):
        self.i += 1
        self.rigidBodies = self.script(self.i)


def test_relay_counts_dropped_frames_and_reports_a_lost_body():
    clock = {"t": 0.0}

    def script(i):
        clock["t"] = i * 0.01 + (0.02 if i >= 10 else 0.0)  # two frames missing after frame 9
        bodies = {"cf_a": _Body([0.01 * i, 0, 1], [0, 0, 0, 1])}
        if i < 30:  # body b vanishes after frame 29
            bodies["cf_b"] = _Body([1, 0, 1], [0, 0, 0, 1])
        return bodies

    frames, lost = [], []
    relay = MocapRelay(
        _ScriptedSource(script),
        {"cf_a": "a", "cf_b": "b"},
        100.0,
        0.1,
        0.0,
        lambda aid, est: frames.append((aid, est)),
        lost.append,
        clock=lambda: clock["t"],
    )
    for _ in range(60):
        relay.step()
    assert relay.dropped_frames == 2
    assert lost == ["b"]  # once, about 0.1 s after its last frame
    assert relay.latest("a").v_w[0] == pytest.approx(1.0, rel=1e-3)  # 0.01 m per 10 ms frame
    assert all(np.isfinite(e.v_w).all() for _, e in frames)


def test_a_drone_already_in_the_air_starts_its_mission_directly():
    plan = FlightPlan(_real_agent())
    assert plan.tracker(np.array([0.0, 0.0, 0.98])) is plan.mission and plan.phase is Phase.MISSION
    assert plan.tracker(np.array([0.3, 0.0, 0.5])) is plan.mission
