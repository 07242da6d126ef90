"""docs/benchmarks/ is generated from benchmarks/results/ (``python -m benchmarks.docs``): a results
JSON updated without regenerating its page fails here, and so does a new results file with no
row in ``benchmarks.docs.RESULTS``."""
import json

import pytest

from benchmarks import docs


def test_docs_benchmarks_is_current(tmp_path):
    docs.write(tmp_path)
    fresh = {p.name: p.read_bytes() for p in tmp_path.glob("*.md")}
    have = {p.name: p.read_bytes() for p in docs.DOCS_DIR.glob("*.md")}
    assert sorted(have) == sorted(fresh), "run: .venv/bin/python -m benchmarks.docs"
    stale = [n for n in fresh if have[n] != fresh[n]]
    assert not stale, f"not current: {stale}; run: .venv/bin/python -m benchmarks.docs"


def test_every_results_json_has_a_row():
    assert docs.unlisted() == []


def test_generation_is_deterministic(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    docs.write(a)
    docs.write(b)
    assert {p.name: p.read_bytes() for p in a.iterdir()} == {p.name: p.read_bytes() for p in b.iterdir()}


def test_a_changed_json_makes_the_docs_stale(tmp_path):
    results = tmp_path / "results"
    results.mkdir()
    (results / "size.json").write_text(json.dumps({"plants": [{"plant": "a", "usdz_bytes": 1}]}))
    out = tmp_path / "out"
    docs.write(out, results)
    assert docs.stale(out, results) == []
    (results / "size.json").write_text(json.dumps({"plants": [{"plant": "a", "usdz_bytes": 2}]}))
    assert docs.stale(out, results) == ["size.md"]


def test_an_unlisted_json_is_refused(tmp_path):
    (tmp_path / "new_benchmark.json").write_text("{}")
    assert docs.unlisted(tmp_path) == ["new_benchmark.json"]
    with pytest.raises(SystemExit, match="new_benchmark.json"):
        docs.build(tmp_path)


def test_the_renderer_turns_json_shapes_into_tables():
    page = docs.render_page(docs.Result("x.json", "x", "python x.py", "what"), {
        "machine": {"cpu": "c", "isa": ["avx2"], "packages": {"numpy": "2"}},
        "n": 3, "ratio": 0.123456, "tiny": 0.0000123,
        "rows": [{"plant": "a", "m": {"hd": 1.5}, "per_leaf": list(range(20))}],
        "table": {"PCA": {"corr": 0.2}, "ours": {"corr": 0.01}},
        "nested": {"inner": {"deep": [1, 2]}}})
    assert "python x.py" in page and "| cpu | c |" in page and "| numpy | 2 |" in page
    assert "| ratio | 0.1235 |" in page and "| tiny | 1.230e-05 |" in page
    assert "| plant | m.hd |" in page and "`per_leaf`" in page
    assert "| PCA | 0.2 |" in page and "### `nested`" in page
