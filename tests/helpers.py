"""Small synthetic datasets for tests, built with the project's writer (no simulator needed), and the import graph
of src/blenav (:func:`import_graph`)."""

from __future__ import annotations

import ast
import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from shapely.geometry import LineString, box

from blenav.data import FREE, OCCUPIED
from blenav.data.writer import write_building, write_dataset_meta, write_session

#: The repository's root (the folder of pyproject.toml), whatever the depth of the test module asking.
REPO = next(p for p in Path(__file__).resolve().parents if (p / "pyproject.toml").is_file())
#: ../shared beside the clone; $BLENAV_SHARED names another (a git worktree elsewhere, say).
SHARED = Path(os.environ.get("BLENAV_SHARED") or REPO.parent / "shared")
RAW = SHARED / "data" / "raw"
#: the source tree whose import graph the layer checks read
SRC = REPO / "src"


def simulate_small(out: Path, seed: int, duration_s: float, sessions: int, *overrides: str) -> Path:
    """The simulator's ``small`` preset, pedestrian walks only (``overrides``: more ``sim.*`` keys), into ``out``."""
    from blenav.cli.sim import run as sim_run
    from blenav.configs import compose

    sim_run(compose("sim", "sim=small", f"seed={seed}", f"out={out}", f"duration_s={duration_s}", f"sessions={sessions}",
                    "progress=false", "sim.carriers=[pedestrian]", *overrides))
    return Path(out)


def as_waypoint_walks(root: Path) -> Path:
    """Turn a simulated dataset into ILC-like walks: ground truth every 5 s only (groundtruth_kind: waypoints), the
    ground-truth orientation as the phone's orientation.csv, no odometry.csv."""
    for d in sorted((root / "sessions").iterdir()):
        gt = pd.read_csv(d / "groundtruth.csv")
        gt[["t", "qw", "qx", "qy", "qz"]].to_csv(d / "orientation.csv", index=False)
        keep = np.r_[np.flatnonzero(np.diff(np.floor(gt["t"].to_numpy() / 5.0), prepend=-1) > 0)]
        gt.iloc[keep].assign(qw=np.nan, qx=np.nan, qy=np.nan, qz=np.nan).to_csv(d / "groundtruth.csv", index=False)
        (d / "odometry.csv").unlink(missing_ok=True)
        meta = yaml.safe_load((d / "session.yaml").read_text())
        meta.update(groundtruth_kind="waypoints", orientation_frame="enu-magnetic")
        (d / "session.yaml").write_text(yaml.safe_dump(meta))
    return root


def copy_raw(src: Path, dst: Path) -> Path:
    """A writable copy of a (read-only) raw folder."""
    shutil.copytree(src, dst, copy_function=shutil.copyfile)
    for p in [dst, *dst.rglob("*")]:
        os.chmod(p, 0o755 if p.is_dir() else 0o644)
    return dst


def edit_line(path: Path, line: int, fn) -> None:
    """Replace 1-based ``line`` of ``path`` by ``fn(old_line)`` (keeps the file's line endings)."""
    raw = path.read_bytes().decode("utf-8")
    lines = raw.splitlines(keepends=True)
    old = lines[line - 1]
    body = old.rstrip("\r\n")
    lines[line - 1] = fn(body) + old[len(body):]
    path.write_text("".join(lines), encoding="utf-8", newline="")


def refused_import(kind: str, src: Path, out: Path, rel: str, line: int):
    """Import ``src`` as ``kind`` into ``out`` expecting the refusal of line ``line`` of file ``rel``: the error names
    the file and the line (``name:line`` in its message) and nothing was written; returns the error."""
    import pytest

    from blenav.errors import ImportError_
    from blenav.importers import run_import

    with pytest.raises(ImportError_) as ei:
        run_import(kind, src, out)
    e = ei.value
    assert Path(e.path).name == Path(rel).name and e.line == line, str(e)
    assert f"{Path(rel).name}:{line}" in str(e)
    assert not (out / "sessions").exists()  # nothing written
    return e


def tiny_grid(w_m: float = 10.0, h_m: float = 8.0, res: float = 0.1) -> np.ndarray:
    """Occupancy (H, W) with outer walls and one inner wall with a door (row 0 on top)."""
    h, w = int(round(h_m / res)), int(round(w_m / res))
    occ = np.full((h, w), FREE, dtype=np.int8)
    occ[:2, :] = occ[-2:, :] = occ[:, :2] = occ[:, -2:] = OCCUPIED
    occ[:, w // 2 : w // 2 + 2] = OCCUPIED
    occ[h // 2 - 5 : h // 2 + 5, w // 2 : w // 2 + 2] = FREE  # door
    return occ


def make_tiny_dataset(root: Path, seed: int = 0, duration_s: float = 20.0) -> Path:
    """A 10 m x 8 m two-room building, 4 BLE beacons, 1 RTT AP, one labelled walking session."""
    rng = np.random.default_rng(seed)
    root = Path(root)
    write_dataset_meta(root, "tiny", "unit-test dataset", "CC0", "tests/helpers.py")
    anchors = pd.DataFrame({
        "anchor_id": ["b1", "b2", "b3", "b4", "ap1"], "kind": ["ble"] * 4 + ["wifi_rtt"],
        "x": [1.0, 9.0, 1.0, 9.0, 5.0], "y": [1.0, 1.0, 7.0, 7.0, 4.0], "z": [2.5] * 5, "floor": [0] * 5,
        "tx_power_dbm": [-59.0, -59.0, np.nan, -59.0, np.nan], "channel_model": ["test"] * 5})
    rooms = [{"id": "west", "floor": 0, "geometry": box(0.2, 0.2, 4.9, 7.8)},
             {"id": "east", "floor": 0, "geometry": box(5.1, 0.2, 9.8, 7.8)}]
    nav = [{"id": "e0", "floor": 0, "geometry": LineString([(2.5, 4.0), (7.5, 4.0)])}]
    write_building(root, "house", "tiny house", [{"id": 0, "occupancy": tiny_grid(), "resolution": 0.1,
                                                   "origin": (0.0, 0.0)}], anchors, rooms, nav)
    t_gt = np.arange(0, duration_s, 0.1)
    x = 2.5 + 5.0 * t_gt / duration_s
    y = np.full_like(x, 4.0)
    gt = pd.DataFrame({"t": t_gt, "x": x, "y": y, "z": 1.2, "qw": 1.0, "qx": 0.0, "qy": 0.0, "qz": 0.0})
    t_imu = np.arange(0, duration_s, 0.01)
    imu = pd.DataFrame({"t": t_imu, "ax": rng.normal(0, 0.1, t_imu.size), "ay": rng.normal(0, 0.1, t_imu.size),
                        "az": 9.81 + rng.normal(0, 0.1, t_imu.size), "gx": 0.0, "gy": 0.0, "gz": 0.0})
    t_b = np.repeat(np.arange(0, duration_s, 0.2), 4)
    ids = np.tile(["b1", "b2", "b3", "b4"], t_b.size // 4)
    rssi = pd.DataFrame({"t": t_b, "anchor_id": ids, "rssi": np.round(rng.normal(-75, 4, t_b.size))})
    write_session(root, "walk0", {"building": "house", "floor": 0, "device_model": "test-phone",
                                  "carrier": "pedestrian", "labelled": True},
                  {"imu": imu, "rssi": rssi, "groundtruth": gt})
    return root


# ------------------------------------------------------------------ validator issues (test_validate, test_data_errors)
def rel(root: Path, issue) -> str:
    """The issue's file relative to the dataset root (posix), or its path as given."""
    p = Path(issue.path)
    try:
        return p.relative_to(root).as_posix()
    except ValueError:
        return p.as_posix()


def errors(issues):
    return [i for i in issues if i.is_error]


# ------------------------------------------------------------------ editing CSV files in tests
def lines(path: Path) -> list[str]:
    return path.read_text(encoding="utf-8").splitlines()


def write_lines(path: Path, text_lines: list[str]) -> None:
    path.write_text("\n".join(text_lines) + "\n", encoding="utf-8")


def set_cell(path: Path, line: int, column: str, value: str) -> None:
    """Replace one cell of a CSV (``line`` 1-based, header = 1)."""
    ls = lines(path)
    col = ls[0].split(",").index(column)
    cells = ls[line - 1].split(",")
    cells[col] = value
    ls[line - 1] = ",".join(cells)
    write_lines(path, ls)


def seeded(seed: int, build):
    """``build()`` with the global torch RNG seeded and restored after: modules with a fixed weight initialisation,
    no global random state touched."""
    import torch

    with torch.random.fork_rng():
        torch.manual_seed(seed)
        return build()


def training_node() -> dict:
    """The networks' training node (data, trainer, models) conf/localizer/fingerprint.yaml composes into a method's
    node, as blenav-eval hands it to the localizer."""
    from omegaconf import OmegaConf

    from blenav.configs import compose

    cfg = compose("eval", "+localizer@methods.fp=fingerprint")
    return OmegaConf.to_container(cfg.methods.fp.training, resolve=True)


def streamed(online, events, t_end: float) -> np.ndarray:
    """Positions (R, K, 2) an :class:`blenav.filters.online.OnlineLocalizer` gives for ``events`` (pushed in order,
    e.g. :func:`blenav.filters.online.replay` of a session) and closed at ``t_end`` (s): the batch run's
    :class:`~blenav.filters.estimate.Estimate` ``position`` when the streaming API reproduces it."""
    out = []
    for e in events:
        out += online.push_event(e)
    out += online.close(t_end)
    return np.stack([r.position for r in out], axis=1)


def modules(root: Path = SRC) -> dict[str, Path]:
    """Dotted module name -> file, for every .py below ``root/blenav`` (a package by its ``__init__``)."""
    out = {}
    for p in sorted((root / "blenav").rglob("*.py")):
        parts = p.relative_to(root).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def import_graph(root: Path = SRC, skip=()) -> dict[str, set[str]]:
    """Module -> the blenav modules it imports (module level, inside functions and under ``if TYPE_CHECKING:``;
    ``from m import name`` counts ``m.name`` when that is a module, else ``m``), less the (importer, imported)
    edges in ``skip``. tests/test_layers.py checks the layers and cycles on it, tests/learn/test_packages.py learn/'s
    packages."""
    mods = modules(root)
    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        deps: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    deps.add(a.name)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    m = ".".join(base + ([node.module] if node.module else []))
                else:
                    m = node.module or ""
                named = [f"{m}.{a.name}" for a in node.names if f"{m}.{a.name}" in mods]
                deps |= set(named) if named and len(named) == len(node.names) else {m, *named}
        graph[name] = {d for d in deps if d in mods and d != name and (name, d) not in skip}
    return graph


class RowModel:
    """A deterministic stand-in inertial network (:class:`blenav.filters.inertial_odometry.VelocityModel`), row by row
    (so a batch of 512 and a batch of 1 agree to the bit): the velocity from the window's mean accelerations and its
    last gyro sample, the log variance from their spread; ``frame``: world or heading; ``yaw``: the attitude's own or
    the gyroscope's held to it (blenav.filters.yaw_hold)."""

    def __init__(self, frame: str, yaw: str = "attitude"):
        from blenav.features.inertial import InertialGrid

        self.grid, self.frame, self.yaw = InertialGrid(rate_hz=50.0, window_s=1.0, stride_s=0.5), frame, yaw
        self.key = f"row-{yaw}"
        self.attitude = "auto"  # the attitude it "was trained in", as an export says (blenav.runtime.inertial)

    def odometry(self, session, attitude: str | None = None, cache: dict | None = None):
        """The track, as :meth:`blenav.runtime.inertial.InertialModel.odometry` gives it."""
        from blenav.filters.inertial_odometry import lio_odometry

        return lio_odometry(session, self, attitude or self.attitude, cache=cache)

    def predict(self, W):
        W = np.asarray(W, np.float64)
        v = np.stack([W[:, :, 0].mean(1) + 0.3 * W[:, -1, 5], W[:, :, 1].mean(1) - 0.2 * W[:, :, 3].std(1)], 1)
        return v, np.stack([np.log1p(W[:, :, 0].var(1)), -1.0 + W[:, :, 2].mean(1) * 0.01], 1)


def exported_streaming(loc, B: int, H: int, layers: int, hidden: int, path, batches=(1, 3), u_max: float = 70.0):
    """``loc`` (a LocNet-like network, its std stated) wrapped as the cross-phone export's streaming graph, traced to
    ONNX at ``path`` and checked: outputs xy, h, c, std_m, and onnxruntime equal to PyTorch within 1e-4 for each batch
    size of ``batches`` (random windows up to ``u_max``, random state). Returns (the wrapper, the path)."""
    from blenav.learn.crossphone.export import StreamingLocalizer, export_onnx, onnx_max_diff, random_inputs
    from blenav.onnx_io import session

    m = StreamingLocalizer(loc, None, u_scale=100.0).eval()
    path = export_onnx(m, random_inputs(B, H, layers, hidden, batch=2, u_max=70, zero_state=True), path)
    assert [o.name for o in session(path).get_outputs()] == ["xy", "h", "c", "std_m"]
    for batch in batches:
        assert onnx_max_diff(path, m, random_inputs(B, H, layers, hidden, batch=batch, seed=batch, u_max=u_max)) < 1e-4
    return m, path
