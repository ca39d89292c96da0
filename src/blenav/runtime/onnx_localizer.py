"""Run an exported cross-phone localizer (:mod:`blenav.learn.crossphone.export`) with onnxruntime, as an app would.

Windows S are (K, B, H) float32 on the thesis scale u: rows in the model's beacon order (:attr:`beacons`),
columns oldest..newest step of ``1 / step_hz`` s, u = rssi_dbm + offset_db (at least floor_u) for a heard
beacon and 0 when not heard (:meth:`OnnxLocalizer.to_u` converts dBm with NaN = not heard). Outputs are
world x, y in metres at each window's last step.

- :meth:`OnnxLocalizer.predict`: independent windows, each from a zero LSTM state;
- :meth:`OnnxLocalizer.step`: one window per call, carrying the LSTM state from call to call (what
  ``LocNet.forward_state`` does when fed its own state back); :meth:`OnnxLocalizer.reset` starts afresh.

No beacon heard -> no fix: a window with every entry 0 gives a NaN row (the network's output there is only
its prior; :meth:`OnnxLocalizer.heard` tells which windows have a reading). In :meth:`~OnnxLocalizer.step`
such a window still advances the LSTM state, exactly as the network would.

Given a :class:`blenav.data.Building`, the loader refuses a model trained for another building or beacon set
(a model of a beacon subset, metadata ``beacon_subset``, accepts a building with more beacons than its own).
It refuses a file whose weights differ from the hash recorded at export (``weights_sha256``, see
:mod:`blenav.onnx_io`), naming the tensors that changed.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from blenav.features.windows import beacon_order, rssi_to_u
from blenav.onnx_io import MIN_FIX_STD_M, STD_OUTPUT, check_weights, read_metadata, session

_EXAMPLES = 5


def _examples(ids: list[str]) -> str:
    more = f", ... ({len(ids) - _EXAMPLES} more)" if len(ids) > _EXAMPLES else ""
    return ", ".join(ids[:_EXAMPLES]) + more


class LocalizerSession:
    """The graph of an exported localizer in an onnxruntime session ``sess`` (inputs S (K, B, H), h0, c0 (layers, K,
    hidden); outputs xy (K, 2) m, h, c, and std_m (K,) m for a LocNet with a std head: :meth:`predict_windows_std`)
    with its decoded metadata ``meta``: the sizes B, H, layers and hidden read
    from the graph, and :meth:`predict_windows` from a zero LSTM state. What :class:`OnnxLocalizer` (one exported
    file) and a runtime bundle's graph (:class:`blenav.runtime.bundle.graphs.LocalizerGraph`) share."""

    def __init__(self, path: str | Path, meta: dict, sess):
        self.path, self._meta, self._sess = Path(path), meta, sess
        s, h = sess.get_inputs()[0].shape, sess.get_inputs()[1].shape
        self.n_beacons, self.history = int(s[1]), int(s[2])
        self.layers, self.hidden = int(h[0]), int(h[2])
        self._has_std = STD_OUTPUT in {o.name for o in sess.get_outputs()}
        if self.n_beacons != len(self.beacons):
            raise ValueError(f"{self.path}: graph reads {self.n_beacons} beacons, metadata lists {len(self.beacons)}")

    @property
    def meta(self) -> dict:
        """Decoded ``metadata_props`` (beacons, window, building, data_hash, model, devices, versions)."""
        return json.loads(json.dumps(self._meta))  # a copy the caller may change

    @property
    def session(self):
        """The underlying ``onnxruntime.InferenceSession`` (inputs S, h0, c0; outputs xy, h, c[, std_m])."""
        return self._sess

    @property
    def beacons(self) -> list[str]:
        return [str(b) for b in self._meta["beacons"]]

    @staticmethod
    def heard(S) -> np.ndarray:
        """(K,) bool: the window has at least one reading (some entry > 0)."""
        S = np.asarray(S)
        return (S > 0).reshape(len(S), -1).any(axis=1)

    def zero_state(self, batch: int) -> tuple[np.ndarray, np.ndarray]:
        z = np.zeros((self.layers, batch, self.hidden), np.float32)
        return z, z.copy()

    def _run(self, S: np.ndarray, h0: np.ndarray, c0: np.ndarray):
        return self._sess.run(["xy", "h", "c"], {"S": S, "h0": h0, "c0": c0})  # by name: a std head adds std_m

    @property
    def has_std(self) -> bool:
        """Whether the graph states a std per fix (output ``std_m``: a LocNet with a std head, issue 29)."""
        return self._has_std

    def predict_windows(self, S: np.ndarray) -> np.ndarray:
        """(K, B, H) float32 windows on the thesis scale (not checked) -> (K, 2) m, each from a zero state; NaN rows
        where no beacon was heard."""
        return self.predict_windows_std(S, std=False)[0]

    def predict_windows_std(self, S: np.ndarray, std: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`predict_windows` and the graph's std per fix (K,) m (None for a graph without ``std_m`` or with
        ``std`` false): NaN where no beacon was heard and where the graph's std is not a finite positive number (a
        float32 overflow: unknown), at least :data:`~blenav.onnx_io.MIN_FIX_STD_M` elsewhere (a foreign graph's
        outputs are data)."""
        S = np.ascontiguousarray(S, dtype=np.float32)
        names = ["xy", STD_OUTPUT] if std and self.has_std else ["xy"]
        if len(S) == 0:
            return np.zeros((0, 2)), np.zeros(0) if len(names) > 1 else None
        z = np.zeros((self.layers, len(S), self.hidden), np.float32)  # h0 = c0 = 0, read-only inputs
        out = [a.astype(float) for a in self._sess.run(names, {"S": S, "h0": z, "c0": z})]
        if out[0].shape != (len(S), 2) or (len(out) > 1 and out[1].shape != (len(S),)):
            raise ValueError(f"{self.path}: the graph gave outputs of shapes {[a.shape for a in out]} for {len(S)} "
                             f"windows (expected xy ({len(S)}, 2) and std_m ({len(S)},)): not a blenav localizer export")
        silent = ~self.heard(S)
        for a in out:
            a[silent] = np.nan
        if len(out) > 1:
            sd = out[1]
            out[1] = np.where(np.isfinite(sd) & (sd > 0), np.maximum(sd, MIN_FIX_STD_M), np.nan)
        return out[0], out[1] if len(out) > 1 else None


class OnnxLocalizer(LocalizerSession):
    """An exported model in an onnxruntime session (``threads`` intra-op threads, sequential execution)."""

    def __init__(self, path: str | Path, building=None, threads: int = 1):
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"ONNX model {path} does not exist")
        sess = session(path, threads)
        self.weights_sha256 = check_weights(path)  # a corrupted or edited file is refused here
        meta = read_metadata(sess)
        names = [i.name for i in sess.get_inputs()]
        if names != ["S", "h0", "c0"] or "beacons" not in meta or "window" not in meta:
            raise ValueError(f"{path} is not a blenav localizer export (inputs {names}, metadata keys "
                             f"{sorted(meta)}); write it with `python export.py ckpt=... out=...`")
        super().__init__(path, meta, sess)
        if building is not None:
            self.check_building(building)
        self.reset()

    # --- metadata ---------------------------------------------------------------------------------------

    @property
    def building(self) -> str | None:
        return self._meta.get("building")

    @property
    def beacon_subset(self) -> str | None:
        """None for a model of all its building's BLE beacons; else the rule that chose its subset
        (``"spread:k"``, ``"list"``): the building's other beacons are left out on purpose."""
        v = self._meta.get("beacon_subset")
        return str(v) if v else None

    def check_building(self, building) -> None:
        """ValueError unless ``building`` has exactly the model's BLE beacons (and its id, when recorded); a
        subset model (:attr:`beacon_subset`) needs all of its beacons and accepts others beside them."""
        have = beacon_order(building)
        want = self.beacons
        lacks = sorted(set(want) - set(have))
        unknown = [] if self.beacon_subset else sorted(set(have) - set(want))
        subset = f" (a subset: {self.beacon_subset})" if self.beacon_subset else ""
        head = (f"model {self.path} was trained for building {self.building!r} with {len(want)} beacons{subset}; "
                f"this building {building.id!r}")
        if lacks or unknown:
            parts = []
            if lacks:
                parts.append(f"lacks {len(lacks)} of them ({_examples(lacks)})")
            if unknown:
                parts.append(f"has {len(unknown)} unknown ({_examples(unknown)})")
            raise ValueError(f"{head} {' and '.join(parts)}; train and export a model for this building")
        if self.building is not None and str(building.id) != str(self.building):
            raise ValueError(f"{head} has the same beacon ids but is another building; "
                             "train and export a model for this building")

    # --- inputs -----------------------------------------------------------------------------------------
    def to_u(self, rssi_dbm) -> np.ndarray:
        """dBm (NaN = not heard) -> thesis scale u with the model's window settings, float32."""
        w = self._meta["window"]
        r = np.asarray(rssi_dbm, dtype=float)
        return np.where(np.isnan(r), 0.0, rssi_to_u(r, w["offset_db"], w["floor_u"])).astype(np.float32)

    def _check(self, S, name: str) -> np.ndarray:
        S = np.asarray(S, dtype=np.float32)
        if S.ndim != 3 or S.shape[1:] != (self.n_beacons, self.history):
            raise ValueError(f"{name} expects windows (K, {self.n_beacons}, {self.history}) (beacons x steps), "
                             f"got {S.shape}")
        if not np.isfinite(S).all():
            raise ValueError(f"{name}: windows contain NaN/inf; use 0 for a beacon not heard")
        if (S < 0).any():
            raise ValueError(f"{name}: windows must be on the thesis scale u >= 0 (rssi_dbm + "
                             f"{self._meta['window'].get('offset_db')}), found {float(S.min()):.1f}; dBm given? "
                             "see to_u()")
        return np.ascontiguousarray(S)

    # --- inference --------------------------------------------------------------------------------------
    def predict(self, S) -> np.ndarray:
        """(K, B, H) windows -> (K, 2) metres, each from a zero state; NaN rows where no beacon was heard."""
        return self.predict_windows(self._check(S, "predict"))

    def predict_std(self, S) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`predict` and the graph's std per fix (K,) m (:meth:`predict_windows_std`; None without one)."""
        return self.predict_windows_std(self._check(S, "predict_std"))

    def step(self, S) -> np.ndarray:
        """One window (1, B, H) (or (B, H)) -> (1, 2) metres, continuing the state of the previous call.
        NaN when no beacon was heard (the state still advances)."""
        S = np.asarray(S, dtype=np.float32)
        if S.ndim == 2:
            S = S[None]
        S = self._check(S, "step")
        if len(S) != 1:
            raise ValueError(f"step takes one window (1, {self.n_beacons}, {self.history}), got {S.shape}")
        xy, self._h, self._c = self._run(S, self._h, self._c)
        xy = xy.astype(float)
        xy[~self.heard(S)] = np.nan
        return xy

    def reset(self) -> None:
        """Forget the streaming state (next :meth:`step` starts from zeros)."""
        self._h, self._c = self.zero_state(1)

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the streaming (h, c), each (layers, 1, hidden)."""
        return self._h.copy(), self._c.copy()

    def __repr__(self) -> str:
        return (f"OnnxLocalizer({str(self.path)!r}, model={self._meta.get('model_name')!r}, "
                f"building={self.building!r}, B={self.n_beacons}, H={self.history})")
