"""A phone walk with no known start (issue 30): position fixes + inertial odometry + the floor plan + where the train
walks went, fused on the walkable grid by :mod:`blenav.crf.smoother`.

``fused-offline`` (``mode: offline``) is the forward-backward smoothed marginal mean of every node (the whole walk
informs every estimate: survey analysis, heat maps, the evaluation itself); ``fused-online`` (``mode: online``) the
forward (filtered) marginal mean, i.e. what a phone running the same model would show, from the first node with a
fix on (before it the model knows only the floor); with ``lag_s`` > 0 the fixed-lag marginal, what the phone shows
``lag_s`` behind the present (the observations up to then). The offline row and a lag-0 online row share one
forward-backward pass per walk (``inputs.cache``).

The model of a walk (nodes every ``dt_s`` seconds, cells of ``grid.cell_m`` over the floor plan's free space, edges up
to ``grid.max_step_m`` that do not cross a wall, :func:`blenav.crf.grid.build_grid`):

* start: uniform over the walkable cells (no ground truth, no first fix assumed right); ``start.source:
  first_waypoint`` instead pins the walk's first surveyed waypoint (reads its ground truth: a bound,
  :data:`START_SOURCES`);
* motion: the PDR odometry of :func:`blenav.filters.pdr_odometry.pdr_odometry` (detected steps along the phone's
  rotation vector, or blenav's AHRS heading where a walk has none (``heading: auto``), the step length fitted on the
  train walks), its displacement over each interval
  with std ``motion.sigma0_m + motion.sigma_per_m`` x its length, under ``layers``: hypotheses of the walk's heading
  offset and step scale (constant per walk; the posterior weighs them), not trusted as given;
* position prior (``path_prior``, from the train walks only): each transition's target cell weighted by
  (density of the train walks' positions, interpolated between their waypoints every 0.5 s, blurred by
  ``blur_m``, + ``floor`` / N) ^ ``weight``: walkers go where walkers went (the challenge's corridor prior);
* fixes: the first role of ``fix_roles`` the session has (the experiment's ``fixes`` block; each fix its own std,
  e.g. the KNN's calibrated ``fix_std``), each a heavy-tailed likelihood
  (1 - ``fix_outlier``) N(cell; fix, std^2 I) + ``fix_outlier`` / N at its nearest node, raised to ``fix_weight``: a
  fix 20 m off costs a bounded amount, so it cannot drag the track;
* off the survey (``off_survey``): a fingerprint answers with places the train walks visited, so a walker d m from
  every train walk gets a fix near the surveyed cell nearest to it, not near itself: the fix's mean at each cell is
  that nearest surveyed cell (``project``) and its std grows to sqrt(std^2 + (``std_per_m`` d)^2); a walk through an
  unsurveyed corridor beside a surveyed one is then not pulled onto the surveyed one (docs/results-ilc20.md);
* scans (``radio_map``, optional): each WiFi (+ BLE) scan of the walk scored at every cell against the floor's radio
  map (:mod:`blenav.localizers.radiomap`, built from the train walks), with the same heavy tail, raised to
  ``radio_map.weight``: a scan that resembles two places keeps both, and an unsurveyed place is uninformative
  rather than confidently wrong (the point fix of a KNN is neither).

A walk without IMU data (or without the heading source asked for) is not skipped: its fixes are smoothed under a
random walk of ``motion.no_odometry_sigma_m`` per node (the notes say so).

Estimates: (R identical runs) the marginal mean and covariance per node; offline with ``estimate: graph`` (the
realwalks experiment's ``fused-offline``) those means refined as a factor graph (:mod:`blenav.crf.walk_graph`): continuous
positions under the odometry's between-factors turned by the walk's most probable layer, the fixes under a robust
kernel, each node's marginal (covariance x ``graph.prior_scale``) as its prior; measured on the train walks against the
mean, the mode and the Viterbi path (docs/results-ilc20.md); online with ``estimate: graph`` (the experiment's
``fused-online``), at every node the graph over the filtered marginals of the last ``graph.window_s`` (the odometry as
measured: the layers' posterior is the whole walk's), its last node: causal, a phone's step adds one small graph.
numba via the smoother; the grid per floor and the walk's odometry are cached.
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import asdict

import numpy as np

from blenav.crf.grid import build_grid
from blenav.crf.smoother import Layers, forward_backward, viterbi
from blenav.crf.walk_graph import GraphSettings
from blenav.errors import MissingStream
from blenav.filters.pdr_odometry import DEFAULT_STEP_M, HEADING_SOURCES, fitted_step_length, pdr_odometry, resolve_heading
from blenav.filters.yaw_hold import check_yaw

from .base import NO_IO_MODEL, Estimate, FixConsumer, InertialModelConsumer, Localizer, Trained, attach_inertial
from .inputs import RunInputs
from .radiomap import RadioMapConfig, build_radio_map
from .survey import SURVEY_STEP_S, fix_log_likelihood, path_prior, survey_counts, survey_distance

__all__ = ["FusedWalk", "MODES", "fix_log_likelihood", "path_prior", "survey_distance"]

MODES = ("online", "offline")
#: what an offline row reports per node: the smoothed marginal's mean (default) or its most probable cell, or the most
#: probable joint path (Viterbi); measured on the train walks (docs/results-ilc20.md)
ESTIMATES = ("mean", "mode", "viterbi", "graph")
#: where a walk starts: uniform over the walkable cells (no ground truth: the contract rows), or N(its first surveyed
#: waypoint, start.std_m^2 I) at that waypoint's time, which **reads the scored walk's ground truth**: a bound on what
#: the unknown start costs (``benchmarks/fused_start.py``), as the PDR rows start at the first waypoint
START_SOURCES = ("uniform", "first_waypoint")


def _block(name: str, what: str, given, defaults: dict) -> dict:
    """``defaults`` updated with the config block ``given`` (a dict or DictConfig); a key not in ``defaults`` (a
    misspelling) is refused, naming the method and the block."""
    given = dict(given or {})
    unknown = set(given) - set(defaults)
    if unknown:
        raise ValueError(f"method {name!r}, {what}: unknown key(s) {sorted(unknown)}; known: {', '.join(defaults)}")
    return {**defaults, **given}


class FusedWalk(Localizer, FixConsumer, Trained, InertialModelConsumer):
    """Fixes + inertial odometry (PDR or learned) + plan + train-walk prior on the walkable grid, no known start
    (module doc)."""

    uses_floor_plan = True
    fix_roles_are_alternatives = True  # the first role of fix_roles the session has

    def __init__(self, name: str, shared=None, mode: str = "offline", estimate: str = "mean", lag_s: float = 0.0,
                 fix_roles=("both", "ble"),
                 odometry: dict | None = None, grid: dict | None = None, dt_s: float = 1.0,
                 motion: dict | None = None, layers: dict | None = None, fix_outlier: float = 0.01,
                 fix_std_scale: float = 1.0, fix_weight: float = 1.0, radio_map: dict | None = None,
                 path_prior: dict | None = None, prune: float = 1e-6, graph: dict | None = None,
                 off_survey: dict | None = None, start: dict | None = None, novelty: dict | None = None):
        super().__init__(name, shared)
        if mode not in MODES:
            raise ValueError(f"method {name!r}: mode must be one of {MODES}, got {mode!r}")
        self.mode = mode
        if estimate not in ESTIMATES or (mode == "online" and estimate not in ("mean", "graph")):
            raise ValueError(f"method {name!r}: estimate must be one of {ESTIMATES} (online: mean or graph), got "
                             f"{estimate!r}")
        self.estimate = estimate
        #: ``estimate: graph``: the grid's marginals refined as a factor graph (:mod:`blenav.crf.walk_graph`)
        graph = _block(name, "graph", graph, asdict(GraphSettings()))
        try:
            self.graph = GraphSettings(**graph)
        except ValueError as exc:
            raise ValueError(f"method {name!r}: graph.{exc}") from None
        if mode == "online" and not self.graph.prior_scale > 0:
            raise ValueError(f"method {name!r}: graph.prior_scale must be finite and >= 0 (online: > 0, a window "
                             f"without a fix has no other anchor), got {self.graph.prior_scale}")
        self.lag_s = float(lag_s)
        if self.estimate == "graph" and self.mode == "online" and self.lag_s > 0:
            raise ValueError(f"method {name!r}: the online graph (estimate: graph) reads the filter, not a lag: lag_s 0")
        if not 0.0 <= self.lag_s <= 60.0:
            raise ValueError(f"method {name!r}: lag_s must be in [0, 60] s, got {lag_s}")
        self.roles = [str(r) for r in (fix_roles or [])]
        if not self.roles:
            raise ValueError(f"method {name!r}: fix_roles names no role of the experiment's fixes block")
        odo = _block(name, "odometry", odometry, {"source": "auto", "heading": "auto", "step_length": None,
                                                  "yaw": "auto"})
        self.source = str(odo.get("source", "auto"))
        if self.source not in ("auto", "pdr", "lio"):
            raise ValueError(f"method {name!r}: odometry.source must be auto, pdr or lio, got {self.source!r}")
        self.io_model, self.io_reason = None, (NO_IO_MODEL if self.source == "lio" else None)
        self.heading = str(odo.get("heading", "auto"))
        if self.heading not in HEADING_SOURCES:
            raise ValueError(f"method {name!r}: odometry.heading must be one of {HEADING_SOURCES}, got "
                             f"{self.heading!r}")
        self.step_length = odo.get("step_length")
        self.yaw = check_yaw(odo.get("yaw", "auto"), f"method {name!r}: odometry.yaw")
        g = _block(name, "grid", grid, {"cell_m": 1.0, "max_step_m": 3.0})
        self.cell_m, self.max_step_m = float(g["cell_m"]), float(g["max_step_m"])
        self.dt_s = float(dt_s)
        mo = _block(name, "motion", motion, {"sigma0_m": 0.3, "sigma_per_m": 0.15, "no_odometry_sigma_m": 1.0})
        self.sigma0, self.sigma_per = float(mo["sigma0_m"]), float(mo["sigma_per_m"])
        self.no_odometry_sigma = float(mo["no_odometry_sigma_m"])
        la = _block(name, "layers", layers, {"heading_offsets_deg": [-5.7, 0.0, 5.7], "scales": [1.0]})
        try:
            self.layers = Layers(tuple(math.radians(float(a)) for a in la["heading_offsets_deg"]),
                                 tuple(float(s) for s in la["scales"]))
        except ValueError as exc:
            raise ValueError(f"method {name!r}: {exc}") from None
        self.fix_outlier, self.fix_std_scale = float(fix_outlier), float(fix_std_scale)
        self.fix_weight = float(fix_weight)
        if not self.fix_weight >= 0:
            raise ValueError(f"method {name!r}: fix_weight must be >= 0, got {self.fix_weight}")
        if radio_map is None:
            self.radio_map, self.radio_weight = None, 0.0
        else:
            rm = _block(name, "radio_map", radio_map, {**asdict(RadioMapConfig()), "weight": 1.0})
            self.radio_weight = float(rm.pop("weight"))
            try:
                self.radio_map = RadioMapConfig(**rm)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"method {name!r}: {exc}") from None
        pp = _block(name, "path_prior", path_prior, {"weight": 1.0, "floor": 0.05, "blur_m": 1.5})
        self.prior_weight, self.prior_floor, self.prior_blur = float(pp["weight"]), float(pp["floor"]), float(pp["blur_m"])
        osv = _block(name, "off_survey", off_survey, {"std_per_m": 0.5, "project": True})
        self.off_std_per_m, self.off_project = float(osv["std_per_m"]), bool(osv["project"])
        if not self.off_std_per_m >= 0:
            raise ValueError(f"method {name!r}: off_survey.std_per_m must be >= 0, got {self.off_std_per_m}")
        nv = _block(name, "novelty", novelty, {"weight": 0.0, "off_m": 5.0})
        self.novelty_weight, self.novelty_off_m = float(nv["weight"]), float(nv["off_m"])
        if not (self.novelty_weight >= 0 and self.novelty_off_m > 0):
            raise ValueError(f"method {name!r}: novelty needs weight >= 0 and off_m > 0, got {self.novelty_weight}, "
                             f"{self.novelty_off_m}")
        st = _block(name, "start", start, {"source": "uniform", "std_m": 1.0})
        self.start_source, self.start_std = str(st["source"]), float(st["std_m"])
        if self.start_source not in START_SOURCES:
            raise ValueError(f"method {name!r}: start.source must be one of {START_SOURCES}, got {self.start_source!r}")
        if not self.start_std > 0:
            raise ValueError(f"method {name!r}: start.std_m must be > 0, got {self.start_std}")
        self.prune = float(prune)
        if not 0.0 <= self.prune < 1.0:
            raise ValueError(f"method {name!r}: prune must be in [0, 1), got {prune}")
        if not (self.prior_floor > 0 and self.prior_weight >= 0 and self.prior_blur > 0):
            raise ValueError(f"method {name!r}: path_prior needs floor > 0, weight >= 0 and blur_m > 0 (got "
                             f"{self.prior_floor}, {self.prior_weight}, {self.prior_blur})")
        if not self.sigma_per >= 0:
            raise ValueError(f"method {name!r}: motion.sigma_per_m must be >= 0, got {self.sigma_per}")
        if self.estimate == "graph" and (self.fix_weight != 1.0 or self.radio_map is not None):
            raise ValueError(f"method {name!r}: estimate: graph weighs each fix at full weight and no radio-map scan: "
                             f"fix_weight 1 and no radio_map (got {self.fix_weight:g}, {self.radio_map})")
        if self.fix_weight == 0 and self.radio_map is None:
            raise ValueError(f"method {name!r}: fix_weight 0 without a radio_map leaves nothing to observe")
        for what, v, lo in (("dt_s", self.dt_s, 1e-3), ("grid.cell_m", self.cell_m, 0.05),
                            ("motion.sigma0_m", self.sigma0, 1e-3), ("fix_std_scale", self.fix_std_scale, 1e-3),
                            ("motion.no_odometry_sigma_m", self.no_odometry_sigma, 1e-3)):
            if not v >= lo:
                raise ValueError(f"method {name!r}: {what} must be >= {lo}, got {v}")
        if not 0.0 < self.fix_outlier < 1.0:
            raise ValueError(f"method {name!r}: fix_outlier must be in (0, 1), got {self.fix_outlier}")
        if self.max_step_m < self.cell_m:
            raise ValueError(f"method {name!r}: grid.max_step_m ({self.max_step_m}) < grid.cell_m ({self.cell_m}): no "
                             f"cell could reach another")
        self.fitted_step: float | None = None
        self.train: list = []

    def fix_roles(self) -> list[str]:
        return list(self.roles)

    def attach_io_model(self, path: str | None, load) -> str | None:
        """``source: lio`` needs ``io_model`` (skipped with the reason without it); ``auto`` uses it when given (and is
        skipped with the reason when the given one cannot be used), PDR otherwise; ``pdr`` never does."""
        if self.source == "pdr" or (self.source == "auto" and not path):
            return None
        self.io_model, self.io_reason = attach_inertial(path, load)
        return self.io_reason  # a model given that cannot be used is said, never replaced by PDR in silence

    # ------------------------------------------------------------------ training
    def fit(self, sessions: list, inputs: RunInputs) -> dict | None:
        """The step length (unless given) and the train walks the path prior is built from (per floor, at run
        time)."""
        self.train = [s for s in sessions if s.labelled]
        rep = {"path_prior_walks": len(self.train)}
        if self.step_length is None:
            rep["step_length"] = fitted_step_length(sessions, None, inputs.cache)
            self.fitted_step = float(rep["step_length"]["step_length_m"])
        return rep

    def _step(self) -> float:
        if self.step_length is not None:
            return float(self.step_length)
        return self.fitted_step if self.fitted_step is not None else DEFAULT_STEP_M

    def _floor_model(self, session, cache: dict):
        """(grid, log target weights (N,)) of the session's floor (cached per floor and settings)."""
        floor = (session.building.id, str(session.meta.get("floor")))
        gkey = ("fused-walk-grid", *floor, self.cell_m, self.max_step_m)  # the grid: shared by every row's settings
        if gkey not in cache:
            cache[gkey] = build_grid(session.floor, cell_m=self.cell_m, max_step_m=self.max_step_m)
        grid = cache[gkey]
        same = [s for s in self.train if s.building.id == session.building.id
                and str(s.meta.get("floor")) == str(session.meta.get("floor"))]
        # where the floor's train walks went: counted once, shared by every row's prior and off-survey settings
        ckey = ("fused-walk-survey", *gkey[1:], tuple(s.id for s in same))
        if ckey not in cache:
            cnt = survey_counts(grid, same, SURVEY_STEP_S)
            cache[ckey] = (cnt, survey_distance(grid, same, counts=cnt))
        cnt, survey = cache[ckey]
        key = ("fused-walk-floor", *gkey[1:], tuple(s.id for s in same), self.prior_weight, self.prior_floor,
               self.prior_blur, self.radio_map)
        if key not in cache:
            if same and self.prior_weight > 0:
                dens = path_prior(grid, same, self.prior_blur, counts=cnt)
                lp = self.prior_weight * np.log(dens + self.prior_floor / grid.n_cells)
            else:
                lp = np.zeros(grid.n_cells)
            rmap = build_radio_map(grid, same, self.radio_map) if same and self.radio_map is not None else None
            cache[key] = (grid, lp, len(same), rmap)
        return (*cache[key], survey)

    def _lag_nodes(self) -> int:
        """The online row's fixed lag in nodes (``lag_s`` / ``dt_s``, rounded); the offline row needs none."""
        return int(round(self.lag_s / self.dt_s)) if self.mode == "online" else 0

    def heading_of(self, session) -> str:
        """The PDR heading source: ``auto`` takes the phone's rotation vector where the walk has one (orientation.csv),
        else blenav's AHRS."""
        return resolve_heading(session, self.heading)

    def _fixes(self, inputs: RunInputs):
        """The first role of ``fix_roles`` the session has: (role, RoleFixes)."""
        why = []
        for role in self.roles:
            try:
                return role, inputs.fixes[role]
            except MissingStream as exc:
                why.append(str(exc))
        raise MissingStream(f"{self.name}: no fixes of roles {self.roles}: " + "; ".join(why))

    # ------------------------------------------------------------------ running
    def smooth(self, session, inputs: RunInputs) -> dict:
        """The walk's forward-backward result and its nodes (cached per session and settings for both modes)."""
        if inputs.fixes is None:
            raise MissingStream(f"{self.name}: the experiment has no fixes block (roles {self.roles})")
        role, fx = self._fixes(inputs)
        novel = fx.off_log_ratio if self.novelty_weight > 0 else None
        digest = hashlib.sha1(b"".join(np.ascontiguousarray(a, float).tobytes()
                                       for a in (fx.t, fx.xy, fx.std, *([] if novel is None else [novel]))))
        lio = self.io_model if self.source in ("auto", "lio") else None
        if self.io_reason is not None:  # source lio without a model, or a model given that cannot be used
            raise MissingStream(self.io_reason)
        key = ("fused-walk", session.id, role, digest.hexdigest(), self._step(), self.heading, self.yaw, lio.key if lio else None, self.cell_m,
               self.max_step_m,
               self.dt_s, self.sigma0, self.sigma_per, self.no_odometry_sigma, self.layers, self.fix_outlier, self.fix_std_scale, self.prior_weight,
               self.prior_floor, self.prior_blur, self.prune, self.estimate == "viterbi", self.fix_weight,
               self.radio_map, self.radio_weight, self._lag_nodes(), tuple(s.id for s in self.train), self.off_std_per_m,
               self.off_project, self.start_source, self.start_std, self.novelty_weight, self.novelty_off_m)
        if key in inputs.cache:
            return inputs.cache[key]
        t0 = time.perf_counter()
        ok = np.isfinite(fx.xy).all(axis=1)
        if not ok.any():
            raise MissingStream(f"session {session.id}: no finite {role} fix")
        ft, fxy = fx.t[ok], fx.xy[ok]
        fsd = self.fix_std_scale * np.where(np.isfinite(fx.std[ok]) & (fx.std[ok] > 0), fx.std[ok], 3.0)
        heading = self.heading_of(session)
        try:
            if lio is not None:  # the learned inertial odometry (issue 31), in the frame of the walk's attitude
                odo = lio.odometry(session, cache=inputs.cache)  # in the attitude it was trained in
                heading = f"learned ({resolve_heading(session, lio.attitude)} frame)"
            else:
                odo = pdr_odometry(session, heading, self._step(), cache=inputs.cache, yaw=self.yaw)
        except MissingStream as exc:  # no IMU (or no heading): the fixes alone, under a random walk at walking pace
            odo, heading = None, f"none ({exc}; random walk of {self.no_odometry_sigma:g} m per node)"
        grid, log_prior, n_prior, rmap, (sdist, snear) = self._floor_model(session, inputs.cache)
        cxy = grid.xy[snear] if self.off_project else grid.xy  # where a fix at each cell is expected
        extra = (self.off_std_per_m * sdist) ** 2  # (N,) var a KNN fix adds off the survey (m^2)
        if rmap is not None:  # the session's scans against the floor's radio map
            try:
                st, Q = rmap.scans(session)
            except MissingStream:
                st, Q = np.zeros(0), None
        else:
            st, Q = np.zeros(0), None
        if odo is not None:
            t_lo = float(min(odo["t"].iloc[0], ft[0], *st[:1]))
            t_hi = float(max(odo["t"].iloc[-1], ft[-1], *st[-1:]))
            T = np.arange(t_lo, t_hi + 0.5 * self.dt_s, self.dt_s)
            ox = np.interp(T, odo["t"].to_numpy(float), odo["x"].to_numpy(float))
            oy = np.interp(T, odo["t"].to_numpy(float), odo["y"].to_numpy(float))
            disp = np.diff(np.column_stack([ox, oy]), axis=0)
            sigma = self.sigma0 + self.sigma_per * np.hypot(disp[:, 0], disp[:, 1])
            # intervals outside the IMU's span (fixes heard before it starts or after it ends): no odometry there
            o0, o1 = float(odo["t"].iloc[0]), float(odo["t"].iloc[-1])
            sigma = np.where((T[1:] <= o0) | (T[:-1] >= o1), self.no_odometry_sigma, sigma)
        else:
            T = np.arange(float(ft[0]), float(ft[-1]) + 0.5 * self.dt_s, self.dt_s)
            disp = np.zeros((len(T) - 1, 2))
            sigma = np.full(len(T) - 1, self.no_odometry_sigma)
        fix_node = np.clip(np.round((ft - T[0]) / self.dt_s).astype(np.int64), 0, len(T) - 1)
        unary: list = [None] * len(T)
        lo_out, lo_in = math.log(self.fix_outlier / grid.n_cells), math.log1p(-self.fix_outlier)  # the scans' tail

        def observe(k, ll, weight):  # ll: with its heavy tail; times the observation's weight
            ll = ll if weight == 1.0 else weight * ll
            unary[k] = ll if unary[k] is None else unary[k] + ll

        if self.fix_weight > 0:
            for k, xy, sd in zip(fix_node, fxy, fsd):  # fixes: F per walk (a few dozen), each (N,): one numpy pass each
                observe(k, fix_log_likelihood(cxy, extra, xy, sd, self.fix_outlier, grid.n_cells), self.fix_weight)
        n_novel = 0
        if novel is not None:  # what each fix's scan says of the walker being off the survey: its log Bayes factor on
            off = sdist > self.novelty_off_m  # the cells off it, times the weight (the fixes' errors are correlated)
            for k, lr in zip(fix_node, np.asarray(novel, float)[ok]):
                if np.isfinite(lr):
                    observe(k, np.where(off, self.novelty_weight * float(lr), 0.0), 1.0)
                    n_novel += 1
        first = int(fix_node.min())
        if self.start_source == "first_waypoint":  # reads the ground truth (START_SOURCES): a bound, not a method
            k0, ll0 = self._start_log_likelihood(session, grid, T)
            observe(k0, ll0, 1.0)
            first = min(first, k0)
        if Q is not None and len(st):
            snode = np.clip(np.round((st - T[0]) / self.dt_s).astype(np.int64), 0, len(T) - 1)
            for k, ll in zip(snode, rmap.log_likelihood(Q)):
                observe(k, np.logaddexp(lo_in + ll, lo_out), self.radio_weight)
            first = min(first, int(snode.min()))
        res = forward_backward(grid, disp, sigma, unary, log_prior=log_prior, layers=self.layers, prune=self.prune,
                               lag=self._lag_nodes())
        path = None
        if self.estimate == "viterbi":
            path = grid.xy[viterbi(grid, disp, sigma, unary, log_prior=log_prior, layers=self.layers,
                                   prune=self.prune)[0]]
        out = {"t": T, "res": res, "first_fix": first, "role": role, "n_fixes": int(len(ft)), "heading": heading,
               "novelty_fixes": n_novel,
               "radio_scans": int(len(st)),
               "prior_walks": n_prior, "wall_s": time.perf_counter() - t0, "path": path, "grid_xy": grid.xy,
               "graph_inputs": (disp, sigma, fix_node, fxy, fsd), "graphs": {}}
        inputs.cache[key] = out
        return out

    def _start_log_likelihood(self, session, grid, T: np.ndarray) -> tuple[int, np.ndarray]:
        """``start.source: first_waypoint``: (the node nearest the walk's first surveyed waypoint's time, log N(cell;
        that waypoint, start.std_m^2 I) (N,) over the cells); MissingStream for a walk without ground truth."""
        gt = session.groundtruth
        if gt is None or not len(gt):
            raise MissingStream(f"{self.name}: start.source first_waypoint needs the walk's ground truth; session "
                                f"{session.id} has none")
        t0, xy0 = float(gt["t"].iloc[0]), gt[["x", "y"]].to_numpy(float)[0]
        k0 = int(np.clip(np.round((t0 - T[0]) / self.dt_s), 0, len(T) - 1))
        return k0, -0.5 * ((grid.xy - xy0) ** 2).sum(axis=1) / self.start_std ** 2

    def _graph(self, sm: dict) -> tuple[np.ndarray, np.ndarray]:
        """``estimate: graph``: the walk's smoothed marginals refined as a factor graph (:mod:`blenav.crf.walk_graph`)
        under its most probable layer; (positions (K, 2), covariances (K, 2, 2)), cached with the pass per setting."""
        if self.graph not in sm["graphs"]:
            r = sm["res"]
            disp, sigma, fix_node, fxy, fsd = sm["graph_inputs"]
            turned = self.layers.turn(int(np.argmax(r.layer_post)), disp)
            sm["graphs"][self.graph] = self.graph.refine(r.smoothed_mean, r.smoothed_cov, turned, sigma, fix_node, fxy,
                                                         fsd, self.cell_m)
        return sm["graphs"][self.graph]

    def _graph_online(self, sm: dict, k0: int) -> tuple[np.ndarray, np.ndarray]:
        """Online ``estimate: graph``: at every node k >= ``k0`` the factor graph over nodes (k - W, k] (W =
        ``graph.window_s`` / ``dt_s``) with their filtered marginals as priors, the fixes of those nodes and the odometry
        as measured (the layers' posterior is the whole walk's: not causal); its node k. Causal as the filter is: node k
        reads nothing after it, i.e. no fix later than T[k] + dt/2 (fixes go to their nearest node). (positions
        (K - k0, 2), covariances (K - k0, 2, 2))."""
        r = sm["res"]
        disp, sigma, fix_node, fxy, fsd = sm["graph_inputs"]
        K = len(sm["t"])
        pos, cov = np.empty((K - k0, 2)), np.empty((K - k0, 2, 2))
        W = max(1, int(round(self.graph.window_s / self.dt_s)))
        for k in range(k0, K):  # one small graph per node, as a phone's step would solve it
            a = max(0, k + 1 - W)
            m = (fix_node <= k) & (fix_node >= a)
            p, c = self.graph.refine(r.filtered_mean[a:k + 1], r.filtered_cov[a:k + 1], disp[a:k], sigma[a:k],
                                     fix_node[m] - a, fxy[m], fsd[m], self.cell_m)
            pos[k - k0], cov[k - k0] = p[-1], c[-1]
        return pos, cov

    def run(self, session, n_runs: int, seed: int, inputs: RunInputs | None = None) -> Estimate:
        t0 = time.perf_counter()
        inputs = inputs or RunInputs()
        sm = self.smooth(session, inputs)
        r, T = sm["res"], sm["t"]
        if self.mode == "online" and self.estimate == "graph":
            k0 = sm["first_fix"]
            t, (pos, cov) = T[k0:], self._graph_online(sm, k0)
        elif self.mode == "online":
            k0 = sm["first_fix"]
            t, pos, cov = T[k0:], r.filtered_mean[k0:], r.filtered_cov[k0:]
        elif self.estimate == "mean":
            t, pos, cov = T, r.smoothed_mean, r.smoothed_cov
        elif self.estimate == "graph":  # positions and covariances of the refined graph
            t, (pos, cov) = T, self._graph(sm)
        else:  # the smoothed marginal's mode, or the Viterbi path; the marginal's covariance about it
            pos = sm["grid_xy"][r.smoothed_mode] if self.estimate == "mode" else sm["path"]
            d = pos - r.smoothed_mean
            t, cov = T, r.smoothed_cov + np.einsum("ki,kj->kij", d, d)
        if not np.isfinite(pos).all():
            raise ValueError(f"{self.name}: non-finite position on session {session.id}")
        R = int(n_runs)
        th, sc = self.layers.at(int(np.argmax(r.layer_post)))
        return Estimate(self.name, session.id, t, np.broadcast_to(pos, (R,) + pos.shape).copy(),
                        np.broadcast_to(cov, (R,) + cov.shape).copy(), wall_s=time.perf_counter() - t0 + sm["wall_s"],
                        notes=[f"{self.mode}: fixes of role {sm['role']}"
                               + (f" (weight {self.fix_weight:g})" if self.fix_weight != 1.0 else "")
                               + (f" + {sm['radio_scans']} scans on the radio map" if self.radio_map is not None else "")
                               + (f" + the off-survey evidence of {sm['novelty_fixes']} fixes (weight "
                                  f"{self.novelty_weight:g}, off beyond {self.novelty_off_m:g} m)"
                                  if self.novelty_weight > 0 else "")
                               + (f" + learned inertial odometry ({sm['heading']})" if sm['heading'].startswith("learned")
                                  else f" + PDR odometry (heading {sm['heading']}, step {self._step():.3f} m)")
                               + f" + plan + train-walk prior ({sm['prior_walks']} walks), "
                               + (f"start N(first waypoint, {self.start_std:g} m: ground truth); "
                                  if self.start_source == "first_waypoint" else "uniform start; ")
                               + f"grid {self.cell_m:g} m, {self.layers.n} heading/scale layers"
                               + (f"; estimate {self.estimate}" if self.estimate != "mean" else "")],
                        outputs={"layer": {"heading_offset_deg": math.degrees(th), "step_scale": sc}})
