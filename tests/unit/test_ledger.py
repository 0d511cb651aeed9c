"""The recorder's ledger: every hole in a stream is a gap with its ticks and its size."""

from __future__ import annotations

from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from swarm.ledger import Gap, Ledger, sent_counts, summaries


def _clocks(ledger: Ledger, ticks: list[int]) -> None:
    for k in ticks:
        ledger.see("clock", "world", 1000 + k, k)


def test_a_whole_run_has_no_gap():
    led = Ledger(2)
    _clocks(led, list(range(50)))
    for k in range(49):
        led.see("command", "cf1", 2 * (k + 1), k)
    led.see("status", "world", 2000, 49, done=True)
    assert led.gaps({"world/clock": 50, "cf1/command": 49}, 49) == []
    assert led.counts() == {"cf1/command": 49, "world/clock": 50}


def test_missing_clocks_and_commands_are_gaps_with_their_ticks():
    led = Ledger(2)
    _clocks(led, [0, 1, 2, 6, 7])  # 3, 4, 5 lost
    for seq, k in ((2, 0), (4, 1), (10, 4), (12, 5)):  # the commands of ticks 2 and 3 lost
        led.see("command", "cf1", seq, k)
    assert led.gaps() == [Gap("cf1/command", 2, 3, 2), Gap("world/clock", 3, 5, 3)]


def test_a_lost_tail_is_found_against_what_the_sender_says_it_sent():
    led = Ledger(1)
    _clocks(led, list(range(10)))  # the world says 15 clocks (0 to 14): 10 to 14 lost, with its done status
    for k in range(6):
        led.see("command", "cf2", k + 1, k)  # cf2 says 9 commands: 3 lost after tick 5
    gaps = led.gaps({"world/clock": 15, "cf2/command": 9}, None)
    assert gaps == [Gap("cf2/command", 6, None, 3), Gap("world/clock", 10, 14, 5)]
    led.see("status", "world", 99, 14, done=True)
    assert Gap("cf2/command", 6, 14, 3) in led.gaps({"cf2/command": 9}, 14)


def test_a_message_that_comes_late_fills_its_hole():
    led = Ledger(1)
    for seq in (1, 2, 5):
        led.see("command", "cf1", seq, seq)
    led.see("command", "cf1", 3, 3)
    assert led.gaps() == [Gap("cf1/command", 3, 4, 1)]
    led.see("command", "cf1", 4, 4)
    assert led.gaps() == []


@given(st.lists(st.booleans(), min_size=1, max_size=200), st.sampled_from([1, 2]))
def test_the_gaps_count_exactly_what_was_lost(kept, step):
    """Any pattern of lost commands: the gaps hold as many messages as were lost, and with
    the sender's count every message is either recorded or in a gap."""
    led = Ledger(step)
    for i, keep in enumerate(kept):
        if keep:
            led.see("command", "cf1", step * (i + 1), i)
    gaps = led.gaps({"cf1/command": len(kept)}, len(kept) - 1)
    assert sum(g.messages for g in gaps) == kept.count(False)
    for g in gaps:  # every gap's ticks are lost ticks
        assert g.to_k is not None and not any(kept[g.from_k : g.to_k + 1])


def test_what_each_process_says_it_sent_is_read_from_its_summary_line(tmp_path: Path):
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "world.log").write_text('pybullet\nWORLD_SUMMARY {"ticks": 736, "late": 0}\n')
    (logs / "agent-cf1.log").write_text('x\nAGENT_SUMMARY {"id": "cf1", "ticks": 700, "rejected": {}}\n')
    (logs / "agent-cf2.log").write_text("killed before its summary\n")
    (logs / "router.log").write_text('ROUTER_SUMMARY {"bundles": 3, "rejected": {"cf1": {"state: x": 2}}}\n')
    said = summaries(logs)
    assert sorted(said) == ["agent-cf1", "router", "world"]
    assert sent_counts(said) == {"world/clock": 737, "cf1/command": 700}
    assert summaries(tmp_path / "nowhere") == {}


def test_ticks_a_clock_says_were_flown_unpublished_are_no_gap():
    """A realtime world behind its real drones flies ticks unpublished (swarm.world.main
    World.catch_up): the next clock says how many, and the world's summary counts them."""
    led = Ledger(1)
    _clocks(led, [0, 1, 2])
    led.see("clock", "world", 1003, 9, skipped=6)  # ticks 3 to 8 flown unpublished
    _clocks(led, [10, 11])
    led.see("clock", "world", 1013, 13)  # 12 lost
    said = {"world": {"ticks": 13, "skipped_ticks": 6}}
    assert led.gaps(sent_counts(said), 13) == [Gap("world/clock", 12, 12, 1)]
    led.see("clock", "world", 1012, 12)  # late: it fills its hole
    assert led.gaps(sent_counts(said), 13) == []
    led = Ledger(1)
    _clocks(led, [0, 1, 2])
    led.see("clock", "world", 1004, 10, skipped=6)  # tick 3 lost, 4 to 9 flown unpublished
    assert led.gaps() == [Gap("world/clock", 3, 3, 1)]
