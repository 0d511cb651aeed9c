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
