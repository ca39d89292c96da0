"""The evaluation's typed spine: EvalConfig parsed once from conf/eval.yaml, the typed results and their JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest

from blenav.configs import compose
from blenav.errors import EvalError
from blenav.eval.config import EvalConfig, FixesConfig, SplitConfig, parse_eval_config
from blenav.eval.result import BoundStats, MethodResult, TrajectoryResult, WindowResult, WindowStats, summary_lines
from blenav.localizers.inputs import Fixes, RoleFixes, RunInputs
from blenav.errors import MissingStream


def parse(*overrides) -> EvalConfig:
    return parse_eval_config(compose("eval", "data=/nonexistent", *overrides))


def test_parse_types_every_node_of_an_experiment():
    c = parse("experiment=realwalks", "runs=3", "seed=7", "+fixes.rate_hz=2")
    assert (c.runs, c.seed, c.init_s, c.experiment.name) == (3, 7, 0.0, "realwalks")
    assert isinstance(c.split, SplitConfig) and (c.split.train_fraction, c.split.seed) == (0.5, 0)
    assert c.split.given == {"train_fraction": 0.5, "seed": 0}  # results.json repeats the keys as given
    assert isinstance(c.fixes, FixesConfig) and c.fixes.rate_hz == 2.0 and c.fixes.sparse_beacons == 4
    assert set(c.fixes.roles) == {"wifi", "ble", "both", "both_crowd", "ble_crowd"} and c.fixes.per_role
    assert c.fixes.compute["wifi"] == c.methods["knn_wifi"]  # ${methods.knn_wifi} resolved once, at parsing
    assert c.scoring.hold_ends is True and c.data.path == "/nonexistent"
    assert c.experiment.evaluator_target == "blenav.eval.trajectory.TrajectoryEvaluator"


@pytest.mark.parametrize("override, expect", [
    ("+sesions=[a]", "did you mean sessions"),
    ("split={train_fractoin: 0.3}", "did you mean split.train_fraction"),
    ("+scoring.hold_end=true", "did you mean scoring.hold_ends"),
    ("+experiment.titel=x", "did you mean experiment.title"),
    ("+plan_error.seeds=1", "did you mean plan_error.seed"),
    ("+fixes={dense: null, rate: 2}", "did you mean fixes.rate_hz"),
    ("runs=abc", "runs='abc': a whole number"),
    ("runs=2.5", "runs=2.5: a whole number"),
    ("runs=1e400", "runs=inf: a whole number"),
    ("plots=3", "plots=3: true or false"),
    ("calibration=sometimes", "calibration='sometimes'"),
    ("+experiment.kind=crosphone", "experiment.kind='crosphone'"),
])
def test_a_misspelt_key_or_bad_value_fails_naming_it(override, expect):
    with pytest.raises(EvalError, match=expect.replace("[", r"\[").replace("+", r"\+")):
        parse(override)


def test_missing_dataset_path_and_evaluator_choice():
    with pytest.raises(EvalError, match="name the dataset to evaluate on: data=DIR"):
        parse_eval_config(compose("eval"))
    assert parse("experiment=leaderboard").experiment.is_leaderboard
    assert parse("experiment=crossphone_003").experiment.evaluator_target.endswith("CrossPhoneEvaluator")
    c = parse("+experiment.evaluator={_target_: blenav.eval.leaderboard.LeaderboardEvaluator}")
    assert c.experiment.is_leaderboard
    assert parse_eval_config(c) is c  # parsed once: the typed object passes through


def test_fixes_block_roles_and_options():
    f = FixesConfig.parse({"dense": None, "sparse": "ps-sparse", "sparse_beacons": [1, "b2"], "write": True})
    assert f.roles == {"dense": None, "sparse": "ps-sparse"} and f.sparse_beacons == ["1", "b2"] and f.write
    assert FixesConfig.parse({"dense": None, "sparse_beacons": 6.0}).sparse_beacons == 6
    with pytest.raises(EvalError, match="fixes.compute names role"):
        FixesConfig.parse({"dense": None, "compute": {"sparse": {"_target_": "x"}}})
    with pytest.raises(EvalError, match="not a role"):
        FixesConfig.parse({"dense": None, "sparse_beacon": 6})


def test_session_ids_and_calibration_sessions():
    assert parse("sessions=a,b").session_ids == ["a", "b"]
    assert parse("sessions=[a,3]").session_ids == ["a", "3"]
    assert parse().session_ids is None and parse("sessions=7").session_ids == ["7"]
    assert parse("+peak_memory=null").peak_memory == "none"
    assert parse("calibration=[s1,s2]").calibration_sessions == {"s1", "s2"}
    assert parse("calibration=none").calibration_sessions == set()


# ------------------------------------------------------------------------------------------ results
def _traj(**kw) -> MethodResult:
    return MethodResult(metrics={"rmse_m": {"mean": 1.5, "stderr": 0.1}, "error_m": {"p75": 2.0}}, wall_s=2.0,
                        realtime_factor=30.0, recoveries=0, map_notes=[], confined={"bbox": 0}, per_session={"s": {}},
                        **kw)


def test_method_json_keeps_the_order_results_json_had():
    m = _traj(skipped={"t": "no IMU"}, orientation_rmse_deg=3.0, peak_memory={"peak_memory_mb": 1.0},
              training={"steps": 1}, family="PF")
    assert list(m.to_json()) == ["rmse_m", "error_m", "skipped", "wall_s", "realtime_factor", "recoveries", "map_notes",
                                 "confined", "orientation_rmse_deg", "per_session", "peak_memory", "training", "family"]
    none = MethodResult(skipped={"s": "no rssi"}, training={"unavailable": "x"})
    assert none.to_json() == {"skipped": {"s": "no rssi"}, "training": {"unavailable": "x"}} and not none.ran
    b = MethodResult(kind="bound", metrics={"rmse_m": {"mean": 0.5}}, per_session={"s": 1},
                     bound=BoundStats({"dt_s": 1.0}, {"s": ["b9"]}), family="bound", best={"ratio": 3.0})
    assert list(b.to_json()) == ["kind", "settings", "rmse_m", "per_session", "no_position", "family", "best"]


def test_result_json_top_level_order_and_mapping_view():
    r = TrajectoryResult("e", "T", "/d", 2, ["s"], 0, {"A": _traj()}, dropped={"s": {"rssi": {"x": 1}}}, init_s=5.0,
                         fixes={"roles": {}}, split={"seed": 0, "train": []})
    keys = list(r.to_json())
    assert keys == ["experiment", "title", "dataset", "runs", "sessions", "init_s", "seed", "calibration", "methods",
                    "split", "dropped", "fixes"]
    assert r["methods"]["A"]["rmse_m"]["mean"] == 1.5 and "fixes" in r and len(r) == len(keys)
    json.dumps(r.to_json())
    w = WindowResult("c", "T", "/d", 1, ["s"], 0, {"KNN": MethodResult(
        kind="windows", metrics={"error_m": {"mean": 1.0, "median": 1.0, "p90": 2.0, "max": 3.0}, "rmse_m": {}},
        windows=WindowStats({}, {}, None, 0.1, 10, "fitted"))}, split={"train": ["a"]})
    assert list(w.to_json())[:4] == ["experiment", "title", "dataset", "sessions"]
    assert list(w.to_json()["methods"]["KNN"]) == ["error_m", "rmse_m", "per_device", "per_brand", "per_session",
                                                   "train_s", "predict_s", "n_windows", "source"]


def test_summary_columns_fit_the_longest_name():
    long = "WiFi+BLE+PDR+learned-map (a long label)"
    r = TrajectoryResult("e", "T", "/d", 2, ["s"], 0, {"A": _traj(), long: _traj(),
                                                       "X": MethodResult(skipped={"s": "no IMU"})})
    lines = summary_lines(r)
    assert [ln.index("RMSE") for ln in lines[:2]] == [len(long) + 1] * 2
    assert lines[2].startswith("X" + " " * len(long)) and lines[2].endswith("skipped on 1 session(s): no IMU")


def test_summary_table_of_a_30_character_method_name():
    """blenav-eval's console table (summary_lines) with a 30-character name beside short ones, a bound and a skipped
    row: every row's text starts in one column, one space after the longest name, none cut."""
    long = "PF-PS+MAP+offset+learned-prior"
    assert len(long) == 30
    bound = MethodResult(kind="bound", metrics={"rmse_m": {"mean": 0.5}}, per_session={"s": 1}, bound=BoundStats())
    r = TrajectoryResult("e", "T", "/d", 2, ["s"], 0, {"RW": _traj(), long: _traj(), "PCRLB": bound,
                                                       "X": MethodResult(skipped={"s": "no IMU"})})
    lines = summary_lines(r)
    assert [ln[:31] for ln in lines] == [f"{n:30s} " for n in ("RW", long, "PCRLB", "X")]
    assert [ln[31:35] for ln in lines] == ["RMSE", "RMSE", "RMSE", "skip"]
    assert lines[1] == f"{long} RMSE 1.50 +- 0.10 m  p75 2.00 m  (30x real time)"


def test_fixes_inputs_raise_missing_stream_with_the_reason():
    rf = RoleFixes(np.arange(3.0), np.zeros((3, 2)), np.full(3, np.nan), "ps-dense", computed=True)
    fx = Fixes({"dense": rf}, {"sparse": "session s has no rssi.csv"})
    assert fx["dense"] is rf and "sparse" in fx and "wifi" not in fx
    with pytest.raises(MissingStream, match="no rssi.csv"):
        fx["sparse"]
    with pytest.raises(ValueError, match="no fixes of role 'wifi'"):
        fx["wifi"]
    with pytest.raises(ValueError, match="xy"):
        RoleFixes(np.arange(3.0), np.zeros((2, 2)), np.zeros(3), "x")
    base = RunInputs(cache={"k": 1})
    assert base.with_fixes(fx).cache is base.cache and base.with_fixes(fx).fixes is fx


def test_the_evaluator_is_an_allow_listed_class():
    from blenav.eval.evaluators import build_evaluator
    from blenav.eval.leaderboard import LeaderboardEvaluator
    from blenav.eval.trajectory import TrajectoryEvaluator
    from blenav.trust import UntrustedTargetError

    assert type(build_evaluator(parse())) is TrajectoryEvaluator
    assert type(build_evaluator(parse("experiment=leaderboard"))) is LeaderboardEvaluator
    assert type(build_evaluator(parse("+experiment.kind=leaderboard"))) is LeaderboardEvaluator  # the old spelling
    with pytest.raises(UntrustedTargetError, match=r"experiment.evaluator._target_ = 'os.system'"):
        build_evaluator(parse("+experiment.evaluator={_target_: os.system}"))


def test_localizers_take_their_fixes_as_arrays():
    """A fix consumer reads the fixes the run hands it (no call back into the evaluation): a particle filter points
    its fix likelihood at the role's source and adds computed fixes once; FixTrack returns them as its estimate."""
    from blenav.eval.harness import build_methods
    from blenav.filters.measurement import FixLikelihood

    ms = build_methods(compose("eval", "experiment=mapprior_003_table37"))
    pf, track = ms["sparse-BLE+IO"], ms["sparse-BLE"]
    xy = np.column_stack([np.arange(4.0), np.ones(4)])
    f = RoleFixes(np.arange(4.0) + 1, xy, np.full(4, np.nan), "ps-sparse4", computed=True, wall_s=0.25)
    extra = pf.use_fixes(Fixes({"sparse": f}))
    assert list(extra.columns) == ["t", "x", "y", "std", "source"] and len(extra) == 4
    assert [m.source for m in pf.method.measurements if isinstance(m, FixLikelihood)] == ["ps-sparse4"]
    assert pf.use_fixes(Fixes({"sparse": RoleFixes(f.t, f.xy, f.std, "named")})) is None  # read from fixes.csv
    with pytest.raises(MissingStream, match="no rssi"):
        pf.use_fixes(Fixes({}, {"sparse": "no rssi"}))
    session = type("S", (), {"id": "s0"})()
    est = track.run(session, 3, 0, RunInputs(fixes=Fixes({"sparse": f})))
    assert est.position.shape == (3, 4, 2) and np.array_equal(est.position[2], xy) and est.wall_s == 0.75
    with pytest.raises(ValueError, match="no fixes block"):
        track.run(session, 1, 0, RunInputs())
