"""The documents' generated tables are the data files they quote (tools/experiments.py):
regenerated from ``docs/experiments/`` they come out as written, and every data file has a
stamp naming the commit that made it."""

import json

from tools.experiments import DOCS, DOCUMENTS, GENERATED, documents


def test_generated_tables_match_their_data():
    assert documents(write=False) == []


def test_every_generated_table_is_quoted_and_stamped():
    text = "".join(d.read_text() for d in DOCUMENTS)
    for name, (path, _render) in GENERATED.items():
        assert f"<!-- generated: {name} -->" in text, name
        assert path.exists(), path
    for part in ("compare", "faults"):
        stamp = json.loads((DOCS / f"{part}.stamp.json").read_text())
        assert len(stamp["commit"]) == 40, stamp


def test_experiments_hand_the_engine_to_the_sweeps_and_the_liveness_benchmark(monkeypatch, tmp_path):
    """``tools.experiments --engine ray --address A``: the sweeps fly on Ray at A, the liveness
    benchmark is told the same flags, and the stamps say which engine made the data."""
    import tools.experiments as ex

    calls: list[tuple[str, object]] = []
    monkeypatch.setattr(ex, "ENGINE", ex.Engine("ray", "10.0.0.1:6379"))
    monkeypatch.setattr(ex, "DOCS", tmp_path / "docs")
    monkeypatch.setattr(ex, "_tool_lines", lambda module, args, dest: calls.append((module, args)))
    monkeypatch.setattr(ex, "stamp", lambda part, **settings: calls.append((part, settings["engine"])))

    def sweep(base, axes, out, **kw):
        calls.append(("sweep", (kw["engine"], kw["address"])))
        out.mkdir(parents=True)
        (out / "results.csv").write_text("run\n")

    monkeypatch.setattr(ex, "sweep", sweep)
    ex.liveness(tmp_path / "runs", 2)
    ex.sweeps(tmp_path / "runs", 2)
    assert calls[0] == (
        "tools.bench_liveness",
        ["--seeds", "2", "--jobs", "2", "--engine", "ray", "--address", "10.0.0.1:6379"],
    )
    assert calls[1] == ("liveness", "ray")
    assert calls[2:] == [("sweep", ("ray", "10.0.0.1:6379"))] * len(ex.SWEEPS) + [("sweeps", "ray")]
    assert ex.Engine().flags() == [] and ex.Engine("ray").flags() == ["--engine", "ray"]


def test_the_liveness_variants_are_regenerated_and_stamped_by_the_tool(monkeypatch, tmp_path):
    """Each variant EXPERIMENTS.md quotes has its data file and a stamp with the commit and the
    command that made it; the tool's ``liveness_variants`` part runs those commands."""
    import tools.experiments as ex

    for name, knobs in ex.LIVENESS_VARIANTS.items():
        stamp = json.loads((DOCS / f"liveness_{name}.stamp.json").read_text())
        assert len(stamp["commit"]) == 40 and stamp["command"][-len(knobs) :] == knobs, stamp
        assert (DOCS / f"liveness_{name}.jsonl").read_text().count("\n") > 0
    calls: list[tuple[str, object]] = []
    monkeypatch.setattr(ex, "DOCS", tmp_path)
    monkeypatch.setattr(ex, "ROOT", tmp_path)
    monkeypatch.setattr(ex, "_tool_lines", lambda module, args, dest: calls.append((dest.name, args)))
    monkeypatch.setattr(ex, "stamp", lambda part, **settings: calls.append((part, settings["command"][3:])))
    ex.liveness_variants(tmp_path, 2)
    for i, (name, knobs) in enumerate(ex.LIVENESS_VARIANTS.items()):
        args = ["--seeds", "2", "--jobs", "2", "--no-orca", *knobs]
        assert calls[2 * i : 2 * i + 2] == [(f"liveness_{name}.jsonl", args), (f"liveness_{name}", args)]
