"""Issue 18, section 4: no method ever outputs NaN or leaves the floor's bounding box, under fuzzed streams (a
property test over the localizer interface).

The methods are built from the committed experiments the way the harness builds them
(:func:`blenav.eval.harness.build_methods`: every ``_target_`` of conf/localizer/*.yaml that runs on a simulated
pedestrian walk: the particle filters of 000/002/003 (RW, DR, IMU proposal, PL/PS, map, offset, fixes), the
front-end and back-end, the CRF and its recursive form, grid-L1/L2, SRLS, the weighted centroid, the fix tracks,
PDR and the heuristic PF of 003). Left out, with the reason: the learned map-prior methods (no model without
training) and the fingerprinting localizer (it learns from the dataset's train walks; a lone simulated walk has
none).

Each example takes the simulator's 12 s walk (plus fixes.csv and visual.csv), applies 1..4 generated stream faults that the
readers accept (the walk has every stream the methods read: IMU, magnetometer, BLE, RTT, odometry, fixes, visual
fixes) -- an RSSI burst dropped, outlier RSSI (still in (-150, 0) dBm), every RSSI gone, IMU rows removed
(what the reader does to NaN rows: it refuses non-finite IMU cells, so a NaN row reaches a method only as a
missing row), IMU spikes up to the sensors' full scale, a time gap in every sensor stream, RTT outliers, fixes
1 km off the plan, a whole stream gone, every stream stopping early, one beacon heard -- and runs every method
on it (``method.run`` as the harness's ``run_method`` does, then its :func:`~blenav.localizers.confine.confine`
step). Every estimate must be finite (positions, covariances: the confine step cannot repair a NaN) and, after the
confine step the harness promises, inside the floor's bounding box; a method may decline a session
(:class:`~blenav.localizers.MissingStream`: the harness skips it, with the reason) or refuse it with a ValueError
(the harness stops with one line naming the method and the session, e.g. a session whose sensors stop after 0.5 s
is 'shorter than one filter step'); any other exception is a failure. On the clean walk every method runs. How
often a method's raw output left the box before the confine step is recorded as a hypothesis event.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import event, example, given, settings
from hypothesis import strategies as st
from hypothesis.errors import InvalidArgument

from blenav.configs import compose
from blenav.data import Dataset
from blenav.data.writer import write_csv
from blenav.errors import MissingStream
from blenav.eval.config import parse_eval_config
from blenav.eval.harness import build_fix_provider, build_methods, method_inputs
from blenav.localizers.inputs import RunInputs
from blenav.localizers.confine import confine
from fuzz_helpers import CI, SLOW

pytestmark = pytest.mark.timeout(900)
#: about 4 s an example (26 methods on a 12 s walk): the clean walk and two fuzzed ones in the default run
CI_LOC = settings(CI, max_examples=max(CI.max_examples // 10, 1))
SLOW_LOC = settings(SLOW, max_examples=max(SLOW.max_examples // 8, 1))
DURATION_S = 12.0
FIX_SOURCE = "pfps"
#: (experiment, methods left out: label -> why); every other method of these experiments is run
EXPERIMENTS = [
    ("frontend_000", {}),
    ("mapfusion_002", {}),
    ("fused_003", {"PF-PS+MAP": "as in mapfusion_002"}),
    ("backend_000", {"RW": "as in frontend_000", "DR": "as in frontend_000", "IMU": "as in frontend_000"}),
    ("crf_004_fig12", {}),
    ("mapprior_003_table37", {"IO+map": "needs a trained map prior (model_path)",
                              "sparse-BLE+IO+map": "needs a trained map prior (model_path)"}),
]
STREAMS = ("imu", "rssi", "rtt", "mag", "odometry", "fixes", "visual")


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> Path:
    """The simulator's small preset: one 12 s pedestrian walk, with a fixes.csv (ground truth + 1.5 m noise) and a
    visual.csv (ground truth at 2 Hz: the CRF's online calibration needs visual fixes)."""
    from helpers import simulate_small

    root = simulate_small(tmp_path_factory.mktemp("robust_loc") / "walk", 11, DURATION_S, 1)
    (s,) = (root / "sessions").iterdir()
    gt = pd.read_csv(s / "groundtruth.csv")
    rng = np.random.default_rng(5)
    t = np.arange(0.0, DURATION_S, 0.5)
    x, y = np.interp(t, gt["t"], gt["x"]), np.interp(t, gt["t"], gt["y"])
    write_csv(s / "fixes.csv", pd.DataFrame({"t": t, "x": x + rng.normal(0, 1.5, t.size),
                                             "y": y + rng.normal(0, 1.5, t.size), "std": 1.5, "source": FIX_SOURCE}))
    write_csv(s / "visual.csv", pd.DataFrame({"t": t, "x": x, "y": y, "z": 1.2, "yaw": 0.0}))
    return root


class _Methods(list):
    def __repr__(self) -> str:
        return f"<{len(self)} methods: {', '.join(label for label, _, _ in self)}>"


@pytest.fixture(scope="module")
def methods(walk, tmp_path_factory):
    """[(label, localizer, (config, every method of the experiment))] of every method of :data:`EXPERIMENTS` but
    those left out (a list that hypothesis prints as its labels)."""
    out, seen = _Methods(), set()
    base = tmp_path_factory.mktemp("robust_loc_out")
    for exp, skip in EXPERIMENTS:
        cfg = compose("eval", f"experiment={exp}", f"data={walk}", "runs=1", f"out={base}", "plots=false",
                      "progress=false", "calibration=none", f"+experiment.fix_source={FIX_SOURCE}"
                      if exp != "fused_003" else f"experiment.fix_source={FIX_SOURCE}")
        built = build_methods(cfg)
        for label, m in built.items():
            if label not in skip and (exp, label) not in seen:
                seen.add((exp, label))
                out.append((f"{exp}/{label}", m, (cfg, built)))
    labels = [label for label, _, _ in out]
    assert len(labels) >= 20 and {"crf_004_fig12/CRF", "backend_000/B-end", "fused_003/PF-FIX",
                                  "mapprior_003_table37/dense-BLE", "crf_004_fig12/SRLS"} <= set(labels), labels
    return out


# --------------------------------------------------------------------------- stream faults the readers accept


def _window(t: pd.Series, start: float, dur: float) -> np.ndarray:
    return ((t >= start) & (t < start + dur)).to_numpy()


def rssi_burst(s: dict, rng, start, dur):
    s["rssi"] = s["rssi"][~_window(s["rssi"]["t"], start, dur)]


def rssi_outliers(s: dict, rng, frac, value):
    r = s["rssi"].copy()
    hit = rng.random(len(r)) < frac
    r.loc[hit, "rssi"] = value
    s["rssi"] = r


def no_rssi(s: dict, rng):
    s["rssi"] = s["rssi"].iloc[:0]


def imu_rows_removed(s: dict, rng, frac, block):
    """What the reader leaves of NaN IMU rows: the rows are gone (scattered, or one block)."""
    imu = s["imu"]
    if block:
        i = int(rng.integers(0, max(len(imu) - 1, 1)))
        keep = np.ones(len(imu), bool)
        keep[i:i + int(frac * len(imu))] = False
    else:
        keep = rng.random(len(imu)) >= frac
    s["imu"] = imu[keep]


def imu_spikes(s: dict, rng, n, acc, gyr):
    """``n`` samples at up to the sensors' full scale (16 g, 2000 deg/s: what the reader accepts)."""
    imu = s["imu"].copy()
    if not len(imu):
        return
    rows = rng.integers(0, len(imu), n)
    for c in ("ax", "ay", "az"):
        imu.iloc[rows, imu.columns.get_loc(c)] = acc * rng.choice([-1.0, 1.0], n)
    for c in ("gx", "gy", "gz"):
        imu.iloc[rows, imu.columns.get_loc(c)] = gyr * rng.choice([-1.0, 1.0], n)
    s["imu"] = imu


def gap(s: dict, rng, start, dur):
    """Nothing from any sensor for ``dur`` s (the ground truth goes on)."""
    for k in STREAMS:
        if k in s:
            s[k] = s[k][~_window(s[k]["t"], start, dur)]


def rtt_outliers(s: dict, rng, frac, value):
    r = s["rtt"].copy()
    r.loc[rng.random(len(r)) < frac, "range_m"] = value
    s["rtt"] = r


def fix_outliers(s: dict, rng, frac, offset):
    f = s["fixes"].copy()
    hit = rng.random(len(f)) < frac
    f.loc[hit, "x"] = f.loc[hit, "x"] + offset
    s["fixes"] = f


def stream_gone(s: dict, rng, name):
    """A stream with no rows at all (a phone without the sensor, a recording that lost it)."""
    if name in s:
        s[name] = s[name].iloc[:0]


def stops_early(s: dict, rng, seconds):
    """Every sensor stream ends after ``seconds`` (the ground truth goes on)."""
    for k in STREAMS:
        if k in s:
            s[k] = s[k][(s[k]["t"] < seconds).to_numpy()]


def one_beacon(s: dict, rng):
    """Only the most frequent beacon is heard."""
    r = s["rssi"]
    if len(r):
        s["rssi"] = r[r["anchor_id"] == r["anchor_id"].mode().iloc[0]]


_start = st.floats(0.0, DURATION_S - 1.0).map(lambda v: round(v, 2))
FAULTS = st.one_of(
    st.tuples(st.just(rssi_burst), _start, st.sampled_from([1.0, 3.0, 8.0, 15.0])),
    st.tuples(st.just(rssi_outliers), st.sampled_from([0.05, 0.3, 1.0]), st.sampled_from([-149.9, -120.0, -1.0,
                                                                                          -10.0])),
    st.tuples(st.just(no_rssi)),
    st.tuples(st.just(imu_rows_removed), st.sampled_from([0.1, 0.5, 0.9]), st.booleans()),
    st.tuples(st.just(imu_spikes), st.integers(1, 50), st.sampled_from([0.0, 50.0, 159.0]),
              st.sampled_from([0.0, 10.0, 34.9])),
    st.tuples(st.just(gap), _start, st.sampled_from([0.5, 2.0, 5.0, 12.0])),
    st.tuples(st.just(rtt_outliers), st.sampled_from([0.1, 1.0]), st.sampled_from([-49.0, 0.0, 999.0])),
    st.tuples(st.just(fix_outliers), st.sampled_from([0.1, 1.0]), st.sampled_from([-1000.0, 1000.0])),
    st.tuples(st.just(stream_gone), st.sampled_from(STREAMS)),
    st.tuples(st.just(stops_early), st.sampled_from([0.5, 2.0, 6.0])),
    st.tuples(st.just(one_beacon)),
)


def apply_faults(src: Path, dst: Path, faults, seed: int) -> Path:
    """A copy of dataset ``src`` at ``dst`` whose one session's streams have ``faults`` applied, in order."""
    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(src, dst)
    (sdir,) = (dst / "sessions").iterdir()
    streams = {k: pd.read_csv(sdir / f"{k}.csv", dtype={"anchor_id": str, "source": str})
               for k in STREAMS if (sdir / f"{k}.csv").is_file()}
    rng = np.random.default_rng(seed)
    for fn, *args in faults:
        fn(streams, rng, *args)
    for k, df in streams.items():
        write_csv(sdir / f"{k}.csv", df.reset_index(drop=True))
    return dst


def _event(what: str) -> None:
    try:
        event(what)
    except InvalidArgument:  # outside a hypothesis test
        pass


def check_methods(methods, root: Path, seed: int) -> int:
    """Run every method on the dataset's one session (see the module docstring); returns how many ran."""
    ds = Dataset.open(root)
    (sid,) = ds.session_ids
    session = ds.session(sid)
    x0, x1, y0, y1 = session.floor.extent
    providers: dict = {}
    ran = 0
    for label, m, (cfg, built) in methods:
        if id(cfg) not in providers:  # per experiment and example: the fix provider caches per session
            providers[id(cfg)] = build_fix_provider(parse_eval_config(cfg), built, root / "out")
        inputs = RunInputs(cache={}, out=root / "out")
        try:  # the session's fixes resolved as the harness does (a missing role: skipped, with the reason)
            est = m.run(session, 1, seed, method_inputs(m, session, inputs, providers[id(cfg)]))
        except MissingStream as exc:
            _event(f"{label}: skipped ({str(exc)[:40]})")
            continue
        except ValueError as exc:  # the harness stops with 'method M, session S: ...' (one line); not a NaN
            _event(f"{label}: refused ({str(exc)[:40]})")
            continue
        ran += 1
        p = est.position
        assert np.isfinite(p).all(), f"{label}: {np.isnan(p).any(axis=-1).sum()} NaN positions of {p.shape[1]}"
        if est.cov is not None:
            assert np.isfinite(est.cov).all(), f"{label}: non-finite covariance"
        out, info = confine(est, session.floor, snap_free=m.uses_floor_plan, cache=inputs.cache)
        q = out.position
        assert np.isfinite(q).all(), label
        inside = (q[..., 0] >= x0) & (q[..., 0] <= x1) & (q[..., 1] >= y0) & (q[..., 1] <= y1)
        assert inside.all(), f"{label}: {int((~inside).sum())} estimates outside x {x0}..{x1}, y {y0}..{y1} m"
        if info["bbox"]:
            _event(f"{label}: raw output left the box (clamped by the harness's confine step)")
    _event(f"{ran} of {len(methods)} methods ran")
    return ran


def _property(profile):
    @profile
    @example(faults=[], seed=0)  # the clean walk
    @given(faults=st.lists(FAULTS, min_size=1, max_size=4), seed=st.integers(0, 2**16))
    def run(walk, methods, tmp_path_factory, faults, seed):
        root = apply_faults(walk, tmp_path_factory.getbasetemp() / "robust_loc_work", faults, seed)
        ran = check_methods(methods, root, seed)
        assert faults or ran == len(methods), f"only {ran} of {len(methods)} methods ran on the clean walk"
    return run


def test_fuzzed_streams_never_give_nan_nor_leave_the_floor(walk, methods, tmp_path_factory):
    _property(CI_LOC)(walk, methods, tmp_path_factory)


@pytest.mark.slow
def test_fuzzed_streams_never_give_nan_nor_leave_the_floor_slow(walk, methods, tmp_path_factory):
    _property(SLOW_LOC)(walk, methods, tmp_path_factory)
