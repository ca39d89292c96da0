"""Settings of the smoothing back-end (Hydra group ``backend/``, schema :class:`BackendConfig`).

``conf/backend/default.yaml`` lists ``- schema`` in its defaults, so a misspelt key or a value outside its
Enum fails when the config is composed. :func:`load_backend_config` reads it outside Hydra (the
``blenav-map`` command, tests) with the same check.

Units are in the comments of every field; noise densities are continuous-time (per sqrt(Hz)), as GTSAM's
preintegration expects them (it divides by the sample interval itself).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Optional


class Solver(StrEnum):
    """``solver.method``: iSAM2 (online, one update per keyframe) or Levenberg-Marquardt (offline batch)."""

    isam2 = "isam2"
    lm = "lm"


class RobustKernel(StrEnum):
    """``range.robust``: the M-estimator of the range factors (GTSAM ``noiseModel.mEstimator``), its width ``robust_k``
    in sigmas: Huber, Cauchy, Geman-McClure, or dynamic covariance scaling (DCS, Agarwal et al. 2013: the
    switchable constraints' closed form; GTSAM's parameter Phi = ``robust_k`` squared). The mapping mode takes none,
    huber and cauchy."""

    none = "none"
    huber = "huber"
    cauchy = "cauchy"
    geman_mcclure = "geman_mcclure"
    dcs = "dcs"


#: the kernels the mapping mode's residuals take (its own square-root form, blenav.backend.mapping_factor)
MAPPING_KERNELS = (RobustKernel.none, RobustKernel.huber, RobustKernel.cauchy)


def mapping_kernel(kernel, where: str = "mapping.robust") -> RobustKernel:
    """``kernel`` as a :class:`RobustKernel` the mapping mode takes; ValueError naming ``where`` for a range-only one."""
    k = RobustKernel(kernel)
    if k not in MAPPING_KERNELS:
        raise ValueError(f"{where}={k.value} is a kernel of the range factors; the mapping mode takes "
                         f"{', '.join(m.value for m in MAPPING_KERNELS)}")
    return k


class Combine(StrEnum):
    """``range.combine``: every range its own factor (000: "does not discard any measurements"), or one factor
    per beacon and keyframe with the median of its ranges in the keyframe interval."""

    all = "all"
    median = "median"


class ChannelRefit(StrEnum):
    """``range.refit_channel``: between LM passes, every range through the channel refitted on the previous pass's
    distances (:mod:`blenav.backend.channel`): not at all, its level (the receiver offset), or level and exponent."""

    none = "none"
    level = "level"
    line = "line"


class Factorization(StrEnum):
    """``solver.factorization``: how GTSAM eliminates the linearised system. Cholesky is the fast default;
    QR (about 10x slower on this graph) tolerates worse conditioning. With stiff IMU position increments
    (``imu.integration_sigma`` < 1e-2 m/sqrt(s)) against 3-5 m priors and ranges, iSAM2's Cholesky reports
    an indeterminant system where QR does not."""

    qr = "qr"
    cholesky = "cholesky"


class InitFrom(StrEnum):
    """``init.from_runs``: which of the front-end's R runs initialises the graph (Fig. 2 of 000)."""

    mean = "mean"
    run0 = "run0"


@dataclass
class ImuConfig:
    """IMU noise for GTSAM's preintegration (Forster et al., ref. [2] of 000), nav frame ENU (gravity -z)."""

    gravity_mps2: float = 9.80665  # m/s^2, magnitude of gravity (nav frame: world ENU, gravity along -z)
    accel_noise_density: float = 0.01  # m/s^2/sqrt(Hz): white accelerometer noise (incl. hand tremor)
    gyro_noise_density: float = 3.0e-4  # rad/s/sqrt(Hz): white gyroscope noise
    accel_bias_rw: float = 1.0e-3  # m/s^3/sqrt(Hz): accelerometer bias random walk
    gyro_bias_rw: float = 2.0e-4  # rad/s^2/sqrt(Hz): gyroscope bias random walk
    integration_sigma: float = 0.01  # m/sqrt(s): position random walk of the integration (lever arm, timing,
    #   tremor); below ~1e-2 the position increments are so stiff against 3-5 m priors and ranges that
    #   Cholesky reports an indeterminant system
    accel_bias_prior: float = 0.1  # m/s^2: std of the first keyframe's accelerometer bias (prior mean 0)
    gyro_bias_prior: float = 0.02  # rad/s: std of the first keyframe's gyroscope bias (prior mean 0)


@dataclass
class RangeConfig:
    """RSSI -> range by path loss, the conversion and 10 m clamp of PF-PL (000 sec. IV-B, Table I), through
    :class:`blenav.filters.measurement.PathLossRange`; range factors N(||p - l|| - r; 0, sigma_n^2)."""

    a_x: float = -64.53  # dBm at d0 (000 Table I; replaced by a fit when the method is calibrated)
    gamma: float = 1.72  # path-loss exponent (000 Table I)
    d0: float = 1.78  # m, reference distance (000 Table I)
    use_anchor_tx_power: bool = False  # an anchor's tx_power_dbm, when known, as its a_X
    sigma_n: float = 5.0  # m, range noise std (000 Table I)
    max_range_m: float = 10.0  # m, ranges above are discarded (000 sec. IV-B)
    robust: RobustKernel = RobustKernel.huber  # M-estimator against NLOS ranges
    robust_k: float = 1.345  # kernel width in units of sigma_n (Huber 1.345: 95 % efficiency)
    gate_m: Optional[float] = 4.0  # m: a range is used only when the beacon's prior position is within this (plus
    #   gate_sigmas x the beacon prior's horizontal std: 5 m for the default 0.5 m std) of
    #   the keyframe's initial (front-end) position; None: no gate. The 10 m clamp keeps far beacons' readings
    #   only when they came out short (-5 m on average beyond 6 m in the simulated office), which pulls beacons
    #   towards the path; gating on the *predicted* distance, not the measured one, does not select on the noise
    gate_sigmas: float = 2.0  # the gate widens by this many of each beacon's prior std (a badly known beacon's
    #   ranges are not all gated out: a 3 m std map gets a 10 m gate)
    combine: Combine = Combine.median  # all | median: one range per beacon and keyframe (the median)
    max_beacons_per_keyframe: Optional[int] = None  # keep the N beacons with the shortest ranges per keyframe
    #   (the nearest: least affected by the 10 m clamp's truncation); None: all
    min_ranges: int = 2  # a beacon with fewer usable ranges in a session: its range factors are dropped
    device_z: float = 1.2  # m, height of the receiver above the floor (initial z; prior mean of the height)
    estimate_offset: bool = False  # the receiver's RSSI offset delta (dB) as a variable O(0): range factors
    #   ||p - l|| 10^(-delta / (10 gamma)) - r (a receiver reading delta dB high sees every range shortened)
    offset_sigma_db: float = 10.0  # dB, prior std of delta (prior mean 0, or the previous window's estimate)
    estimate_exponent: bool = False  # with estimate_offset: the channel's path-loss exponent as a variable E(0), the
    #   ratio b to the ranges' gamma (range r_hat = d0 (d / d0)^b 10^(-delta / (10 gamma)))
    exponent_sigma: float = 0.3  # prior std of b (prior mean 1: the ranges' own exponent)
    channel_group: int = 30  # keyframes per factor of the channel's ranges (LM; iSAM2: one per keyframe): 10 / 30 /
    #   100: batch 19.3 / 9.4 / 11.8 s on the 384 s session of benchmarks/backend_speed.py (each Python call copies
    #   all the values; 100: dense cliques)
    refit_channel: ChannelRefit = ChannelRefit.none  # LM passes after the first: every range through the channel
    #   refitted on the previous pass's distances (blenav.backend.channel, a line in log range: none | level | line)


@dataclass
class PriorConfig:
    """Priors that keep every variable determined."""

    beacon_sigma_m: float = 0.5  # m per axis: a beacon's prior when anchors.csv gives no std_m
    beacon_sigma_z_m: float = 0.5  # m: vertical prior std of a beacon (mounting height)
    start_position_sigma_m: float = 3.0  # m per axis: X(0) position around the front-end's first estimate
    start_velocity_sigma_mps: float = 1.0  # m/s per axis: V(0) around the front-end's velocity
    attitude_sigma_deg: float = 15.0  # deg, isotropic: the AHRS attitude error (heading prior)
    attitude_corr_s: float = 2.0  # s: correlation time of the AHRS error; per keyframe the prior's sigma is
    #   attitude_sigma_deg * sqrt(attitude_corr_s / keyframe interval), i.e. one independent prior per corr_s
    height_sigma_m: Optional[float] = 0.3  # m: every keyframe's world z around range.device_z (None: off)
    front_end_sigma_m: Optional[float] = None  # m: every keyframe's x, y around the front-end's (smoothed)
    #   estimate; None (000): the front-end only initialises the graph. The front-end saw the same ranges, so
    #   this counts them twice: a regulariser for sparse radio data, not a measurement
    front_end_corr_s: float = 5.0  # s: correlation time of the front-end's error (sigma inflated as the attitude's)
    front_end_cloud: bool = True  # x, y prior per keyframe with the front-end's own covariance (its particle cloud,
    #   and the spread of its runs), inflated by sqrt(front_end_corr_s / interval) and front_end_cloud_scale: the
    #   smoother keeps what the filter knew where its ranges add nothing better (issue 32)
    front_end_cloud_scale: float = 0.25  # the cloud's covariance times this (its std times the square root): 0.25
    #   keeps B-end under 0.95x its better filter on five simulated buildings (make backend-robust) and no worse than
    #   F-end on the real ILC F1 walks it was chosen on and on F2 (docs/results-000-002.md); 4 gained more on the
    #   simulations and drifted where the filter is lost on real walks
    front_end_min_sigma_m: float = 0.5  # m: the cloud's std floored here (a collapsed cloud is not certainty)


@dataclass
class InitConfig:
    """Initial values from the front-end (000 Fig. 2: its position and velocity estimates)."""

    from_runs: InitFrom = InitFrom.mean  # R runs of an Estimate: their mean, or run 0
    position_window_s: float = 1.0  # s: positions are a centred moving average over this span (a particle
    #   filter's estimate jumps by decimetres between steps, which the IMU factors would first have to undo)
    velocity_window_s: float = 1.0  # s: velocities are central differences of positions over this span
    max_speed_mps: float = 3.0  # m/s: faster initial velocities (a jumping filter) are scaled down to it


@dataclass
class SolverConfig:
    method: Solver = Solver.isam2
    keyframe_every: int = 1  # a keyframe every N front-end steps (1: the front-end's rate)
    update_every: int = 1  # iSAM2: one update per N keyframes (each update re-eliminates the beacons at the
    #   root of the Bayes tree, ~20 ms with 40-80 beacons: N > 1 trades latency for throughput)
    factorization: Factorization = Factorization.cholesky  # iSAM2 and LM elimination, beacon marginals (QR: 10x slower)
    # iSAM2 relinearizes a variable when its delta exceeds these (per component). Positions and velocities enter
    # the preintegrated IMU residual linearly (given the rotations) and the 5 m range factors are nearly linear
    # over a metre, so their thresholds are large; a beacon is in the factors of every keyframe that heard it,
    # and relinearizing it re-eliminates most of the tree.
    relinearize_rotation_rad: float = 0.05  # rad
    relinearize_position_m: float = 0.5  # m
    relinearize_velocity_mps: float = 0.3  # m/s
    relinearize_accel_bias: float = 0.02  # m/s^2
    relinearize_gyro_bias: float = 0.002  # rad/s
    relinearize_beacon_m: float = 0.5  # m
    relinearize_offset_db: float = 0.5  # dB: the receiver offset (range.estimate_offset); it touches every range factor
    relinearize_exponent: float = 0.02  # the exponent ratio (range.estimate_exponent)
    relinearize_skip: int = 1  # iSAM2: check relinearization every N updates (GTSAM's default: 10)
    passes: int = 2  # LM only (iSAM2 is online: one pass): passes in all; each after the first starts from the
    #   previous solution, whose trajectory and beacons re-gate the ranges
    lm_max_iterations: int = 100  # Levenberg-Marquardt
    lm_relative_tol: float = 1.0e-3  # LM: stop when the error decreases by less than this fraction (1e-5:
    #   3x the iterations for 1 % of the error on a 384 s session)
    beacon_covariance: bool = True  # marginal covariance of every beacon (its std_m)


@dataclass
class MappingConfig:
    """Beacon maps from labelled walks (issue 14 sec. 3, :mod:`blenav.backend.mapping`).

    Per reading, RSSI-domain path loss (log-normal shadowing, the model PF-PS uses):
    rssi = A_j - 10 gamma log10(||p - l_j|| / 1 m) + eps, eps ~ N(0, sigma_db^2), with the beacon's
    position l_j and its RSSI at 1 m A_j both unknown, the pose p known (ground truth)."""

    gamma: float = 2.0  # path-loss exponent (initial value when estimate_gamma)
    estimate_gamma: bool = True  # one exponent shared by all beacons, estimated with them
    sigma_db: float = 6.0  # dB: RSSI residual std (shadowing + receiver noise)
    robust: RobustKernel = RobustKernel.huber
    robust_k: float = 1.345  # in units of sigma_db
    min_rssi_dbm: Optional[float] = None  # readings weaker than this are left out (None: all; a fixed threshold
    #   ignores the receiver's own level and selects on the noise: worse on the simulated office)
    censor_margin_db: Optional[float] = None  # dB: leave out readings within this of the session's weakest
    #   (0.5th percentile) reading: near its sensitivity a receiver reports only what came out strong
    a_x_prior_dbm: float = -60.0  # dBm: prior mean of A_j (broad)
    a_x_prior_sigma_db: float = 20.0  # dB (of the common level, or of each beacon when a_x_spread_db is None)
    a_x_spread_db: Optional[float] = 3.0  # dB: beacons' 1 m levels around their common level (None: independent)
    prior_sigma_m: float = 30.0  # m per axis: broad horizontal prior around the initial guess
    use_map_prior: bool = False  # centre the broad prior on anchors.csv's x, y (else on the initial guess)
    height_sigma_m: float = 0.3  # m: vertical prior around anchors.csv's z (walks on one floor hardly see the height)
    default_z_m: float = 2.5  # m: the height prior of a beacon whose anchors.csv z is empty (ceiling mount)
    min_readings: int = 30  # readings below which a beacon is not placed (heard too little)
    min_spread_m: float = 1.0  # m: minor-axis std of the hearing positions below which it is not placed
    max_std_m: float = 2.5  # m: placed only when the estimate's (stated) horizontal std is below this
    device_z: Optional[float] = None  # m: receiver height (None: the ground truth's z, 0 when it has none)
    body_loss: bool = True  # the carrier's body shadow W (1 - cos theta) / 2, W estimated (shared by all beacons)
    body_db_prior: float = 5.0  # dB, prior mean of W
    body_db_sigma: float = 5.0  # dB
    walls: bool = True  # multi-wall term: M per wall of the floor plan crossed by the line of sight, M estimated
    wall_db_prior: float = 3.0  # dB per wall, prior mean of M
    wall_db_sigma: float = 3.0  # dB
    max_walls: int = 5  # walls counted at most
    wall_passes: int = 3  # solves, each with the wall counts at the previous estimate (stops when < 1 % change)
    max_iterations: int = 100  # LM
    relative_tol: float = 1.0e-4  # LM: stop when the error decreases by less than this fraction
    shadow_corr_m: float = 3.0  # m: cell size over which shadowing is taken as shared (stds: design effect)
    std_scale: float = 2.5  # the stated std is this times the model's (measured on simulated walks, see mapping.py)


@dataclass
class LoopConfig:
    """The closed loop of 000 (Fig. 2, Remark 2): every ``period_s`` the back-end smooths the keyframes of the
    last ``window_s`` (the map and bias of the previous window as priors), and its beacon map replaces the
    filter's, its bias corrects the IMU samples the AHRS and the IMU proposal read from then on."""

    enabled: bool = True  # false: open loop (the front-end never hears from the back-end)
    period_s: float = 30.0  # s between feedbacks
    window_s: Optional[float] = 30.0  # s of keyframes per solve (None: everything so far, cost grows with time)
    feed_map: bool = True  # optimized beacons (status 'optimized') replace the filter's map
    feed_bias: bool = True  # accelerometer and gyroscope biases subtracted from the IMU after each feedback
    beacon_sigma_floor_m: float = 0.3  # m, smallest per-axis std a carried-over beacon prior gets
    min_beacon_std_gain: float = 0.0  # m: move a beacon only when its std beats its prior's by this much


@dataclass
class OdometryConfig:
    """Between-factors from a learned inertial odometry (issue 31), where the back-end is given one (``io_model=``):
    the track's displacement between consecutive keyframes, x, y in the world frame, its variance the track's own
    times ``var_scale`` (a network's stated variance is overconfident on a walk unlike its training walks: 30 was
    chosen on two simulated offices, docs/results-000-002.md), z held by ``z_sigma_m``."""

    enabled: bool = True  # false: the odometry is not used even when given
    var_scale: float = 30.0  # the track's variance times this
    z_sigma_m: float = 0.05  # m per sqrt(s), vertical displacement std (a walk on one floor)
    min_sigma_m: float = 0.01  # m, floor of the x, y std of one keyframe interval


@dataclass
class BackendConfig:
    """The radio-inertial smoother of 000 (sec. IV-D, Problem 3) and its mapping mode."""

    imu: ImuConfig = field(default_factory=ImuConfig)
    range: RangeConfig = field(default_factory=RangeConfig)
    priors: PriorConfig = field(default_factory=PriorConfig)
    init: InitConfig = field(default_factory=InitConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)


def load_backend_config(path: str | Path | None = None, overrides: list[str] | None = None,
                        node=None) -> BackendConfig:
    """:class:`BackendConfig` from ``conf/backend/default.yaml`` (or ``path``), then ``node`` (a dict or
    DictConfig of overrides), then dotlist ``overrides`` (``["solver.method=lm"]``). A key the schema lacks
    raises ``ValueError`` naming it."""
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    if path is None:
        from blenav.paths import conf_dir

        path = conf_dir() / "backend" / "default.yaml"
    try:
        doc = OmegaConf.load(path)
        doc.pop("defaults", None)
        merged = OmegaConf.merge(OmegaConf.structured(BackendConfig), doc, node or {},
                                 OmegaConf.from_dotlist(list(overrides or [])))
        cfg = OmegaConf.to_object(merged)
    except OmegaConfBaseException as exc:
        raise ValueError(f"backend config {path}: {' '.join(str(exc).split())}") from exc
    check_combinations(cfg)
    return cfg


def check_combinations(cfg: BackendConfig) -> None:
    """ValueError for settings that load but cannot work together (each named)."""
    rc = cfg.range
    if ChannelRefit(rc.refit_channel) != ChannelRefit.none:
        if Solver(cfg.solver.method) != Solver.lm or int(cfg.solver.passes) < 2:
            raise ValueError(f"backend: range.refit_channel={rc.refit_channel} refits between LM passes: it needs "
                             f"solver.method=lm and solver.passes >= 2 (got {cfg.solver.method}, {cfg.solver.passes})")
        if rc.estimate_offset:
            raise ValueError("backend: range.refit_channel and range.estimate_offset both estimate the receiver's "
                             "offset; choose one")
    if rc.estimate_exponent and not rc.estimate_offset:
        raise ValueError("backend: range.estimate_exponent needs range.estimate_offset=true (a channel of unknown "
                         "exponent has an unknown level too: the two are estimated together)")
    if int(rc.channel_group) < 1:
        raise ValueError(f"backend: range.channel_group must be >= 1 (got {rc.channel_group})")
    if not rc.exponent_sigma > 0:
        raise ValueError(f"backend: range.exponent_sigma must be > 0 (got {rc.exponent_sigma})")
    mapping_kernel(cfg.mapping.robust, "backend: mapping.robust")
    oc = cfg.odometry
    if not (oc.var_scale > 0 and oc.z_sigma_m > 0 and oc.min_sigma_m > 0):
        raise ValueError(f"backend: odometry.var_scale, z_sigma_m and min_sigma_m must be > 0 (got {oc.var_scale}, "
                         f"{oc.z_sigma_m}, {oc.min_sigma_m})")
