"""The layers of blenav import in one direction (issue 13, section 2; issue 27, section 4).

1. The layers a phone or gateway runs load no torch, lightning or hydra: importing every module of ``blenav.data``,
   ``blenav.features``, ``blenav.filters``, ``blenav.crf``, ``blenav.runtime``, ``blenav.sim`` and
   ``blenav.importers`` (and ``blenav.onnx_io``) in a fresh interpreter leaves them out of ``sys.modules``; the
   networks (``blenav.models``) load torch but neither lightning nor hydra.
2. Every module belongs to one layer of :data:`LAYERS` (bottom-up) and imports only modules of its own layer or of
   lower ones: filters below runtime, learn below the localizers, ``blenav.configs`` (which composes ``conf/``)
   above everything but the command lines, so that only entry points (``blenav.cli``, ``train.py``,
   ``export.py``) compose a config and hand the nodes down.
3. No import cycles between the modules of ``src/blenav``.

The graph counts every ``import`` statement of a module: at module level, inside functions (a lazy import hides a
cycle or an upward edge, it does not remove it) and under ``if TYPE_CHECKING:`` (a type-only import is still a
dependency of the code that reads it). A justified import that closes a cycle must be listed in :data:`ALLOWED`
with the reason.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from helpers import SRC, import_graph, modules

LOWER = ("blenav.data", "blenav.features", "blenav.filters", "blenav.runtime", "blenav.sim", "blenav.importers",
         "blenav.onnx_io", "blenav.crf")
HEAVY = ("torch", "lightning", "hydra")
#: (importer, imported) edges left out of the cycle and layer checks, each with its reason; none needed today
ALLOWED: dict[tuple[str, str], str] = {}

#: The layers, bottom-up. A module (or package, with everything below it) named here belongs to that layer and may
#: import its own layer and the ones before it; ``blenav`` is the package's ``__init__`` alone. A new top-level
#: module or package must be placed here (test_every_module_has_a_layer).
LAYERS: tuple[tuple[str, ...], ...] = (
    # stdlib / numpy helpers that know no other blenav module: paths, the shared exceptions, trust and size limits,
    # the ONNX file helpers
    ("blenav", "blenav.paths", "blenav.errors", "blenav.trust", "blenav.limits", "blenav.onnx_io"),
    ("blenav.data",),                    # the dataset format: schema, readers, writer, validator
    ("blenav.radio_stats",),             # statistics of a dataset's radio streams
    ("blenav.features",),                # windows, fingerprints, scales, map grids
    ("blenav.sim", "blenav.importers"),  # datasets made (simulator) or converted (importers)
    ("blenav.filters",),                 # the particle filter, its models, the batch and streaming runners
    ("blenav.crf",),                     # the CRF / Viterbi localizer's tables
    ("blenav.runtime",),                 # bundles, ONNX localizers, the map prior's runtime (no torch)
    ("blenav.models",),                  # the torch networks
    ("blenav.plotting",),                # matplotlib figures (learn and eval import it lazily)
    ("blenav.learn",),                   # training, export, baselines
    ("blenav.localizers",),              # the methods behind one interface (they may train: learn is below)
    ("blenav.backend",),                 # the factor-graph back-end, one of the localizers
    ("blenav.eval",),                    # the evaluation harness and its experiments
    ("blenav.reporting",),               # the README / docs tables written from evaluations' results
    ("blenav.configs",),                 # composes conf/ (Hydra): only entry points call it
    ("blenav.cli", "blenav.__main__"),   # the command lines (python -m blenav: the blenav command)
)


def import_all(tops: tuple[str, ...], heavy: tuple[str, ...]) -> dict:
    """Import every module of the packages ``tops`` in a fresh interpreter: {"modules": their names, "heavy": the
    names of ``heavy`` then in ``sys.modules``}."""
    code = f"""
import importlib, json, pkgutil, sys
names = []
for top in {tops!r}:
    mod = importlib.import_module(top)
    names.append(top)
    if hasattr(mod, "__path__"):
        for info in pkgutil.walk_packages(mod.__path__, top + "."):
            importlib.import_module(info.name)
            names.append(info.name)
print(json.dumps({{"modules": names, "heavy": sorted(m for m in {heavy!r} if m in sys.modules)}}))
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_lower_layers_import_without_torch_lightning_hydra():
    out = import_all(LOWER, HEAVY)
    assert "blenav.runtime.map_prior" in out["modules"] and "blenav.features.windows" in out["modules"]
    assert out["heavy"] == [], f"importing {LOWER} loads {out['heavy']}"


def test_the_networks_import_without_lightning_hydra():
    """docs/architecture.md: ``models`` holds plain ``nn.Module``s; Lightning wraps them in ``learn/``."""
    out = import_all(("blenav.models",), HEAVY)
    assert "blenav.models.mapprior" in out["modules"]
    assert out["heavy"] == ["torch"], f"importing blenav.models loads {out['heavy']}"


# --- the module graph ------------------------------------------------------------------------------------

def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle [a, b, ..., a] of ``graph``, or None (iterative depth-first search)."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    for start in sorted(graph):
        if state.get(start):
            continue
        stack = [(start, iter(sorted(graph[start])))]
        path = [start]
        state[start] = 1
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                state[node] = 2
                stack.pop()
                path.pop()
            elif state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            elif not state.get(nxt):
                state[nxt] = 1
                path.append(nxt)
                stack.append((nxt, iter(sorted(graph.get(nxt, ())))))
    return None


def test_cycle_finder_finds_a_lazy_import_cycle(tmp_path):
    pkg = tmp_path / "blenav"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from blenav import b\n")
    (pkg / "b.py").write_text("def f():\n    from .a import x\n")
    (pkg / "c.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from blenav import d\n")
    (pkg / "d.py").write_text("from . import c\n")
    graph = import_graph(tmp_path)
    assert graph["blenav.a"] == {"blenav.b"} and graph["blenav.b"] == {"blenav.a"}
    assert graph["blenav.c"] == {"blenav.d"} and graph["blenav.d"] == {"blenav.c"}  # a type-only import counts
    assert find_cycle(graph) in (["blenav.a", "blenav.b", "blenav.a"], ["blenav.b", "blenav.a", "blenav.b"])
    assert find_cycle({"x": {"y"}, "y": set()}) is None


def test_no_import_cycles():
    graph = import_graph(skip=ALLOWED)
    assert "blenav.learn.train" in graph and "blenav.runtime.map_prior" in graph
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def layer_of(module: str) -> int | None:
    """The index in :data:`LAYERS` of ``module`` (its longest listed prefix; ``blenav`` only for itself), or None."""
    best, found = -1, None
    for i, names in enumerate(LAYERS):
        for n in names:
            hit = module == n if n == "blenav" else module == n or module.startswith(n + ".")
            if hit and len(n) > best:
                best, found = len(n), i
    return found


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """The edges of ``graph`` that point to a higher layer, as 'importer (layer) -> imported (layer)'."""
    name = lambda i: LAYERS[i][0]
    return [f"{m} ({name(layer_of(m))}) -> {d} ({name(layer_of(d))})" for m, deps in sorted(graph.items())
            for d in sorted(deps) if layer_of(m) is not None and layer_of(d) is not None and layer_of(d) > layer_of(m)]


def test_layer_check_catches_an_upward_import(tmp_path):
    pkg = tmp_path / "blenav"
    (pkg / "filters").mkdir(parents=True)
    (pkg / "runtime").mkdir()
    for p in ("__init__.py", "filters/__init__.py", "runtime/__init__.py", "paths.py"):
        (pkg / p).write_text("")
    (pkg / "filters" / "a.py").write_text("def f():\n    from blenav.runtime import b\n")  # lazy, upward
    (pkg / "runtime" / "b.py").write_text("from blenav.filters import a\nfrom blenav import paths\n")  # downward
    assert upward_imports(import_graph(tmp_path)) == [
        "blenav.filters.a (blenav.filters) -> blenav.runtime.b (blenav.runtime)"]
    assert layer_of("blenav") == 0 and layer_of("blenav.filters.map.geometry") == layer_of("blenav.filters")
    assert layer_of("blenav.nosuchmodule") is None and layer_of("blenav.datafoo") is None


def test_every_module_has_a_layer():
    missing = sorted(m for m in modules() if layer_of(m) is None)
    assert not missing, f"modules in no layer of LAYERS (place them in tests/test_layers.py): {missing}"


def test_every_import_points_to_the_same_or_a_lower_layer():
    """Module level, lazy and type-only imports alike: no module imports a layer above its own."""
    up = upward_imports(import_graph(skip=ALLOWED))
    assert not up, "imports that point up the layers:\n" + "\n".join(up)


def test_runtime_map_prior_runs_a_checkpoint_only_with_the_loader_it_is_handed(tmp_path):
    """runtime.MapPrior imports nothing of learn/: a checkpoint file needs a loader from the caller."""
    import numpy as np
    import pytest

    from blenav.runtime import MapPrior

    ck = tmp_path / "last.ckpt"
    ck.write_bytes(b"not read")
    with pytest.raises(ValueError, match=r"loader=blenav\.learn\.mapprior\.checkpoint\.TorchBackend"):
        MapPrior(ck)

    class Backend:  # what a loader returns (blenav.learn.mapprior.checkpoint.TorchBackend for a real one)
        meta = {"resolution_m": 0.5, "window": {"window_s": 5.0, "step_hz": 1.0, "n_points": 6}, "channels": 3}
        weights_hash = "fake"

        def __init__(self, path):
            self.path = path

        def encode_map(self, mask):
            return np.zeros((3, *mask.shape), np.float32)

        def encode_trajectory(self, odo_px):
            return np.ones((len(odo_px), 3), np.float32)

    prior = MapPrior(ck, loader=Backend)
    assert prior._backend.path == ck and prior.n_points == 6 and prior.weights_hash == "fake"
    assert prior.dtv(np.zeros((2, 6, 2))).shape == (2, 3)


#: the most lines a module of src/blenav may have without saying at its top why it is one file
MAX_LINES = 500
#: the words that give that reason, in the module's first 20 lines
REASON = "one file because"


def long_modules(root: Path = SRC, max_lines: int = MAX_LINES) -> list[str]:
    """The modules of ``root/blenav`` over ``max_lines`` lines whose first 20 lines do not say why (:data:`REASON`)."""
    out = []
    for name, path in modules(root).items():
        lines = path.read_text(encoding="utf-8").splitlines()
        if len(lines) > max_lines and not any(REASON in ln for ln in lines[:20]):
            out.append(f"{name} ({len(lines)} lines)")
    return out


def test_no_module_over_500_lines_without_its_reason(tmp_path):
    pkg = tmp_path / "blenav"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "big.py").write_text("x = 1\n" * 501)
    (pkg / "told.py").write_text(f'"""Kept as {REASON} its parts share one state."""\n' + "x = 1\n" * 600)
    (pkg / "small.py").write_text("x = 1\n" * 500)
    assert long_modules(tmp_path) == ["blenav.big (501 lines)"]
    assert long_modules() == [], "split these along their sections, or say at the top why each is one file"
