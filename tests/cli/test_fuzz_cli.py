"""Issue 19, section 2: corrupted datasets against the evaluation (blenav-eval) and the command lines.

The evaluation runs in-process (``blenav.eval.harness.evaluate`` with the composed config of ``blenav-eval
experiment=mapfusion_002 runs=1 plots=false progress=false calibration=none``): an ``EvalError`` /
``DatasetError`` (``ValueError``) is the CLI's one-line ``exit 1``, anything else would be a traceback. For each
generated fault (tests/fuzz_helpers.py) the evaluation

* gives results identical to the clean dataset's when the fault changes nothing (BOM, CRLF, padding, quoting,
  column and anchor order, consistent Unicode renames, ...), and whenever the readers read exactly what they
  read for the clean dataset;
* refuses what the readers refuse, with a message naming a file of the dataset;
* otherwise has no NaN or infinity anywhere in its results, and reports every row the readers dropped
  (``results['dropped']``).

A few subprocess runs check the command lines end to end: one line ``PROG: error: ...`` naming the file and
exit 1, no traceback; a BOM + CRLF dataset gives the clean results.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from blenav.configs import compose
from blenav.errors import DatasetError, EvalError
from blenav.eval.harness import evaluate
from fuzz_helpers import (
    CI,
    CSV_FILES,
    REFUSED,
    SLOW,
    TEXT_FILES,
    bad_faults,
    f_bom,
    f_line_ends,
    f_scale,
    f_truncate,
    fresh_copy,
    make_fuzz_dataset,
    make_sim_fuzz_dataset,
    read_everything,
    same_faults,
    two_bad_faults,
)

from helpers import REPO

pytestmark = pytest.mark.timeout(900)
#: the evaluation is the slow part (about 0.7 s an example): 12 examples per test in the default run
CI_EVAL = settings(CI, max_examples=max(CI.max_examples * 3 // 5, 1))
BIN = Path(sys.executable).parent
#: keys whose values are timings or the dataset's path, not results
VOLATILE = {"wall_s", "realtime_factor", "dataset"}


class Env:
    """The template, a work folder (dataset copy ``d``, output ``o``), the config and the clean results."""

    def __init__(self, base: Path, make=make_fuzz_dataset, *overrides: str):
        self.base = base
        self.template = make(base / "template")
        self.data = base / "d"
        self.out = base / "o"
        self.cfg = compose("eval", "experiment=mapfusion_002", f"data={self.data}", "runs=1", f"out={self.out}",
                           "plots=false", "progress=false", "calibration=none", *overrides)
        self.fresh()
        self.snapshot = read_everything(self.data)
        self.results = normalized(evaluate(self.cfg).to_json())

    def fresh(self) -> Path:
        shutil.rmtree(self.out, ignore_errors=True)
        return fresh_copy(self.template, self.base, "d")


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    return Env(tmp_path_factory.mktemp("fuzz_eval"))


@pytest.fixture(scope="module")
def env_imu(tmp_path_factory):
    """RW, DR and the IMU proposal (frontend_000) on a simulated walk: the inertial and odometry paths."""
    return Env(tmp_path_factory.mktemp("fuzz_eval_imu"), make_sim_fuzz_dataset, "experiment=frontend_000")


@pytest.fixture(scope="module")
def env_fixes(tmp_path_factory):
    """The fix likelihood (fused_003) on fixes.csv's source 'pfps'."""
    return Env(tmp_path_factory.mktemp("fuzz_eval_fixes"), make_fuzz_dataset, "experiment=fused_003",
               "experiment.fix_source=pfps")


def normalized(res: dict, rename: dict | None = None) -> dict:
    """The results without timings and paths; session ids renamed back to the template's."""
    rename = rename or {}

    def walk(x):
        if isinstance(x, dict):
            return {rename.get(k, k): walk(v) for k, v in x.items() if k not in VOLATILE}
        if isinstance(x, list):
            return [walk(v) for v in x]
        return rename.get(x, x) if isinstance(x, str) else x
    return walk(res)


def numbers(x, path=""):
    if isinstance(x, dict):
        for k, v in x.items():
            yield from numbers(v, f"{path}.{k}")
    elif isinstance(x, (list, tuple)):
        for i, v in enumerate(x):
            yield from numbers(v, f"{path}[{i}]")
    elif isinstance(x, float):
        yield path, x


def run_eval(env: Env):
    """('ok', results) or ('refused', the exception); any other exception propagates (a traceback for the user)."""
    shutil.rmtree(env.out, ignore_errors=True)
    try:
        return "ok", evaluate(env.cfg).to_json()
    except (EvalError, DatasetError) as exc:
        return "refused", exc
    except ValueError as exc:  # the CLI prints it as one line too, but it should say which method and file
        return "refused", exc


def check_eval_same(env: Env, fault) -> None:
    root = env.fresh()
    outcome = fault.apply(root)
    kind, res = run_eval(env)
    assert kind == "ok", res
    assert normalized(res, outcome.rename) == env.results


def check_eval_bad(env: Env, fault) -> None:
    root = env.fresh()
    outcome = fault.apply(root)
    try:
        snap = read_everything(root)
    except DatasetError:
        snap = None
    kind, res = run_eval(env)
    if kind == "refused":
        event(f"{fault.name}: refused")
        assert str(root) in str(res), f"{type(res).__name__} names no file of the dataset: {res}"
        return
    assert snap is not None, "the evaluation ran on a dataset the readers refuse"
    assert outcome.expect != REFUSED
    event(f"{fault.name}: ran")
    bad = [(p, v) for p, v in numbers(res) if not math.isfinite(v)]
    assert not bad, bad
    assert res.get("dropped", {}) == snap.dropped  # every dropped row is in the results
    try:
        snap.assert_same(env.snapshot)
    except AssertionError:
        return  # the data differ (e.g. a flipped digit): the results may too
    assert normalized(res) == env.results, "the readers read the same data, but the results differ"


@settings(CI_EVAL)
@given(fault=same_faults())
def test_eval_of_a_harmlessly_changed_dataset_is_identical(env, fault):
    check_eval_same(env, fault)


@settings(CI_EVAL)
@given(fault=bad_faults())
def test_eval_of_a_corrupted_dataset_refuses_cleanly_or_has_finite_results(env, fault):
    check_eval_bad(env, fault)


@pytest.mark.slow
@settings(SLOW, max_examples=max(SLOW.max_examples // 4, 1))
@given(fault=same_faults())
def test_eval_harmless_slow(env, fault):
    check_eval_same(env, fault)


@pytest.mark.slow
@settings(SLOW, max_examples=max(SLOW.max_examples // 4, 1))
@given(fault=bad_faults())
def test_eval_corrupted_slow(env, fault):
    check_eval_bad(env, fault)


@pytest.mark.slow
@settings(SLOW, max_examples=max(SLOW.max_examples // 4, 1))
@given(fault=two_bad_faults())
def test_eval_two_corruptions_slow(env, fault):
    check_eval_bad(env, fault)


@pytest.mark.slow
@settings(SLOW, max_examples=max(SLOW.max_examples // 4, 1))
@given(fault=st.one_of(bad_faults(), two_bad_faults()))
def test_eval_imu_methods_on_a_simulated_walk_slow(env_imu, fault):
    check_eval_bad(env_imu, fault)


@pytest.mark.slow
@settings(SLOW, max_examples=max(SLOW.max_examples // 4, 1))
@given(fault=st.one_of(bad_faults(), two_bad_faults()))
def test_eval_fix_likelihood_slow(env_fixes, fault):
    check_eval_bad(env_fixes, fault)


# --------------------------------------------------------------------------- the command lines, end to end


def _run(*args):
    env = {k: v for k, v in os.environ.items() if k != "BLENAV_DEBUG"}
    return subprocess.run([str(a) for a in args], capture_output=True, text=True, cwd=REPO, env=env, timeout=600)


def _error_line(p, prog: str) -> str:
    lines = [ln for ln in p.stderr.splitlines() if ln.strip() and "Warning" not in ln and "warnings.warn" not in ln]
    assert p.returncode == 1, (p.returncode, p.stderr)
    assert "Traceback" not in p.stderr, p.stderr
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), p.stderr
    return lines[0]


@pytest.mark.parametrize("fault, file, rule", [
    ((f_scale, f"sessions/walk0/rssi.csv", ("t",), 1000.0), "rssi.csv", "time-clock"),
    ((f_truncate, "buildings/house/building.yaml", -3), "building.yaml", "truncated"),
], ids=["rssi-in-ms", "building.yaml-cut"])
def test_cli_refuses_a_corrupted_dataset_in_one_line(tmp_path, env, fault, file, rule):
    root = fresh_copy(env.template, tmp_path)
    fn, *args = fault
    fn(root, *args)
    out = tmp_path / "o"
    p = _run(BIN / "blenav-eval", "experiment=mapfusion_002", f"data={root}", f"out={out}", "runs=1", "plots=false",
             "calibration=none")
    line = _error_line(p, "blenav-eval")
    assert file in line and f"[{rule}]" in line and str(root) in line
    assert not out.exists()
    v = _run(BIN / "blenav-validate", root)
    assert v.returncode == 1 and "Traceback" not in v.stderr
    assert any(file in ln and f"[{rule}]" in ln for ln in v.stdout.splitlines())


def test_cli_reads_a_dataset_with_bom_and_crlf_everywhere_as_the_clean_one(tmp_path, env):
    root = fresh_copy(env.template, tmp_path)
    for f in TEXT_FILES:
        f_bom(root, f)
        f_line_ends(root, f, "\r\n")
    assert all((root / f).read_bytes().startswith(b"\xef\xbb\xbf") for f in CSV_FILES)
    out = tmp_path / "o"
    p = _run(BIN / "blenav-eval", "experiment=mapfusion_002", f"data={root}", f"out={out}", "runs=1", "plots=false",
             "progress=false", "calibration=none")
    assert p.returncode == 0, p.stderr
    res = json.loads((out / "results.json").read_text())
    assert normalized(res) == json.loads(json.dumps(env.results))
    v = _run(BIN / "blenav-validate", root)
    assert v.returncode == 0 and "ERROR" not in v.stdout, v.stdout


@pytest.mark.parametrize("rows", ["1", "all-at-0"])
def test_ground_truth_of_one_instant_is_refused_naming_the_file(env, rows):
    """Was: a plain ValueError 'no estimate falls inside the ground truth's time span', naming neither the method,
    the session nor the file."""
    from fuzz_helpers import f_keep_rows, f_one_time

    root = env.fresh()
    f = "sessions/walk0/groundtruth.csv"
    f_keep_rows(root, f, 1) if rows == "1" else f_one_time(root, f, "0")
    with pytest.raises(EvalError, match=r"session walk0: no estimate .*groundtruth\.csv: t 0\.\.0 s"):
        evaluate(env.cfg)


def test_an_imu_with_every_time_twice_runs_the_imu_methods(tmp_path):
    """Was: OverflowError (a traceback) in the step detector: duplicate times (allowed) made the median IMU
    interval 0 and the rate infinite. Found by the fuzz faults with experiment=frontend_000 (RW, DR, IMU)."""
    import pandas as pd

    root = make_fuzz_dataset(tmp_path / "d")
    p = root / "sessions/walk0/imu.csv"
    df = pd.read_csv(p)
    pd.concat([df, df]).sort_values("t", kind="stable").to_csv(p, index=False)
    res = evaluate(compose("eval", "experiment=frontend_000", f"data={root}", "runs=1", f"out={tmp_path / 'o'}",
                           "plots=false", "progress=false", "calibration=none")).to_json()
    assert {m["rmse_m"]["n"] for m in res["methods"].values()} == {1}
    bad = [(p, v) for p, v in numbers(res) if not math.isfinite(v)]
    assert not bad, bad


def test_an_imu_that_ends_before_the_ground_truth_starts_gives_no_nan(tmp_path):
    """Was: orientation_rmse_deg NaN in results.json when no ground-truth time falls in the IMU's time span (the
    mean of nothing); now absent, as for a method without an AHRS."""
    import pandas as pd

    root = make_fuzz_dataset(tmp_path / "d")
    s = root / "sessions/walk0"
    imu = pd.read_csv(s / "imu.csv")
    imu[imu["t"] < 5.0].to_csv(s / "imu.csv", index=False)
    gt = pd.read_csv(s / "groundtruth.csv")
    gt[gt["t"] >= 10.0].to_csv(s / "groundtruth.csv", index=False)
    res = evaluate(compose("eval", "experiment=frontend_000", f"data={root}", "runs=1", f"out={tmp_path / 'o'}",
                           "plots=false", "progress=false", "calibration=none", "init_s=1")).to_json()
    bad = [(p, v) for p, v in numbers(res) if not math.isfinite(v)]
    assert not bad, bad
    assert all("orientation_rmse_deg" not in m for m in res["methods"].values())
