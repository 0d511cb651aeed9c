"""What a user reads (swarm.runs.readable): rounded figures, tables that read off a terminal."""

from __future__ import annotations

import io
import math

from swarm.runs.compare import cells, markdown
from swarm.runs.readable import MEANINGS, fig, print_table


def test_figures_are_rounded_to_what_they_mean():
    assert fig(7.3100000000000005, "duration_s") == "7.310"  # seconds to the millisecond
    assert fig(4.341666666666667, "time_to_goal_s") == "4.342"
    assert fig(0.34386349406692146, "min_separation_m") == "0.344"  # metres to the millimetre
    assert fig(-0.0076018710828655855, "min_h") == "-0.00760"  # 3 significant digits
    assert fig(6.0531089957725825, "real_time_factor") == "6.05"
    assert fig(1.0, "real_time_factor") == "1.00"
    assert fig(-1e-9, "min_clearance_m") == "0.000"  # no "-0.000"
    assert fig(None) == "-" and fig(True) == "True" and fig(12) == "12" and fig([]) == "-"
    assert fig(math.inf, "min_h") == "inf"


def test_a_table_off_a_terminal_is_plain_markdown_at_full_width():
    out = io.StringIO()  # (not a terminal: a log, CI, a pipe)
    long = "x" * 300
    print_table("t", ["world", "filter"], [["ideal", long]], ["world: the world's realism preset"], out)
    text = out.getvalue()
    assert "| world | filter |" in text and f"| ideal | {long} |" in text
    assert "…" not in text and "* world: the world's realism preset" in text


def test_compare_tables_carry_rounded_cells_and_each_columns_meaning():
    rows = [
        {"world": "ideal", "filter": "c3bf", "collisions": 0, "margin_violations": 0, "min_clearance_m": 0.11912345,
         "min_separation_m": None, "min_h": -0.0023154690333619943, "negative_h_ticks": 3,
         "max_time_to_goal_s": 5.516666666666667, "max_path_deviation_m": 0.4161, "infeasible_ticks": 0,
         "all_reached_goal": True},
    ]  # fmt: skip
    header, body, legend = cells(rows)
    assert body[0][header.index("closest to an obstacle surface [m]")] == "0.119"
    assert body[0][header.index("min exact C3BF h [m^2/s]")] == "-0.00232"
    assert body[0][header.index("latest time to goal [s]")] == "5.517"
    assert any(line.startswith("min exact C3BF h [m^2/s]: ") and "HO-CBF" in line for line in legend)
    text = markdown("s", rows)
    assert "| ideal | c3bf | 0 | 0 | 0.119 | - | -0.00232 | 3 | 5.517 |" in text
    assert "* latest time to goal [s]: " + MEANINGS["max_time_to_goal_s"] in text


def test_several_seeds_make_one_row_of_spreads_and_the_table_says_so():
    from swarm.runs.compare import spread

    def one(clear: float, reached: bool) -> dict:
        return {"world": None, "filter": "c3bf", "collisions": 0, "min_clearance_m": clear, "min_separation_m": None,
                "all_reached_goal": reached, "stop_reason": "completed"}  # fmt: skip

    row = spread([one(0.1094, True), one(0.1212, False), one(0.1150, True)])
    assert row["seeds"] == 3 and row["collisions"] == {"mean": 0.0, "min": 0, "max": 0, "n": 3}
    assert row["min_clearance_m"]["n"] == 3 and row["min_separation_m"] is None
    assert row["all_reached_goal"] == {"yes": 2, "n": 3} and row["stop_reason"] == "completed"
    header, body, legend = cells([row])
    cell = dict(zip(header, body[0], strict=True))
    assert cell["seeds"] == "3" and cell["contacts"] == "0"
    assert cell["closest to an obstacle surface [m]"] == "0.115 [0.109, 0.121]"
    assert cell["all reached goal"] == "2/3"
    assert any("mean [min, max]" in line for line in legend)


def test_every_figure_a_table_prints_has_its_meaning():
    from swarm.offline.metrics import SUMMARY_KEYS
    from swarm.runs.compare import COLUMNS

    printed = [*SUMMARY_KEYS, *(k for k, _ in COLUMNS if k not in ("world", "filter"))]
    printed += ["reached_goal", "time_to_goal_s", "path_length_m", "min_row_h", "infeasible_ticks", "monitor"]
    assert [k for k in printed if k not in MEANINGS] == []
