"""An evaluation's result as typed objects: :class:`EvalResult` (one experiment) of :class:`MethodResult` (one method).

Every evaluator returns an :class:`EvalResult`; :func:`write_results` is the one writer of ``results.json`` and
``results.md``, and :func:`summary_lines` the console summary, both reading fields. ``results.json`` is
:meth:`EvalResult.to_json`: the keys and their order are those the evaluations wrote as plain dicts before
(blenav.eval.harness documents the schema), so a run gives the same file byte for byte.

Three kinds of method rows (:attr:`MethodResult.kind`):

* ``trajectory``: a localizer's estimates scored against the ground truth (:mod:`blenav.eval.harness`):
  ``metrics`` (pooled ``rmse_m``, ``error_m``, ``ate_m``, ...), timing, recoveries, ``confined``, ``per_session``;
* ``windows``: a learned or baseline localizer scored per RSSI window (:mod:`blenav.eval.crossphone`):
  ``metrics`` (``error_m``, ``rmse_m``) and :class:`WindowStats` (per device, per brand, training, timing);
* ``bound``: the PCRLB rows of the leaderboard (:mod:`blenav.eval.pcrlb`): ``metrics`` and :class:`BoundStats`.

``EvalResult`` is also a read-only mapping of the results.json view (``res["methods"]["PF-PL"]["rmse_m"]``), for
scripts and tests that read results as results.json does.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["MethodResult", "WindowStats", "BoundStats", "EvalResult", "TrajectoryResult", "WindowResult",
           "write_results", "summary_lines"]


@dataclass
class WindowStats:
    """What a window-level comparison adds per method: error stats per device model and per brand, the seconds to
    train (None: a complete run reused) and to predict, the windows scored, and where the model came from."""

    per_device: dict
    per_brand: dict
    train_s: float | None
    predict_s: float
    n_windows: int
    source: str


@dataclass
class BoundStats:
    """What a bound row adds (:func:`blenav.eval.pcrlb.bound_entries`): the ``settings`` it was computed with (None on
    data without the simulator's parameters: skipped), and per session the anchors heard whose position anchors.csv
    lacks (``no_position``; their packets are not counted)."""

    settings: dict | None = None
    no_position: dict = field(default_factory=dict)


#: a trajectory method's optional summaries, written in this order after its timing when set
OPTIONAL_KEYS = ("beacon_error_m", "orientation_rmse_deg", "fix_coverage", "convergence", "segment_error_m")


@dataclass
class MethodResult:
    """One method of an experiment. ``metrics``: the pooled summaries in the order written (empty: the method ran
    on no session); ``skipped``: session id -> why the method could not run there; ``per_session``: session id ->
    that session's summaries. The optional fields are written only when set (None)."""

    kind: str = "trajectory"  # trajectory | windows | bound
    metrics: dict = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    wall_s: float | None = None
    realtime_factor: float | None = None
    recoveries: int | None = None
    map_notes: list[str] | None = None
    confined: dict | None = None
    beacon_error_m: dict | None = None
    orientation_rmse_deg: float | None = None
    fix_coverage: dict | None = None  # role -> {1sigma, 2sigma, waypoints}: the fixes a fused method was given, their own std
    convergence: dict | None = None  # a fused method: time until it settles within 5 m (metrics.pool_convergence)
    segment_error_m: dict | None = None  # waypoint walks: displacement error per waypoint segment (metrics.segment_errors)
    per_session: dict = field(default_factory=dict)
    windows: WindowStats | None = None
    bound: BoundStats | None = None
    peak_memory: dict | None = None
    training: Any = None
    family: str | None = None
    best: dict | None = None  # a bound's: the best method's RMSE and its ratio to the bound

    @property
    def ran(self) -> bool:
        """Whether the method gave scored estimates on at least one session."""
        return "rmse_m" in self.metrics

    @property
    def rmse_mean(self) -> float | None:
        return float(self.metrics["rmse_m"]["mean"]) if self.ran else None

    def to_json(self) -> dict:
        if self.kind == "bound":
            out = {"kind": "bound"}
            if self.bound.settings is not None:
                out["settings"] = self.bound.settings
            out.update(self.metrics)
            if self.ran:
                out["per_session"] = self.per_session
            if self.skipped:
                out["skipped"] = self.skipped
            if self.bound.no_position:
                out["no_position"] = self.bound.no_position
        elif self.kind == "windows":
            w = self.windows
            out = {**self.metrics, "per_device": w.per_device, "per_brand": w.per_brand,
                   "per_session": self.per_session, "train_s": w.train_s, "predict_s": w.predict_s, "n_windows": w.n_windows, "source": w.source}
        elif not self.ran:
            out = {"skipped": self.skipped}
        else:
            out = dict(self.metrics)
            if self.skipped:
                out["skipped"] = self.skipped
            out.update({"wall_s": self.wall_s, "realtime_factor": self.realtime_factor, "recoveries": self.recoveries,
                        "map_notes": self.map_notes, "confined": self.confined})
            out.update({k: getattr(self, k) for k in OPTIONAL_KEYS if getattr(self, k) is not None})
            out["per_session"] = self.per_session
            if self.peak_memory is not None:
                out["peak_memory"] = self.peak_memory
        if self.training is not None:
            out["training"] = self.training
        if self.family is not None:
            out["family"] = self.family
        if self.best is not None:
            out["best"] = self.best
        return out


@dataclass
class EvalResult(Mapping):
    """One experiment's result: its name and title, the dataset, the runs per session, the scored sessions, the seed,
    the methods by label, and the rows the readers dropped (session -> stream -> reason -> rows)."""

    experiment: str
    title: str
    dataset: str
    runs: int
    sessions: list[str]
    seed: int
    methods: dict[str, MethodResult] = field(default_factory=dict)
    dropped: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        raise NotImplementedError

    # the results.json view, read-only
    def __getitem__(self, key):
        return self.to_json()[key]

    def __iter__(self):
        return iter(self.to_json())

    def __len__(self) -> int:
        return len(self.to_json())

    def _methods_json(self) -> dict:
        return {name: m.to_json() for name, m in self.methods.items()}


@dataclass
class TrajectoryResult(EvalResult):
    """Trajectories scored against the ground truth (:mod:`blenav.eval.harness`): also ``init_s`` (s), the path-loss
    ``calibration``, and, when they apply, the ``model`` that could not be used, the wrong ``plan_error``, the
    ``beacon_map`` given, the ``split`` (with its train walks), ``floor_accuracy`` and the ``fixes`` used."""

    init_s: float = 0.0
    calibration: dict | None = None
    model: dict | None = None
    plan_error: dict | None = None
    beacon_map: dict | None = None
    split: dict | None = None
    floor_accuracy: dict | None = None
    fixes: dict | None = None

    def to_json(self) -> dict:
        out = {"experiment": self.experiment, "title": self.title, "dataset": self.dataset, "runs": self.runs,
               "sessions": self.sessions, "init_s": self.init_s, "seed": self.seed, "calibration": self.calibration,
               "methods": self._methods_json()}
        for key in ("model", "plan_error", "beacon_map", "split", "floor_accuracy"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.dropped:
            out["dropped"] = self.dropped
        if self.fixes is not None:
            out["fixes"] = self.fixes
        return out


@dataclass
class WindowResult(EvalResult):
    """Windows scored per device (:mod:`blenav.eval.crossphone`): also the device ``split`` (group -> device models),
    the ``train_sessions`` and, per test session, the windows in which no beacon was heard (``no_fix_windows``)."""

    split: dict = field(default_factory=dict)
    train_sessions: list[str] = field(default_factory=list)
    no_fix_windows: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"experiment": self.experiment, "title": self.title, "dataset": self.dataset, "sessions": self.sessions,
                "seed": self.seed, "runs": self.runs, "split": self.split, "train_sessions": self.train_sessions,
                "no_fix_windows": self.no_fix_windows, "methods": self._methods_json()}


# ------------------------------------------------------------------------------------------ writing
def write_results(out: Path, result: EvalResult, experiment=None) -> dict:
    """``OUT/results.json`` and ``OUT/results.md`` of ``result`` (``experiment``: the
    :class:`~blenav.eval.config.ExperimentConfig`, for the paper's numbers and the leaderboard's layout); returns the
    JSON written."""
    from .common import write_json
    from .report import write_crossphone_markdown, write_markdown

    data = result.to_json()
    write_json(Path(out) / "results.json", data)
    if isinstance(result, WindowResult):
        write_crossphone_markdown(Path(out) / "results.md", data, experiment)
    else:
        write_markdown(Path(out) / "results.md", data, experiment)
    return data


def summary_lines(res: EvalResult) -> list[str]:
    """One console line per method (its error, or why it was skipped), then one per session with dropped rows. The
    name column is as wide as the longest method name."""
    width = max([len(n) for n in res.methods] + [12])
    out = []
    for name, m in res.methods.items():
        label = f"{name:{width}s}"
        if m.kind == "windows":  # a window-level comparison (crossphone): absolute error per window
            e = m.metrics["error_m"]
            out.append(f"{label} error mean {e['mean']:.2f} m  median {e['median']:.2f}  p90 {e['p90']:.2f}  "
                       f"max {e['max']:.2f}  ({m.windows.n_windows} windows)")
        elif not m.ran:
            first = next(iter(m.skipped.values()), "no session")
            out.append(f"{label} skipped on {len(m.skipped)} session(s): {first}")
        elif m.kind == "bound":  # the leaderboard's PCRLB (blenav.eval.pcrlb): no estimates, no timing
            out.append(f"{label} RMSE {m.rmse_mean:.2f} m  (lower bound on the position error)")
        else:
            r = m.metrics["rmse_m"]
            out.append(f"{label} RMSE {r['mean']:.2f} +- {r['stderr']:.2f} m  p75 {m.metrics['error_m']['p75']:.2f} m  "
                       f"({m.realtime_factor:.0f}x real time)")
    for sid, streams in (res.dropped or {}).items():
        what = "; ".join(f"{stream}: " + ", ".join(f"{n} {why}" for why, n in reasons.items())
                         for stream, reasons in streams.items())
        out.append(f"dropped rows in {sid}: {what}")
    return out
