"""``v2xbench coverage``: the per-instance records and their per-type summary."""

from __future__ import annotations

from v2xbench.benchmarks import rsu_coverage as cov


def test_summary_counts_instances_by_threshold():
    recs = [
        {"route": "a", "type": "T", "in_view": True, "hidden_s": 1.0, "covered_s": 0.6, "rsu_s": 2.0},
        {"route": "b", "type": "T", "in_view": False, "hidden_s": 0.4, "covered_s": 0.4, "rsu_s": 0.0},
        {"route": "c", "type": "U", "in_view": True, "hidden_s": 0.5, "covered_s": 0.0, "rsu_s": 0.0},
    ]
    rows = {r["type"]: r for r in cov.summarize(recs)}
    assert rows["T"] == {"type": "T", "n": 2, "in_view": 1, "hidden": 1, "covered": 1}
    assert rows["U"] == {"type": "U", "n": 1, "in_view": 1, "hidden": 1, "covered": 0}
    assert rows["all"]["n"] == 3 and rows["all"]["covered"] == 1
    assert "| T | 2 | 1 | 1 | 1 |" in cov.markdown(list(rows.values()))


def test_measure_on_v2x_routes_of_test50():
    recs = cov.measure("test50", max_routes=4, progress=False)
    assert recs, "the first test50 routes hold V2X-type scenarios"
    for r in recs:
        assert 0.0 <= r["covered_s"] <= r["hidden_s"]
        assert isinstance(r["in_view"], bool)
