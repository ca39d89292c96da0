"""learn/ is one package per model over one shared learn/common (issue 27, section 3).

The import graph of ``src/blenav/learn`` (every import: module level, lazy and type-only, as tests/test_layers.py
counts them) has these edges between its packages only: ``common`` imports no model package; ``crossphone``,
``mapprior`` and ``inertial`` import ``common`` and not each other; ``fingerprint`` runs the cross-phone pipeline (``crossphone``,
``common`` and the ``train`` entry); the entries ``train``, ``export`` (and ``bundle`` over it) and ``reference`` sit above the models.
"""

from __future__ import annotations

from helpers import import_graph

PACKAGES = ("common", "crossphone", "mapprior", "fingerprint", "inertial")
#: package (or top-level module of learn) -> the packages / modules of learn it may import
ALLOWED = {
    "common": {"common"},
    "crossphone": {"common", "crossphone"},
    "mapprior": {"common", "mapprior"},
    "inertial": {"common", "inertial"},
    "fingerprint": {"common", "crossphone", "fingerprint", "train"},
    "train": {"crossphone", "mapprior", "inertial"},
    "export": {"common", "crossphone", "mapprior", "inertial"},
    "bundle": {"common", "export"},
    "reference": {"crossphone", "mapprior"},
}


def part(module: str) -> str | None:
    """``blenav.learn.crossphone.train`` -> ``crossphone``; ``blenav.learn`` -> None."""
    rest = module.removeprefix("blenav.learn").lstrip(".")
    return rest.split(".")[0] or None


def wrong_way(graph: dict[str, set[str]]) -> list[str]:
    """The edges of ``graph`` from one part of learn/ to another that :data:`ALLOWED` does not list."""
    return sorted(f"{m} -> {d}" for m, deps in graph.items() for d in deps
                  if m.startswith("blenav.learn.") and d.startswith("blenav.learn.") and part(d) not in ALLOWED[part(m)])


def test_the_check_catches_common_importing_a_model(tmp_path):
    learn = tmp_path / "blenav" / "learn"
    for pkg in ("common", "crossphone"):
        (learn / pkg).mkdir(parents=True)
        (learn / pkg / "__init__.py").write_text("")
    (tmp_path / "blenav" / "__init__.py").write_text("")
    (learn / "__init__.py").write_text("")
    (learn / "common" / "a.py").write_text("def f():\n    from blenav.learn.crossphone import b\n")  # lazy, wrong way
    (learn / "crossphone" / "b.py").write_text("from ..common import a\n")  # a model on common: fine
    assert wrong_way(import_graph(tmp_path)) == ["blenav.learn.common.a -> blenav.learn.crossphone.b"]


def test_learn_has_one_package_per_model_over_common():
    graph = {m: deps for m, deps in import_graph().items() if m.startswith("blenav.learn")}
    parts = {part(m) for m in graph} - {None}
    assert parts == set(ALLOWED), f"learn/ holds {sorted(parts)}; place a new module in a package of {PACKAGES}"
    bad = wrong_way(graph)
    assert not bad, "imports across learn/'s packages that point the wrong way:\n" + "\n".join(bad)
    assert "blenav.learn.common.trainer" in graph and "blenav.learn.mapprior.train" in graph
