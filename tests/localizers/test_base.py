"""The localizer interface: any class behind it runs in an experiment; config errors name method and node."""

from __future__ import annotations

import numpy as np
import pytest

from blenav.configs import compose
from blenav.errors import EvalError, MissingStream
from blenav.eval.harness import build_methods, evaluate
from blenav.localizers import Estimate, FixConsumer, Localizer, ParticleFilterLocalizer
from blenav.trust import register
from helpers import make_tiny_dataset


class GroundTruthPlusOffset(Localizer):
    """A localizer the harness has never heard of: the ground truth shifted by ``offset_m`` in x, at 2 Hz."""

    def __init__(self, name, shared=None, offset_m: float = 1.0):
        super().__init__(name, shared)
        self.offset_m = float(offset_m)

    def run(self, session, n_runs, seed, ctx=None):
        gt = session.groundtruth
        if not len(gt):
            raise MissingStream("no ground truth")
        t = np.arange(gt["t"].iloc[0], gt["t"].iloc[-1], 0.5)
        xy = np.stack([np.interp(t, gt["t"], gt["x"]) + self.offset_m, np.interp(t, gt["t"], gt["y"])], -1)
        cov = np.broadcast_to(np.eye(2) * 0.25, (n_runs, len(t), 2, 2)).copy()
        return Estimate(self.name, session.id, t, np.broadcast_to(xy, (n_runs,) + xy.shape).copy(), cov,
                        outputs={"smoothed": xy})


class NeedsRadio(Localizer):
    def run(self, session, n_runs, seed, ctx=None):
        raise MissingStream("no RTT ranges in this session")


register(GroundTruthPlusOffset, NeedsRadio)  # code, not a file: the configs below may name them (blenav.trust)


def _cfg(data, out, *over):
    return compose("eval", "experiment=mapfusion_002", f"data={data}", "runs=2", f"out={out}", "plots=false",
                   "progress=false", *over)


def test_a_new_class_runs_without_any_harness_change(tmp_path):
    data = make_tiny_dataset(tmp_path / "tiny")
    cfg = _cfg(data, tmp_path / "out", f"+methods.shifted={{_target_: {__name__}.GroundTruthPlusOffset, "
               "label: shifted, offset_m: 1.5}", f"+methods.radio={{_target_: {__name__}.NeedsRadio}}",
               "methods.pf_pl_map=null", "methods.pf_ps=null", "methods.pf_ps_map=null", "calibration=none")
    res = evaluate(cfg)
    m = res["methods"]["shifted"]
    # scored against the ground truth like every method: a constant 1.5 m offset
    assert m["error_m"]["mean"] == pytest.approx(1.5, abs=1e-9) and m["rmse_m"]["mean"] == pytest.approx(1.5)
    assert res["methods"]["radio"] == {"skipped": {"walk0": "no RTT ranges in this session"}}
    assert np.isfinite(res["methods"]["PF-PL"]["error_m"]["mean"])


def test_estimate_checks_shapes_and_gives_std():
    t = np.arange(3.0)
    cov = np.zeros((2, 3, 2, 2))
    cov[..., 0, 0], cov[..., 1, 1] = 4.0, 1.0
    e = Estimate("m", "s", t, np.zeros((2, 3, 2)), cov)
    np.testing.assert_allclose(e.std, np.sqrt(2.5))
    assert e.n_runs == 2 and Estimate("m", "s", t, np.zeros((1, 3, 2))).std is None
    with pytest.raises(ValueError, match=r"\(R, K, 2\)"):
        Estimate("m", "s", t, np.zeros((2, 4, 2)))
    with pytest.raises(ValueError, match=r"cov"):
        Estimate("m", "s", t, np.zeros((2, 3, 2)), np.zeros((2, 3, 2)))


@pytest.mark.parametrize("override, words", [
    ("methods.pf_pl.map.init=gt", ["PF-PL", "map", "gt"]),
    ("+methods.pf_pl.steps.threshod=1", ["PF-PL", "steps", "threshod"]),
    ("+methods.pf_pl.attitude.gian=1", ["PF-PL", "attitude", "gian"]),
    ("+methods.pf_pl.filter.n_particle=3", ["PF-PL", "filter", "n_particle"]),
    ("+methods.pf_pl.motion.sigmaa=1", ["PF-PL", "motion", "sigmaa"]),
    ("~methods.pf_pl._target_", ["PF-PL", "_target_"]),
    ("methods.pf_pl._target_=blenav.filters.motion.RandomWalk", ["PF-PL"]),
])
def test_config_errors_name_the_method_and_node(override, words):
    with pytest.raises(EvalError) as err:
        build_methods(_cfg("unused", "unused", override))
    assert all(w in str(err.value) for w in words), str(err.value)


def test_step_detector_and_attitude_are_settable_per_method():
    ms = build_methods(_cfg("unused", "unused", "experiment=frontend_000", "+methods.IMU.steps.threshold=2.5",
                            "+methods.IMU.attitude.gain=0.1", "attitude.median_window=3"))
    imu, rw = ms["IMU"].method, ms["RW"].method
    assert imu.steps.threshold == 2.5 and rw.steps.threshold != 2.5
    assert imu.attitude.gain == 0.1 and rw.attitude.gain is None
    assert imu.attitude.median_window == rw.attitude.median_window == 3  # the experiment-wide node is the default


def test_capabilities_are_declared():
    ms = build_methods(compose("eval", "experiment=mapprior_003_table37", "data=unused"))
    assert isinstance(ms["dense-BLE"], FixConsumer) and ms["dense-BLE"].fix_roles() == ["dense"]
    assert ms["sparse-BLE+IO+map"].fix_roles() == ["sparse"] and ms["IO"].fix_roles() == []
    assert isinstance(ms["IO"], ParticleFilterLocalizer) and not ms["IO"].wants_path_loss_fit()
    ps = build_methods(_cfg("unused", "unused"))["PF-PS"]
    assert ps.wants_path_loss_fit()
