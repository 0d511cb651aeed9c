"""A motion-capture system's bad day (issue 64): bursts of occlusion, two drones' identities
swapped, jumps and a constant centroid offset, by their statistics and counters; and the agent's
estimator refusing the implausible frames (its innovation gate) while fusing a true return after a
gap, and never locking itself out. Everything off is the sensor and the filter of before, bit for bit."""

from __future__ import annotations

import hashlib
import heapq
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.realism.rng import Stream, normals, uniform, word
from swarm.realism.sensing import (
    REJECT_REASONS,
    Estimator,
    EstimatorParams,
    MocapFrame,
    MocapParams,
    MocapSensor,
    quat_exp,
    quat_mul,
)
from swarm.realism.settings import RealismSettings
from swarm.rotation import euler_to_quat

PHYS = 1 / 240
LAB = MocapParams(rate_hz=100.0, position_noise_m=0.001, attitude_noise_rad=0.0045, latency_s=0.010, drop_fraction=0.1)
Q0 = np.array([0.0, 0.0, 0.0, 1.0])
LAB_EST = RealismSettings.model_validate("crazyflie_lab").sensing.estimator_params()
GATED = replace(LAB_EST, gate_sigmas=5.0)  # the lab's estimator with the gate on, as the bad-day preset is to fly it


def lissajous(t: float) -> np.ndarray:
    return np.array([0.5 * math.sin(2 * t), 0.4 * math.sin(3 * t), 1.0 + 0.2 * math.sin(1.5 * t)])


def lissajous_v(t: float) -> np.ndarray:
    return np.array([1.0 * math.cos(2 * t), 1.2 * math.cos(3 * t), 0.3 * math.cos(1.5 * t)])


def lissajous_a(t: float) -> np.ndarray:
    return np.array([-2.0 * math.sin(2 * t), -3.6 * math.sin(3 * t), -0.45 * math.sin(1.5 * t)])


# --- everything off: the sensor and the filter of before -------------------------------------------


class OldMocapSensor:
    """The sensor before this change (git 7958cbe), kept to compare with."""

    def __init__(self, p: MocapParams, n: int, seed: int) -> None:
        self.p, self.n, self.seed = p, n, word(seed)
        self._next_seq = 0
        self._in_flight: list = []
        self.dropped = 0

    def step(self, t_s, x_w, q):
        seq = math.floor(t_s * self.p.rate_hz + 1e-9)
        if seq >= self._next_seq:
            p = self.p
            drones = np.arange(self.n)
            dpos = normals(int(self.seed), Stream.MOCAP_POSITION, drones, seq, 3) * p.position_noise_m
            datt = normals(int(self.seed), Stream.MOCAP_ATTITUDE, drones, seq, 3) * p.attitude_noise_rad
            due = t_s + p.latency_s
            for i in range(self.n):
                if p.drop_fraction > 0.0:
                    u = uniform(self.seed, np.uint64(int(Stream.MOCAP_DROP)), np.uint64(i), word(seq), np.uint64(0))
                    if u <= p.drop_fraction:
                        self.dropped += 1
                        continue
                qi = np.asarray(q[i], float)
                q_meas = quat_mul(qi, quat_exp(datt[i])) if p.attitude_noise_rad > 0 else qi.copy()
                frame = MocapFrame(i, seq, t_s, due, np.asarray(x_w[i], float) + dpos[i], q_meas)
                heapq.heappush(self._in_flight, (due, seq, i, frame))
            self._next_seq = seq + 1
        out = []
        while self._in_flight and self._in_flight[0][0] <= t_s + 1e-12:
            out.append(heapq.heappop(self._in_flight)[3])
        return out


def swarm_pose(t: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    x = np.array([[0.3 * i + 0.5 * math.sin(2 * t + i), 0.4 * math.cos(3 * t - i), 1.0 + 0.1 * i] for i in range(n)])
    q = np.array([[0.0, 0.0, math.sin(0.1 * t * (i + 1)), math.cos(0.1 * t * (i + 1))] for i in range(n)])
    return x, q


def run_digest(sensor, est_params: EstimatorParams | None, n: int = 4, seconds: float = 3.0) -> str:
    """A digest of every frame (and, with ``est_params``, of every estimate of n agents) of a flight."""
    h = hashlib.sha256()
    ests = None
    for k in range(round(seconds / PHYS)):
        t = k * PHYS
        x, q = swarm_pose(t, n)
        if ests is None and est_params is not None:
            ests = [Estimator(est_params, x[i], q[i]) for i in range(n)]
        for f in sensor.step(t, x, q):
            h.update(np.array([f.drone, f.seq], np.int64).tobytes())
            h.update(np.array([f.t_capture_s, f.t_arrival_s, *f.x_w, *f.q]).tobytes())
            if ests is not None:
                h.update(bytes([ests[f.drone].frame(f)]))
        if ests is not None and k % 2 == 0:
            for i, e in enumerate(ests):
                s = e.estimate(t)
                h.update(
                    np.concatenate(
                        [s.x_w, s.v_w, s.q, s.Omega_b, s.pos_std_m, s.vel_std_mps, [s.age_s], s.d_w]
                    ).tobytes()
                )
                e.command(t, np.array([0.0, 0.1 * i, 0.0]))
    h.update(np.array([sensor.dropped], np.int64).tobytes())
    return h.hexdigest()


def test_everything_off_is_the_sensor_and_the_filter_of_before():
    """The lab's frames and the lab preset's frames and estimates, against the old sensor and against
    digests taken on the code before this change (git 7958cbe, on this machine)."""
    lab = RealismSettings.model_validate("crazyflie_lab").sensing
    assert lab.mocap_params() == replace(LAB, rate_hz=100.0)  # the preset has no failure on
    assert run_digest(MocapSensor(LAB, 4, 11), None) == run_digest(OldMocapSensor(LAB, 4, 11), None)
    assert run_digest(MocapSensor(LAB, 4, 11), None) == (
        "986834d241b2b6aef97de02bd53a448a849a79fea669602cc3e7dc0afe9cfe9f"
    )
    assert run_digest(MocapSensor(lab.mocap_params(), 4, 11), lab.estimator_params()) == (
        "b99d60438ff9baac2aa98ace694d367e190b82131ad2a820469473903a1886ad"
    )
    assert RealismSettings().sensing.estimator_params().gate_sigmas == 0.0 == lab.estimator_params().gate_sigmas


def test_the_new_streams_are_numbered_40_to_49_and_the_old_ones_kept():
    old = {"THRUST_FACTOR": 1, "MASS_FACTOR": 2, "WIND": 3, "MOCAP_POSITION": 4, "MOCAP_ATTITUDE": 5}
    old |= {"MOCAP_DROP": 6, "COMMS": 7}
    assert all(Stream[k] == v for k, v in old.items())
    new = [s for s in Stream if s.name not in old and s.name.startswith("MOCAP")]
    assert len(new) == 6 and all(40 <= s <= 49 for s in new)


def test_a_gate_that_refuses_nothing_is_the_filter_without_it():
    """On the lab's clean frames (1 mm of noise, 10 % dropped) the gate refuses no frame in 10 s,
    and the estimates are the ungated filter's to the bit."""
    for seed in (5, 6, 7):
        out = []
        for params in (LAB_EST, GATED):
            sensor = MocapSensor(LAB, 1, seed)
            est = Estimator(params, lissajous(0.0), Q0, v0_w=lissajous_v(0.0))
            xs = []
            for k in range(round(10.0 / PHYS)):
                t = k * PHYS
                for f in sensor.step(t, lissajous(t)[None], Q0[None]):
                    est.frame(f)
                if k % 2 == 0:
                    e = est.estimate(t)
                    xs.append(np.concatenate([e.x_w, e.v_w, e.pos_std_m, e.d_w]))
                    est.command(t, lissajous_a(t))
            out.append(np.array(xs))
            assert est.rejected == 0 and est.reacquired == 0
        assert np.array_equal(out[0], out[1])


# --- the sensor's failures ---------------------------------------------------------------------------


def capture(sensor: MocapSensor, seconds: float, x: np.ndarray, q: np.ndarray | None = None) -> list[MocapFrame]:
    """Every frame of drones held at ``x`` (n, 3)."""
    q = np.tile(Q0, (len(x), 1)) if q is None else q
    out: list[MocapFrame] = []
    for k in range(round(seconds / PHYS)):
        out += sensor.step(k * PHYS, x, q)
    return out


def runs_of_missing(seqs: list[int], last: int) -> list[int]:
    """The lengths of the runs of frame numbers missing from ``seqs`` (sorted), before ``last``."""
    have = np.zeros(last + 1, bool)
    have[seqs] = True
    runs, k = [], 0
    for s in range(last + 1):
        if not have[s]:
            k += 1
        elif k:
            runs.append(k)
            k = 0
    return runs  # (a run still open at the end is not counted)


def test_occlusion_bursts_have_the_configured_rate_and_mean_length():
    """0.5 bursts a second of each drone seen, 0.2 s long on average: over 40 drones for 60 s,
    the bursts per second seen and their mean length within 4 sigma of the asked."""
    n, seconds, rate, mean = 40, 60.0, 0.5, 0.2
    p = MocapParams(rate_hz=100.0, occlusion_rate_hz=rate, occlusion_mean_s=mean)
    sensor = MocapSensor(p, n, seed=3)
    frames = capture(sensor, seconds, np.zeros((n, 3)))
    captured = 100 * round(seconds) * n
    assert sensor.occluded + len(frames) == captured and sensor.dropped == 0
    runs, seen_s = [], 0.0
    for i in range(n):
        seqs = sorted(f.seq for f in frames if f.drone == i)
        runs += runs_of_missing(seqs, seqs[-1])
        seen_s += len(seqs) / 100.0
    lengths = np.array(runs) / 100.0  # s
    m = len(runs)
    assert m / seen_s == pytest.approx(rate, abs=4 * math.sqrt(m) / seen_s)  # Poisson count
    assert lengths.mean() == pytest.approx(mean, abs=4 * mean / math.sqrt(m))  # geometric: std ~ mean
    # the counters: every hidden frame, every burst (two back to back look like one: rare at 0.5 %)
    assert sensor.occlusions >= m and sensor.occlusions - m <= 0.03 * m
    assert sensor.occluded >= int(round(lengths.sum() * 100))


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(-(2**63), 2**64),
    n=st.integers(2, 6),
    rate=st.floats(0.1, 20.0),
    mean=st.floats(0.005, 1.0),
    outliers=st.floats(0.0, 0.3),
    offset=st.floats(0.0, 0.005),
)
def test_drone_failures_are_pure_functions_of_seed_drone_and_frame(seed, n, rate, mean, outliers, offset):
    """Occlusion, jumps and the centroid offset of drone 0 are the same whatever the swarm's size and
    whoever asks, differ with the seed, and the counters add up to the frames captured."""
    p = replace(
        LAB, occlusion_rate_hz=rate, occlusion_mean_s=mean, outlier_fraction=outliers, centroid_offset_std_m=offset
    )
    x = np.arange(3 * n, dtype=float).reshape(n, 3)

    def drone0(sensor: MocapSensor, k: int) -> list:
        return [(f.seq, tuple(f.x_w), tuple(f.q)) for f in capture(sensor, 1.0, x[:k]) if f.drone == 0]

    a = drone0(MocapSensor(p, n, seed), n)
    assert a == drone0(MocapSensor(p, n, seed), n) == drone0(MocapSensor(p, 1, seed), 1)
    assert a != drone0(MocapSensor(p, n, seed + 1), n)
    sensor = MocapSensor(p, n, seed)
    frames = capture(sensor, 1.0, x)
    assert sensor.occluded + sensor.dropped + len(frames) + len(sensor._in_flight) == 100 * n
    jumps = sum(1 for f in frames if np.linalg.norm(f.x_w - x[f.drone]) > 0.05)  # 10 cm, less at most 3.5 cm of offset
    assert sensor.outliers - sum(1 for f in sensor._in_flight if f[3].x_w is not None) <= jumps <= sensor.outliers
    assert sensor.swaps == sensor.swapped == 0


def test_the_centroid_offset_is_constant_per_drone_with_the_asked_spread():
    n = 300
    p = MocapParams(rate_hz=100.0, centroid_offset_std_m=0.003)
    x = np.random.default_rng(1).uniform(-2, 2, (n, 3))
    frames = capture(MocapSensor(p, n, seed=2), 0.5, x)
    off = np.array([f.x_w - x[f.drone] for f in frames]).reshape(-1, n, 3)  # (frames, drones, 3)
    assert np.allclose(off, off[0], atol=1e-12, rtol=0)  # constant
    assert off[0].std(axis=0) == pytest.approx(np.full(3, 0.003), rel=4 / math.sqrt(2 * n))
    assert np.abs(off[0].mean(axis=0)).max() < 4 * 0.003 / math.sqrt(n)


def test_outliers_jump_by_the_asked_length_at_the_asked_fraction():
    n, p = 20, MocapParams(rate_hz=100.0, outlier_fraction=0.05, outlier_m=0.1)
    x = np.random.default_rng(2).uniform(-2, 2, (n, 3))
    sensor = MocapSensor(p, n, seed=4)
    frames = capture(sensor, 10.0, x)
    d = np.array([np.linalg.norm(f.x_w - x[f.drone]) for f in frames])
    jumped = d > 1e-9
    assert np.allclose(d[jumped], 0.1) and sensor.outliers == jumped.sum()
    m = len(frames)
    assert jumped.mean() == pytest.approx(0.05, abs=4 * math.sqrt(0.05 * 0.95 / m))
    dirs = np.array([(f.x_w - x[f.drone]) / 0.1 for f, j in zip(frames, jumped, strict=True) if j])
    assert np.abs(dirs.mean(axis=0)).max() < 4 / math.sqrt(3 * len(dirs))  # no preferred direction


def test_a_swap_exchanges_the_closest_pairs_frames_for_its_duration():
    """Drones 0 and 2 are the closest pair (0.3 m): at a swap each frame of one carries the other's
    position and attitude (its noise included) for 0.5 s, 50 frames; drone 1 is never swapped."""
    x = np.array([[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [0.3, 0.0, 1.0]])
    q = np.array([euler_to_quat(0.0, 0.0, yaw) for yaw in (0.0, 1.0, 2.0)])
    p = replace(LAB, drop_fraction=0.0, swap_rate_hz=0.5, swap_duration_s=0.5)
    sensor = MocapSensor(p, 3, seed=8)
    frames = capture(sensor, 20.0, x, q)
    owner = [int(np.argmin(np.linalg.norm(x - f.x_w, axis=1))) for f in frames]
    qown = [int(np.argmax(np.abs(q @ f.q))) for f in frames]
    assert owner == qown  # position and attitude swap together
    swapped = [f for f, o in zip(frames, owner, strict=True) if o != f.drone]
    assert {(f.drone, o) for f, o in zip(frames, owner, strict=True) if o != f.drone} == {(0, 2), (2, 0)}
    assert sensor.swapped == len(swapped) and sensor.swaps >= 3
    seqs = sorted({f.seq for f in swapped})
    starts = [s for s in seqs if s - 1 not in seqs]
    assert len(starts) == sensor.swaps  # (with 0.5 swaps/s over 20 s none ends where the next begins here)
    for s in starts[:-1]:
        assert set(range(s, s + 50)) <= set(seqs) and s + 50 not in seqs
    assert sensor.swaps == pytest.approx(0.5 * 20 * 0.8, abs=4 * math.sqrt(10))  # a swap in progress cannot begin


# --- the estimator's gate ---------------------------------------------------------------------------


def fly_pair(seed: int, offset: np.ndarray, hover: bool, p: MocapParams, seconds: float = 4.0, window=(0.0, 0.0)):
    """Two drones, B at A's path plus ``offset``, each agent commanding its true acceleration (0 at
    hover) with the gated lab estimator. Frames captured in ``window`` [s) are swapped by hand (as
    the sensor swaps them), beside any swap the sensor makes. Per frame (drone, fused, does it carry
    the other's pose, the time since its estimator last fused a frame), and per tick the position
    errors of the estimates."""
    path = (lambda t: np.array([0.0, 0.0, 1.0])) if hover else lissajous
    accel = (lambda t: np.zeros(3)) if hover else lissajous_a
    vel = (lambda t: np.zeros(3)) if hover else lissajous_v
    sensor = MocapSensor(p, 2, seed)
    ests = [Estimator(GATED, path(0.0) + d, Q0, v0_w=vel(0.0)) for d in (np.zeros(3), offset)]
    log, errors = [], []
    for k in range(round(seconds / PHYS)):
        t = k * PHYS
        x = np.array([path(t), path(t) + offset])
        frames = sensor.step(t, x, np.tile(Q0, (2, 1)))
        if any(window[0] <= f.t_capture_s < window[1] for f in frames):
            mine = {f.drone: f for f in frames}
            frames = [
                f._replace(x_w=mine[1 - f.drone].x_w, q=mine[1 - f.drone].q) if 1 - f.drone in mine else f
                for f in frames
            ]
            frames = [f for f in frames if 1 - f.drone in mine]  # (a frame whose pair was dropped: drop it too)
        for f in frames:
            other = np.linalg.norm(f.x_w - x[1 - f.drone]) < np.linalg.norm(f.x_w - x[f.drone])
            e = ests[f.drone]
            tau = f.t_capture_s - e._t_frame_s
            log.append((f.drone, e.frame(f), other, tau, f.t_capture_s))
        if k % 2 == 0:
            errors.append([t] + [float(np.linalg.norm(e.estimate(t).x_w - x[i])) for i, e in enumerate(ests)])
            for e in ests:
                e.command(t, accel(t))
    return sensor, ests, log, np.array(errors)


def direction(azimuth: float, elevation: float) -> np.ndarray:
    ce = math.cos(elevation)
    return np.array([ce * math.cos(azimuth), ce * math.sin(azimuth), math.sin(elevation)])


@settings(max_examples=12, deadline=None)
@given(
    seed=st.integers(0, 2**32),
    distance=st.floats(0.2, 1.5),
    azimuth=st.floats(0.0, 2 * math.pi),
    elevation=st.floats(-math.pi / 2, math.pi / 2),
    hover=st.booleans(),
)
def test_a_swap_of_half_a_second_is_refused_whole(seed, distance, azimuth, elevation, hover):
    """Two drones 0.2-1.5 m apart in any direction, hovering or flying the Lissajous curve (up to
    1.2 m/s), on the lab's frames, their identities swapped for 0.5 s from t = 1 s: every frame
    that carries the other drone's pose is refused (so the swap is refused from its first frame),
    every true frame is fused (the first after the swap too), and the estimates stay within 5 cm of
    the truth while they coast blind for 0.5 s (measured over seeds 0-39: median 1.4 cm, largest
    3.3 cm, the disturbance estimate being still young at 1 s)."""
    _sensor, ests, log, errors = fly_pair(seed, distance * direction(azimuth, elevation), hover, LAB, 2.5, (1.0, 1.5))
    swapped = [fused for _d, fused, other, _tau, _t in log if other]
    assert len(swapped) > 60 and not any(swapped)
    assert all(fused for _d, fused, other, _tau, _t in log if not other)
    for i, e in enumerate(ests):
        assert e.rejected == sum(1 for d, _f, other, _tau, _t in log if other and d == i)
        assert e.rejected_reasons["jump"] + e.rejected_reasons["after_gap"] == 1  # one run
        assert e.rejected_reasons["in_run"] == e.rejected - 1 and e.reacquired == e.resets == 0
    assert errors[errors[:, 0] > 0.5, 1:].max() < 0.05


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("offset", [(0.25, 0.0, 0.0), (0.0, 0.0, 0.25), (0.6, -0.4, 0.2)])
def test_the_sensors_swaps_are_refused_while_the_gate_is_within_its_reach(seed, offset):
    """End to end, the sensor swapping the pair about once a second (some swaps back to back: a
    longer swap): every swapped frame is refused while its estimator has coasted at most 0.55 s
    (half a second of swap, a frame dropped); a longer swap of drones this close may be fused late
    (the limit, docs/design.md), but the filter never stays wrong: the last second's true frames
    are all fused and the estimates are within 2 cm."""
    p = replace(LAB, swap_rate_hz=1.0, swap_duration_s=0.5)
    sensor, ests, log, errors = fly_pair(seed, np.array(offset), False, p, seconds=6.0)
    assert sensor.swaps >= 2
    assert not any(fused for _d, fused, other, tau, _t in log if other and tau <= 0.55)
    last = max(t for _d, _f, other, _tau, t in log if other)
    after = [fused for _d, fused, other, _tau, t in log if not other and t > last + GATED.gate_reset_s + 0.05]
    assert all(after)
    quiet = errors[errors[:, 0] > last + GATED.gate_reset_s + 0.5, 1:]
    assert len(quiet) == 0 or quiet.max() < 0.02


def test_a_long_swap_of_close_drones_is_the_limit_and_the_filter_recovers():
    """Drones 0.2 m apart one above the other, swapped for 2 s: after about 0.58 s of coasting the
    gate's reach covers the other drone and its frames are fused (the gate's limit: swaps longer
    than 0.5 s of drones this close), the filter restarting from them; once the swap ends the true
    frames are refused until the reach covers them again, and the filter is back within 1 cm."""
    for seed in (1, 2, 3):
        _sensor, ests, log, errors = fly_pair(seed, np.array([0.0, 0.0, 0.2]), True, LAB, 6.0, (1.0, 3.0))
        fused_swapped = [t for _d, fused, other, _tau, t in log if other and fused]
        assert fused_swapped and min(fused_swapped) > 1.5  # the limit, after the half second the gate holds
        assert all(e.reacquired >= 2 for e in ests)  # onto the swap, back onto the truth
        assert all(fused for _d, fused, other, _tau, t in log if not other and t > 3.0 + GATED.gate_reset_s)
        assert errors[errors[:, 0] > 4.6, 1:].max() < 0.01


def test_without_the_gate_a_swap_is_fused():
    """The same flight with today's filter (no gate) takes the other drone's frames: the estimate
    jumps to it (what the gate is for)."""
    p = replace(LAB, swap_rate_hz=1.0, swap_duration_s=0.5)
    offset = np.array([0.3, 0.0, 0.0])
    sensor = MocapSensor(p, 2, 1)
    est = Estimator(LAB_EST, np.array([0.0, 0.0, 1.0]), Q0)
    worst = 0.0
    for k in range(round(4.0 / PHYS)):
        x = np.array([[0.0, 0.0, 1.0], [0.3, 0.0, 1.0]])
        for f in sensor.step(k * PHYS, x, np.tile(Q0, (2, 1))):
            if f.drone == 0:
                est.frame(f)
        worst = max(worst, float(np.linalg.norm(est.estimate(k * PHYS).x_w - x[0])))
    assert sensor.swaps > 0 and worst > 0.25 and np.linalg.norm(offset) == 0.3


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_a_jump_is_refused(seed):
    """5 % of the lab's frames jump by 10 cm: every jump is refused, as a jump right after a fused
    frame, after frames missed (a dropped one), or after another refused; every true frame is fused."""
    p = replace(LAB, outlier_fraction=0.05, outlier_m=0.1)
    sensor = MocapSensor(p, 1, seed)
    est = Estimator(GATED, lissajous(0.0), Q0, v0_w=lissajous_v(0.0))
    verdicts = []
    for k in range(round(10.0 / PHYS)):
        t = k * PHYS
        x = lissajous(t)
        for f in sensor.step(t, x[None], Q0[None]):
            t_c = f.t_capture_s
            verdicts.append((np.linalg.norm(f.x_w - lissajous(t_c)) > 0.05, est.frame(f)))
        if k % 2 == 0:
            est.command(t, lissajous_a(t))
    jumps = [fused for jumped, fused in verdicts if jumped]
    assert len(jumps) == sensor.outliers > 20 and not any(jumps)
    assert all(fused for jumped, fused in verdicts if not jumped)
    assert est.rejected == sensor.outliers == sum(est.rejected_reasons.values())
    assert est.rejected_reasons["jump"] > est.rejected_reasons["after_gap"] > 0 or sensor.dropped == 0


def test_the_reasons_are_counted_by_what_came_before():
    """By hand: a jump right after a fused frame, the frame after it (in a run), a jump after a
    frame missed (after a gap); the true frames between are fused."""
    est = Estimator(GATED, np.zeros(3), Q0)
    far = np.array([0.5, 0.0, 0.0])

    def f(seq: int, x: np.ndarray) -> bool:
        return est.frame(MocapFrame(0, seq, seq / 100, seq / 100 + GATED.latency_s, x, Q0))

    assert all(f(s, np.zeros(3)) for s in range(1, 10))
    assert not f(10, far) and not f(11, far) and f(12, np.zeros(3))
    assert not f(15, far) and f(16, np.zeros(3))
    assert est.rejected == 3 and est.rejected_reasons == {"jump": 1, "in_run": 1, "after_gap": 1}
    assert set(REJECT_REASONS) == set(est.rejected_reasons) and est.stale == 0 and est.reacquired == 0


def track_with_gap(est: Estimator, gap: tuple[float, float], push: np.ndarray, seconds: float, seed: int = 5):
    """One drone on the Lissajous curve; its agent commands the curve's acceleration less ``push``
    (what it does not know); no frame is captured in ``gap`` [s) (an occlusion). Per frame after
    the gap (capture time, fused), and per tick (t, position error, pos_std, age)."""
    sensor = MocapSensor(LAB, 1, seed)
    after, ticks = [], []
    for k in range(round(seconds / PHYS)):
        t = k * PHYS
        for f in sensor.step(t, lissajous(t)[None], Q0[None]):
            if gap[0] <= f.t_capture_s < gap[1]:
                continue
            fused = est.frame(f)
            if f.t_capture_s >= gap[1]:
                after.append((f.t_capture_s, fused))
        if k % 2 == 0:
            e = est.estimate(t)
            ticks.append((t, float(np.linalg.norm(e.x_w - lissajous(t))), float(e.pos_std_m.max()), e.age_s))
            est.command(t, lissajous_a(t) - push)
    return after, np.array(ticks)


def test_a_true_return_after_a_1_s_occlusion_is_fused_at_once():
    """The lab's gated estimator, a drone with a push of 0.6 m/s^2 its agent does not command (the
    disturbance estimate finds it before the gap): through 1 s unseen its pos_std and age grow; the
    first frame after is fused and so are all that follow, and the error is back under 4 mm (the
    lab's largest in steady flight)."""
    push = np.array([0.4, -0.3, 0.3])
    est = Estimator(GATED, lissajous(0.0), Q0, v0_w=lissajous_v(0.0))
    after, ticks = track_with_gap(est, (3.0, 4.0), push, 6.0)
    assert all(fused for _t, fused in after) and est.rejected == 0 and est.reacquired == 0
    before = ticks[(ticks[:, 0] > 2.5) & (ticks[:, 0] < 3.0)]
    during = ticks[(ticks[:, 0] > 3.9) & (ticks[:, 0] < 4.0)]
    late = ticks[ticks[:, 0] > 4.5]
    # (age_s counts from the filter's own state, moved on once the gap passes MAX_GAP_S: at most 0.5 s)
    assert during[:, 2].min() > 10 * before[:, 2].max() and during[:, 3].min() > 0.45
    assert late[:, 1].max() < 0.004 and late[:, 2].max() < 2 * before[:, 2].max()  # the lab's steady errors


def test_an_occlusion_burst_of_the_sensor_grows_the_estimates_uncertainty():
    """Bursts of occlusion made by the sensor (0.4 s on average) for a drone held still: while it is
    unseen the estimate's pos_std and age grow; each return is fused."""
    p = replace(LAB, drop_fraction=0.0, occlusion_rate_hz=1.0, occlusion_mean_s=0.4)
    sensor = MocapSensor(p, 1, seed=12)
    x = np.array([[0.0, 0.0, 1.0]])
    est = Estimator(GATED, x[0], Q0)
    std, age = [], []
    for k in range(round(10.0 / PHYS)):
        t = k * PHYS
        for f in sensor.step(t, x, Q0[None]):
            assert est.frame(f)
        e = est.estimate(t)
        std.append(e.pos_std_m.max())
        age.append(e.age_s)
        est.command(t, np.zeros(3))
    std, age = np.array(std), np.array(age)
    assert sensor.occlusions >= 3 and est.rejected == 0
    long_gaps = age > 0.3  # only in a burst (frames every 10 ms, 10 ms late)
    assert long_gaps.any() and std[long_gaps].min() > 5 * np.median(std)
    assert std.max() > 0.01 and np.median(std) < 0.001


@pytest.mark.parametrize("seed", [5, 6])
def test_a_long_gap_with_an_unknown_push_cannot_lock_the_filter_out(seed):
    """No disturbance estimate and a push of 0.7 m/s^2 its agent does not know: after 2 s unseen the
    drone is 1.4 m from where the filter predicts it, beyond its own 5 sigma (38 cm across). The
    gate's reach (1 m/s^2 allowed: 2 m) takes the first frame back, the filter restarts from it and
    the error is under 1 cm within 0.5 s. With no reach (gate_accel_mps2 0) the frames are refused
    for the gate's reset time (1 s), then it restarts; with neither (a reset after 60 s) every frame
    after the gap is refused: locked out for good, the error growing as the square of the time."""
    push = np.array([0.5, -0.4, 0.3])
    plain = replace(EstimatorParams(position_noise_m=0.001, latency_s=0.010), gate_sigmas=5.0)
    est = Estimator(plain, lissajous(0.0), Q0, v0_w=lissajous_v(0.0))
    after, ticks = track_with_gap(est, (2.0, 4.0), push, 6.0, seed)
    assert all(fused for _t, fused in after) and est.reacquired == 1 and est.rejected == est.resets == 0
    assert ticks[(ticks[:, 0] > 3.9) & (ticks[:, 0] < 4.0), 1].min() > 1.0
    assert ticks[ticks[:, 0] > 4.5, 1].max() < 0.01
    no_reach = Estimator(replace(plain, gate_accel_mps2=0.0), lissajous(0.0), Q0, v0_w=lissajous_v(0.0))
    after, ticks = track_with_gap(no_reach, (2.0, 4.0), push, 6.0, seed)
    refused = [t for t, fused in after if not fused]
    assert no_reach.resets == 1 and no_reach.reacquired == 0 and no_reach.rejected == len(refused)
    assert refused[0] == min(t for t, _ in after) and 0.95 < refused[-1] - refused[0] < 1.0
    assert all(fused for t, fused in after if t > refused[-1]) and ticks[ticks[:, 0] > 5.5, 1].max() < 0.01
    locked = Estimator(
        replace(plain, gate_accel_mps2=0.0, gate_reset_s=60.0), lissajous(0.0), Q0, v0_w=lissajous_v(0.0)
    )
    after, ticks = track_with_gap(locked, (2.0, 4.0), push, 6.0, seed)
    assert not any(fused for _t, fused in after) and locked.rejected == len(after) > 150
    assert locked.rejected_reasons["after_gap"] == 1 and locked.rejected_reasons["in_run"] == len(after) - 1
    assert ticks[-1, 1] > 3.0
