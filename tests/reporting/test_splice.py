"""blenav.reporting: the one splice helper and the docs tables' command line (python -m blenav.cli.tables)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from blenav.reporting.splice import markers, splice


def test_splice_replaces_the_block_and_keeps_the_rest(tmp_path):
    start, end = markers("t")
    assert (start, end) == ("<!-- t -->", "<!-- /t -->")
    page = tmp_path / "page.md"
    page.write_text(f"head\n  {start}\nold 1\nold 2\n{end}  tail\n{end}\n")
    assert splice(page, "| a | 1.00 |", "t") is True
    assert page.read_text() == f"head\n  {start}\n| a | 1.00 |\n{end}  tail\n{end}\n"
    assert splice(page, "| a | 2.00 |", "t") and page.read_text().count("| a |") == 1  # idempotent block
    assert sorted(p.name for p in tmp_path.iterdir()) == ["page.md"]  # atomic: no temporary file left


def test_splice_without_markers_appends_only_when_asked(tmp_path):
    readme, page = tmp_path / "README.md", tmp_path / "page.md"
    readme.write_text("no markers\n")
    page.write_text("text\n")
    assert splice(readme, "body", "t") is False and readme.read_text() == "no markers\n"
    assert splice(page, "body", "t", append=True) is True
    assert page.read_text() == "text\n\n<!-- t -->\nbody\n<!-- /t -->\n"
    assert splice(tmp_path / "new.md", "b", "t", append=True) and (tmp_path / "new.md").read_text() == \
        "\n<!-- t -->\nb\n<!-- /t -->\n"
    half = tmp_path / "half.md"  # a start marker without its end: left alone, not cut
    half.write_text("<!-- t -->\nkeep\n")
    assert splice(half, "x", "t") is False and half.read_text() == "<!-- t -->\nkeep\n"


def test_splice_reads_the_end_marker_after_the_start_marker(tmp_path):
    """An end marker above the block (a stray one, or another block's quoted) is text: the block ends at the first
    end marker after its start, and a second splice writes the same file."""
    start, end = markers("t")
    page = tmp_path / "page.md"
    page.write_text(f"see {end} above\n{start}\nold\n{end}\ntail\n")
    assert splice(page, "new", "t") is True
    once = page.read_text()
    assert once == f"see {end} above\n{start}\nnew\n{end}\ntail\n"
    assert splice(page, "new", "t") and page.read_text() == once
    orphan = tmp_path / "orphan.md"  # an end marker, then a start marker without its end: no block, left alone
    orphan.write_text(f"{end}\nkeep\n{start}\nkeep too\n")
    assert splice(orphan, "x", "t") is False and orphan.read_text() == f"{end}\nkeep\n{start}\nkeep too\n"


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "blenav.cli.tables", *map(str, args)], capture_output=True, text=True,
                          timeout=120, cwd=cwd)


def _results(folder, dataset, rmse):
    folder.mkdir(parents=True)
    methods = {k: {"family": "PF classical", "rmse_m": {"mean": v}, "per_session": {"s0": {"rmse_m": {"mean": v}}}}
               for k, v in rmse.items()}
    (folder / "results.json").write_text(json.dumps({"dataset": dataset, "sessions": ["s0"], "runs": 1,
                                                     "methods": methods}))


def test_tables_merge_and_leaderboard(tmp_path):
    _results(tmp_path / "a", "data/a", {"PF": 2.0, "RW": 4.0})
    _results(tmp_path / "b", "data/b", {"PF": 3.0})
    r = _run("merge", tmp_path / "m.md", "T", tmp_path / "a", f"{tmp_path / 'b'}:own/")
    assert r.returncode == 0, r.stderr
    md = (tmp_path / "m.md").read_text()
    assert "| session | PF | RW | own/PF |" in md and "| s0 | 2.00 | 4.00 | 3.00 |" in md
    r = _run("leaderboard", tmp_path / "lb.md", "L", tmp_path / "a", tmp_path / "b")
    assert r.returncode == 0, r.stderr
    merged = json.loads((tmp_path / "lb.json").read_text())
    assert merged["methods"]["PF"]["pooled_rmse_m"] == pytest.approx(2.5) and merged["methods"]["PF"]["datasets"] == 2
    assert "| 1 | PF | PF classical | 2.00 | 3.00 | 2.50 | 2 | 2 |" in (tmp_path / "lb.md").read_text()


def test_tables_errors_are_one_line(tmp_path):
    r = _run("leaderboard", tmp_path / "x.md", "T", tmp_path / "nothing")
    assert r.returncode == 1 and r.stderr.strip().splitlines() == [
        f"python -m blenav.cli.tables: error: {tmp_path / 'nothing'}: no results.json there nor in its sub-folders"]
    (tmp_path / "odd").mkdir()
    (tmp_path / "odd" / "results.json").write_text("{}")
    r = _run("merge", tmp_path / "x.md", "T", tmp_path / "odd")
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1 and "odd/results.json: no 'methods' table" in r.stderr
    r = _run("crf", tmp_path)
    assert r.returncode == 2 and r.stderr.startswith("usage: python -m blenav.cli.tables merge")
    assert not (tmp_path / "x.md").exists()
