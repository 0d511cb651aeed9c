"""The world's stamps on a real drone's motion-capture frames (swarm.world.main.mocap_stamp):
never far ahead of the physics while the ticks go on, and after the last tick going on from
where they were at the wall clock's pace, however far behind the world ended."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from swarm.world.real_drones import behind_at_end, mocap_stamp

MAX_LAG_S = 0.25


@given(
    physics_s=st.floats(0.0, 3600.0),
    behind_s=st.floats(0.0, 60.0),  # how far the wall clock is ahead of the physics at the last tick
    after_s=st.floats(0.0, 30.0),  # wall time since the last tick
)
def test_the_stamps_go_on_from_the_last_tick_s_without_a_jump(physics_s, behind_s, after_s):
    wall_end_s = physics_s + behind_s
    last = mocap_stamp(wall_end_s, physics_s, MAX_LAG_S, None)
    assert last <= physics_s + MAX_LAG_S and last <= wall_end_s
    end = behind_at_end(wall_end_s, physics_s, MAX_LAG_S)
    first_after = mocap_stamp(wall_end_s, physics_s, MAX_LAG_S, end)
    assert abs(first_after - last) <= 1e-9 * max(1.0, wall_end_s)  # (was: the wall clock, behind_s - 0.25 later)
    later = mocap_stamp(wall_end_s + after_s, physics_s, MAX_LAG_S, end)
    assert abs((later - first_after) - after_s) <= 1e-9 * max(1.0, wall_end_s + after_s)  # at the wall clock's pace


def test_a_world_on_time_stamps_on_the_wall_clock_throughout():
    assert mocap_stamp(10.0, 10.0, MAX_LAG_S, None) == 10.0
    assert behind_at_end(10.1, 10.0, MAX_LAG_S) == 0.0
    assert mocap_stamp(12.0, 10.0, MAX_LAG_S, 0.0) == 12.0
