"""The range factors on channels the model does not fit (issue 32): the channel refit between LM passes
(blenav.backend.channel: the receiver offset and the path-loss exponent recovered from ranges against known
distances; the toy graph is in test_graph.py) and the robust kernels of ``range.robust``."""

import numpy as np
import pytest

from blenav.backend.channel import LogRangeFit, apply_log_fit, channel_of, fit_log_ranges, measured_ranges

D0, A_X, GAMMA = 1.78, -64.53, 1.72


def _ranges(d, gamma_c, offset_db, shadow_db, rng, clamp=10.0):
    """Ranges the model (A_X, GAMMA) reads from RSSI of a channel with exponent gamma_c and level A_X + offset_db."""
    rssi = A_X + offset_db - 10 * gamma_c * np.log10(d / D0) + rng.normal(0.0, shadow_db, len(d))
    r = D0 * 10 ** ((A_X - rssi) / (10 * GAMMA))
    keep = r <= clamp  # the back-end's clamp discards longer ranges
    return r[keep], d[keep]


def test_noise_free_line_gives_the_channel_exactly():
    d = np.linspace(0.5, 5.0, 50)
    r, d = _ranges(d, 2.6, 7.0, 0.0, np.random.default_rng(0))
    fit = fit_log_ranges(r, d, D0, slope=True)
    gc, off = channel_of(fit, GAMMA)
    assert gc == pytest.approx(2.6, abs=1e-9) and off == pytest.approx(7.0, abs=1e-9)
    np.testing.assert_allclose(apply_log_fit(r, fit), d, rtol=1e-9)  # the refitted ranges are the distances


@pytest.mark.parametrize("gamma_c,offset", [(2.6, 6.0), (2.0, -4.0), (1.72, 0.0)])
def test_shadowed_clamped_ranges_recover_exponent_and_offset(gamma_c, offset):
    """5 dB shadowing and the 10 m clamp: the slope fit (log range on log distance, truncated at the clamp) recovers
    the exponent within 0.15 and the offset within 0.5 dB; the level-only fit recovers the offset when the exponent
    is the model's. Without the truncation in the likelihood the slope comes out flat."""
    rng = np.random.default_rng(3)
    r, d = _ranges(rng.uniform(0.5, 5.0, 4000), gamma_c, offset, 5.0, rng)
    gc, off = channel_of(fit_log_ranges(r, d, D0, slope=True, max_r=10.0), GAMMA)
    assert gc == pytest.approx(gamma_c, abs=0.15) and off == pytest.approx(offset, abs=0.5)
    flat, _ = channel_of(fit_log_ranges(r, d, D0, slope=True), GAMMA)
    assert flat < gc - 0.05
    if gamma_c == GAMMA:
        _, off_level = channel_of(fit_log_ranges(r, d, D0, max_r=10.0), GAMMA)
        assert off_level == pytest.approx(offset, abs=0.5)


def test_too_few_or_degenerate_pairs_give_no_fit():
    assert fit_log_ranges(np.ones(5), np.ones(5), D0) is None
    assert fit_log_ranges(np.full(20, 2.0), np.full(20, 3.0), D0, slope=True) is None  # no spread of distance
    fit = fit_log_ranges(np.full(20, 2.0), np.full(20, 3.0), D0)  # the level alone is determined
    assert isinstance(fit, LogRangeFit) and fit.b == 1.0
    np.testing.assert_allclose(apply_log_fit(np.array([2.0]), fit), [3.0])


def test_a_bound_slope_keeps_the_level_consistent():
    """Distances all near 1 m but ranges spread (a bad solution): b is held at its bound and a refitted with it."""
    rng = np.random.default_rng(1)
    d = np.exp(rng.normal(0.5, 0.02, 200))
    r = np.exp(1.0 + 4.0 * (np.log(d) - 0.5) + rng.normal(0.0, 0.01, 200))  # slope 4: beyond the bound
    fit = fit_log_ranges(r, d, D0, slope=True)
    assert fit.b in (0.5, 2.0)
    assert np.isfinite(apply_log_fit(r, fit)).all()


def test_measured_ranges_undo_the_fit():
    """A later pass takes the ranges it used (turned by the previous fit) back to their measured values."""
    rng = np.random.default_rng(5)
    r = rng.uniform(0.3, 10.0, 50)
    fit = LogRangeFit(0.05, 1.3, D0, len(r))
    np.testing.assert_allclose(measured_ranges(apply_log_fit(r, fit), fit), r, rtol=1e-12)


@pytest.mark.parametrize("kind", ["huber", "cauchy", "geman_mcclure", "dcs"])
def test_range_kernels_weigh_small_residuals_fully_and_outliers_little(kind):
    """GTSAM's M-estimators behind ``range.robust``: a 0.5-sigma residual keeps most of its weight (DCS and Huber all of
    it), a 20-sigma one (an NLOS range) almost none; the redescending kernels (Geman-McClure, DCS) less than Huber."""
    pytest.importorskip("gtsam")
    from blenav.backend.factors import robust_noise

    w = robust_noise(kind, 1.345, 5.0).robust().weight
    assert w(0.5) > 0.75 and w(20.0) < 0.07
    if kind in ("huber", "dcs"):
        assert w(0.5) == pytest.approx(1.0)
    if kind in ("geman_mcclure", "dcs"):
        assert w(20.0) < 0.01 * robust_noise("huber", 1.345, 5.0).robust().weight(20.0) + 1e-3


def test_settings_that_cannot_work_together_are_refused():
    from blenav.backend.config import load_backend_config

    with pytest.raises(ValueError, match="refit_channel=line refits between LM passes"):
        load_backend_config(overrides=["range.refit_channel=line", "solver.method=isam2"])
    with pytest.raises(ValueError, match="passes >= 2"):
        load_backend_config(overrides=["range.refit_channel=level", "solver.method=lm", "solver.passes=1"])
    with pytest.raises(ValueError, match="choose one"):
        load_backend_config(overrides=["range.refit_channel=level", "solver.method=lm", "range.estimate_offset=true"])
    with pytest.raises(ValueError, match="mapping.robust=dcs"):
        load_backend_config(overrides=["mapping.robust=dcs"])
