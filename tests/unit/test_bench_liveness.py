"""``tools.bench_liveness``: a point with ORCA beside C3BF prints its line, ORCA's summary included
(ORCA's runs carry no estimate, no monitor)."""

from __future__ import annotations

import json

from tools import bench_liveness


def test_a_formation_point_with_orca_prints_both_summaries(capsys):
    bench_liveness.main(quick=True, family="formation", jobs=1, orca=True)
    lines = [json.loads(s) for s in capsys.readouterr().out.splitlines() if s.startswith("{")]
    assert lines and all(r["family"] == "formation" for r in lines)
    with_orca = [r for r in lines if r["orca"] is not None]
    assert with_orca, lines
    for r in with_orca:
        assert r["orca"]["estimate_error_p95_m"] is None and r["orca"]["runs"] == r["runs"]
        assert r["collisions"] == 0 and 0.0 <= r["success_rate"] <= 1.0
