"""The channel's variables of the radio-inertial graph (issue 32): the receiver's RSSI offset O(0) (dB,
``range.estimate_offset``) and the path-loss exponent's ratio E(0) to the ranges' own (``range.estimate_exponent``),
one each for the session, with their priors; the range factors that see them
(:func:`blenav.backend.factors.channel_range_factor`, many ranges per factor); and their estimates read back into
the :class:`~blenav.backend.graph_types.BackendResult`."""

from __future__ import annotations

import numpy as np

from .factors import channel_range_factor, load_gtsam


class ChannelVariables:
    """O(0) and, with ``rc.estimate_exponent``, E(0) of one graph. ``rc``: the :class:`~blenav.backend.config.
    RangeConfig`; ``gamma``: the ranges' path-loss exponent (RangeObs.gamma); prior means and initial values of the
    offset (dB) and of the channel's exponent (None: ``gamma``, the ranges' own), the exponent held in the graph as
    its ratio b to ``gamma`` (prior std ``rc.offset_sigma_db``, ``rc.exponent_sigma`` on b).

    While a batch graph is built (:meth:`defer` ... :meth:`flush`), the ranges :meth:`add_factors` is handed wait, so
    that one factor spans ``rc.channel_group`` keyframes (every Python call of a factor copies all the graph's values:
    fewer, larger factors cost less)."""

    def __init__(self, rc, gamma: float, offset_prior_db: float = 0.0, offset_init_db: float | None = None,
                 exponent_prior: float | None = None, exponent_init: float | None = None):
        self.rc, self.gamma = rc, float(gamma)
        self.offset_prior_db = float(offset_prior_db)
        self.offset_init_db = self.offset_prior_db if offset_init_db is None else float(offset_init_db)
        self.ratio_prior = 1.0 if exponent_prior is None else float(exponent_prior) / self.gamma
        self.ratio_init = self.ratio_prior if exponent_init is None else float(exponent_init) / self.gamma
        self._held: list | None = None  # ranges waiting for flush (a batch graph being built)

    def add_variables(self, g, v) -> None:
        """Insert O(0) (and E(0)) into ``v`` with their priors into ``g`` (once, with the first keyframe)."""
        gtsam = load_gtsam()
        from gtsam.symbol_shorthand import E, O

        v.insert(O(0), np.array([self.offset_init_db]))
        g.add(gtsam.PriorFactorVector(O(0), np.array([self.offset_prior_db]),
                                      gtsam.noiseModel.Isotropic.Sigma(1, self.rc.offset_sigma_db)))  # dB
        if self.rc.estimate_exponent:
            v.insert(E(0), np.array([self.ratio_init]))
            g.add(gtsam.PriorFactorVector(E(0), np.array([self.ratio_prior]),
                                          gtsam.noiseModel.Isotropic.Sigma(1, self.rc.exponent_sigma)))

    def defer(self) -> None:
        """From now until :meth:`flush`, :meth:`add_factors` keeps its ranges."""
        self._held = []

    def flush(self, g) -> None:
        """The ranges kept since :meth:`defer` into ``g``, one factor per ``rc.channel_group`` keyframes."""
        held, self._held = self._held or [], None
        self.add_factors(g, held, int(self.rc.channel_group))

    def add_factors(self, g, held: list[tuple[int, int, float]], group: int = 1) -> None:
        """The ``held`` ranges (keyframe, beacon row, range m) into ``g``, one factor per ``group`` keyframes (the
        M-estimator ``rc.robust`` acting per range inside it); kept instead while deferred."""
        if self._held is not None:
            self._held.extend(held)
            return
        if not held:
            return
        from gtsam.symbol_shorthand import E, L, O, X

        rc = self.rc
        k, j, r = (np.array(c) for c in zip(*held))
        grp = k // int(group)
        for gi in np.unique(grp).tolist():
            m = grp == gi
            g.add(channel_range_factor([X(x) for x in k[m].tolist()], [L(x) for x in j[m].tolist()], O(0),
                                       E(0) if rc.estimate_exponent else None, r[m], self.gamma, rc.d0, rc.sigma_n,
                                       rc.robust, rc.robust_k))

    def read(self, estimate, cov, res, fail) -> None:
        """The estimates into ``res``: ``offset_db`` / ``offset_std_db``, and ``channel_exponent`` /
        ``channel_exponent_std`` (b times gamma); ``cov``: key -> marginal covariance, or None; ``fail(stage, exc,
        k)`` records a marginal that failed."""
        from gtsam.symbol_shorthand import E, O

        for key, scale, attrs, on in ((O(0), 1.0, ("offset_db", "offset_std_db"), True),
                                      (E(0), self.gamma, ("channel_exponent", "channel_exponent_std"),
                                       self.rc.estimate_exponent)):
            if not on or estimate is None or not estimate.exists(key):
                continue
            setattr(res, attrs[0], float(estimate.atVector(key)[0]) * scale)
            if cov is not None:
                try:
                    setattr(res, attrs[1], float(np.sqrt(np.asarray(cov(key))[0, 0])) * scale)
                except RuntimeError as exc:
                    fail("marginals", exc, None)
