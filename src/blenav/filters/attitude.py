"""Device attitude (AHRS) from IMU and magnetometer: the orientation front-end of Ghaffari Jadidi et al.,
section IV.B (median filter on the IMU and magnetometer signals, then an AHRS at IMU rate; the back-end
later feeds a time-varying IMU bias estimate back into the AHRS).

Pipeline, per IMU sample k (identical in :func:`estimate_attitude` and :class:`StreamingAttitude`):

1. Bias removal: ``gyr - gyro_bias`` (rad/s) and ``acc - acc_bias`` (m/s^2); biases are (3,) or, in
   batch, (T, 3) per sample; ``mag - mag_offset`` (uT, hard-iron offset, see :func:`estimate_hard_iron`).
2. Causal running median per axis over the last ``median_window`` samples of each stream (IMU at IMU
   rate, magnetometer at its own rate). Before ``median_window`` samples exist the window is padded
   with copies of the stream's first sample, so output k depends on samples <= k only.
3. Zero-order hold of the magnetometer: IMU sample k uses the latest (median-filtered) magnetometer
   sample with ``mag_t <= t[k]``; none yet: an IMU-only (gyro + accelerometer) update.
4. One per-sample update (``updateIMU``/``updateMARG``, EKF ``update``) of the selected ``ahrs``
   (0.4.0) filter with ``dt = t[k] - t[k-1]``; optionally a reset (``AttitudeConfig.reset_deg``). Madgwick
   runs compiled by default (:mod:`blenav.filters.ahrs_jit`, ``AttitudeConfig.backend``: the ahrs
   package's quaternions to ~1e-15, ~250x faster).
   ahrs' own batch mode (data given to the constructor, result in the (N, 4) attribute ``Q``) is not
   used: it assumes a fixed rate and same-length magnetometer samples.

Shapes and units: ``t`` (T,) s non-decreasing; ``acc`` (T, 3) m/s^2 including gravity (Android sign:
a phone flat on a table reads +9.81 on z); ``gyr`` (T, 3) rad/s; ``mag_t`` (M,) s; ``mag`` (M, 3) uT
(any unit: only directions are used). All in the Android device frame (x right, y up, z out of the
screen). Output quaternions (T, 4), w first, rotate device-frame vectors into the project's world frame
(ENU: x east, y north, z up), v_world = R(q) v_device, the same convention as ``groundtruth.csv``.

Frames inside ``ahrs`` 0.4.0 (read from its source) and the explicit conversion to ENU. All three
filters use Hamilton quaternions [w, x, y, z], q_dot = 0.5 q (x) [0, omega], i.e. q rotates
sensor-frame vectors into the filter's earth frame; they differ in the earth frame:

- ``Madgwick``: objective R^T e_z - a_hat (so the normalised Android accelerometer, which points *up*
  for a still device, defines +z = up) and magnetic reference [b_x, 0, b_z] (magnetic north on +x).
  Earth frame = North-West-Up (magnetic). Converted with q_ENU = q_z(+90 deg) (x) q_NWU, since a
  vector (n, w, u) in NWU is (-w, n, u) in ENU.
- ``Mahony``: expected gravity R^T [0, 0, 1] against the accelerometer (+z = up) and magnetic reference
  [0, |h_xy|, h_z] (magnetic north on +y). Earth frame = East-North-Up (magnetic): no axis change.
- ``EKF``: measurement model h(q) = [C^T g_ref, C^T m_ref] compared with the normalised accelerometer
  and magnetometer. Its ``frame`` option only chooses g_ref ([0, 0, 1] for 'NED', [0, 0, -1] for 'ENU',
  i.e. the direction of *gravity*) and the default m_ref. We use ``frame='ENU'``, feed the *negated*
  accelerometer (Android measures specific force, -gravity at rest) and pass an explicit ENU magnetic
  reference m_ref = [0, cos(dip), -sin(dip)] (dip from ``AttitudeConfig.mag_dip_deg`` or, if None,
  measured from the first accelerometer and magnetometer samples). Earth frame = ENU (magnetic).
  (The EKF decides between 3 and 6 measurements from whether its ``mag`` attribute is None; it is
  set to None for the IMU-only updates before the first magnetometer sample.)

Finally magnetic ENU -> world ENU: q_world = q_z(-declination) (x) q_magENU, with ``declination_deg``
the angle from the world's +y (north) to magnetic north, positive towards east (0 for the simulator,
whose Earth field is (0, 22, -42) uT in the world frame).

Initial orientation: from the first (bias-removed, median-filtered) accelerometer and magnetometer
samples with ``ahrs.common.orientation.ecompass(acc, mag, frame='ENU')`` (+z along the accelerometer,
+x along mag x up = east, +y = north), or, without magnetometer, ``ahrs.common.orientation.acc2q`` (yaw 0). When the
magnetometer stream starts after the first IMU sample, the heading is aligned once (rotation about
world z) when its first sample becomes available.

Helpers: :func:`gravity_compensated_acc` (eq. 6 of the paper: a~ = R a + g, g = [0, 0, -9.80665]),
:func:`yaw_of_device_forward` (heading of the device's +y axis, rad CCW from +x),
:func:`misalignment_deg` (the paper's orientation error ||log(R_gt^T R_est)|| in degrees) and
:func:`estimate_hard_iron` (magnetometer offset by a sphere fit, an offline calibration step: the
simulator, like a raw Android magnetometer, adds a per-device hard-iron offset of ~15 uT per axis,
which otherwise biases the heading by tens of degrees).

Accuracy on the simulator's ``small`` preset, 60 s, 200 Hz, seed 0 (tests/filters/test_attitude.py), median
misalignment after 5 s: with a calibrated magnetometer in a clean field 0.5-1.7 deg (Madgwick, Mahony)
and 2.3-4.9 deg (EKF, which has no gyro-bias state); with the default indoor disturbances and a
fitted hard-iron offset 15-17 deg on a pedestrian session, where the compass alone is 15 deg off.

The quaternion algebra is :mod:`blenav.filters.quaternions`'s, the running median of step 2
:mod:`blenav.filters.median`'s.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from .median import CausalMedian, causal_median
from .quaternions import matrix_to_quat, qconj, qmul, qmul1, quat_to_matrix, qz

GRAVITY = 9.80665


class AttitudeFilter(StrEnum):
    """``attitude.filter``: the ahrs filter (see the module docstring for their frames)."""

    madgwick = "madgwick"
    mahony = "mahony"
    ekf = "ekf"


FILTERS = tuple(f.value for f in AttitudeFilter)
BACKENDS = ("numba", "ahrs")  # ``AttitudeConfig.backend``: compiled Madgwick, or the ahrs package per sample

# earth frame of each ahrs filter -> magnetic ENU (w-first quaternions, left-multiplied)
_S2 = np.sqrt(0.5)
_FRAME_TO_ENU = {
    "madgwick": np.array([_S2, 0.0, 0.0, _S2]),  # NWU -> ENU: +90 deg about z
    "mahony": np.array([1.0, 0.0, 0.0, 0.0]),
    "ekf": np.array([1.0, 0.0, 0.0, 0.0]),
}


def _check_filter(name: str) -> None:
    if name not in FILTERS:
        raise ValueError(f"unknown attitude filter {name!r}; choose one of {list(FILTERS)}")


@dataclass
class AttitudeConfig:
    """AHRS settings (defaults are those of ahrs 0.4.0 where it has one).

    - filter: one of ``FILTERS``; median_window: samples of the causal running median (1 = off).
    - use_mag: fuse the magnetometer; without it yaw starts at 0 (acc2q) and drifts with the gyro.
    - gain: Madgwick's beta, rad/s (None: 0.041 with magnetometer, 0.033 without).
    - k_P, k_I: Mahony's gains (Mahony also estimates a gyro bias, on top of the one given).
    - ekf_noises: EKF variances (gyroscope, accelerometer, magnetometer); the latter two of the
      normalised vectors. mag_dip_deg: dip below the horizon of the EKF's magnetic reference (None:
      measured from the first accelerometer and magnetometer samples).
    - declination_deg: magnetic north east of the world's +y axis.
    - hard_iron: fit a hard-iron offset on the session's magnetometer (:func:`estimate_hard_iron`) and remove it
      before the AHRS (the offline evaluation path, :func:`blenav.filters.runner.hard_iron_offset`). True for a
      raw magnetometer (the simulator's, Android's ``*_UNCALIBRATED``); false for one the device already
      calibrates (Android ``TYPE_MAGNETIC_FIELD``, e.g. the ILC 2.0 walks): there the residual offset is ~0 and
      a sphere fit on a walk (phone held level, turning about one axis, indoor disturbances) is ill-determined
      (median |offset| 26 uT, half the field itself, on the 106 ILC F1 walks) and turns the heading away from the
      phone's rotation vector by 16 deg on average (3 deg without it).
    - reset_deg, reset_s: when the compass (the magnetometer rotated into the world frame by the current
      estimate) disagrees with the estimated heading by more than ``reset_deg`` on every magnetometer
      sample for ``reset_s`` seconds, re-initialise from the current accelerometer and magnetometer
      samples as at the start (Mahony's bias estimate is restored to its value before the disagreement).
      Recovers in ``reset_s`` from a bad start or a device moved without gyro signal (the simulator's
      survey sessions jump between points), where the filters alone take tens of seconds (Madgwick
      corrects at most ``gain`` rad/s). None (default): never. Indoor magnetic anomalies can trigger it
      too, so it is off unless the data needs it.
    - extra: further keyword arguments for the ahrs filter class.
    - backend: ``numba`` (default) runs Madgwick compiled (:mod:`blenav.filters.ahrs_jit`: the ahrs package's
      numbers to ~1e-15, ~100x faster); ``ahrs`` calls the ahrs package per sample (the reference). Mahony
      and the EKF always use the ahrs package.
    """

    filter: AttitudeFilter = AttitudeFilter.madgwick
    median_window: int = 5
    use_mag: bool = True
    gain: float | None = None
    k_P: float = 1.0
    k_I: float = 0.3
    ekf_noises: tuple[float, float, float] = (0.3**2, 0.5**2, 0.8**2)
    mag_dip_deg: float | None = None
    declination_deg: float = 0.0
    hard_iron: bool = True
    reset_deg: float | None = None
    reset_s: float = 1.0
    extra: dict = field(default_factory=dict)
    backend: str = "numba"

    def __post_init__(self):
        _check_filter(self.filter)
        self.filter = AttitudeFilter(self.filter)
        if self.backend not in BACKENDS:
            raise ValueError(f"unknown attitude backend {self.backend!r}; choose one of {list(BACKENDS)}")
        if int(self.median_window) < 1:
            raise ValueError(f"median_window must be >= 1, got {self.median_window}")


# ------------------------------------------------------------------------------------------- helpers


def gravity_compensated_acc(q: np.ndarray, acc: np.ndarray, g: float = GRAVITY) -> np.ndarray:
    """World-frame (ENU) acceleration with gravity removed, (T, 3) m/s^2: a~ = R(q) a + [0, 0, -g]
    (eq. 6 of Ghaffari Jadidi et al.; a still device gives ~0). ``q`` (T, 4) or (4,), ``acc`` (T, 3)."""
    a_w = np.einsum("...ij,...j->...i", quat_to_matrix(q), np.asarray(acc, float))
    return a_w + np.array([0.0, 0.0, -g])


def yaw_of_device_forward(q: np.ndarray) -> np.ndarray:
    """Heading (rad, CCW from world +x, in (-pi, pi]) of the device's +y axis (top edge of the screen)
    projected on the horizontal plane. ``q`` (T, 4) -> (T,)."""
    R = quat_to_matrix(q)
    return np.arctan2(R[..., 1, 1], R[..., 0, 1])


def misalignment_deg(q_est: np.ndarray, q_gt: np.ndarray) -> np.ndarray:
    """Rotation angle of R_gt^T R_est in degrees (T,) (the orientation error ||log(R_gt^T R_est)|| of
    Ghaffari Jadidi et al., section VI); sign of the quaternions does not matter. Broadcasts."""
    a = np.asarray(q_est, float)
    b = np.asarray(q_gt, float)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    rel = qmul(qconj(b), a)
    return np.degrees(2.0 * np.arctan2(np.linalg.norm(rel[..., 1:], axis=-1), np.abs(rel[..., 0])))


def estimate_hard_iron(mag: np.ndarray) -> np.ndarray:
    """Hard-iron offset (3,) in the magnetometer's unit by a linear least-squares sphere fit,
    |m - c|^2 = r^2. Needs the device to have turned (a pedestrian or robot session, or several facing
    directions of a survey). When it turned about one device axis only, the offset along that axis is
    undetermined; the minimum-norm solution is returned, and that component only changes the apparent
    magnetic dip, not the heading. An offline calibration step: pass the result as ``mag_offset``."""
    m = np.asarray(mag, float)
    c0 = m.mean(axis=0)
    d = m - c0
    A = np.column_stack([2.0 * d, np.ones(len(d))])
    b = (d * d).sum(axis=1)
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    sol = np.linalg.lstsq(A / scale, b, rcond=1e-6)[0] / scale
    return c0 + sol[:3]


def _ecompass_q(acc: np.ndarray, mag: np.ndarray) -> np.ndarray:
    """Device -> magnetic ENU quaternion from one accelerometer (pointing up at rest) and magnetometer
    sample: ahrs' ``ecompass(frame='ENU')`` builds R with rows east = m x a, north = a x east, up = a."""
    from ahrs.common.orientation import ecompass

    return matrix_to_quat(ecompass(np.asarray(acc, float), np.asarray(mag, float), frame="ENU",
                                    representation="rotmat"))


def _as_bias(b, n: int | None = None) -> np.ndarray:
    if b is None:
        return np.zeros(3)
    b = np.asarray(b, float)
    if b.shape != (3,) and not (n is not None and b.shape == (n, 3)):
        raise ValueError(f"bias must have shape (3,){'' if n is None else f' or ({n}, 3)'}, got {b.shape}")
    return b


# ------------------------------------------------------------------------------------------- engine


class _Engine:
    """One ahrs filter and its state; fed with preprocessed samples one at a time."""

    def __init__(self, cfg: AttitudeConfig):
        from ahrs.filters import EKF, Madgwick, Mahony

        _check_filter(cfg.filter)
        self.cfg = cfg
        self.name = cfg.filter
        self.to_menu = _FRAME_TO_ENU[self.name]  # filter frame -> magnetic ENU
        self.to_world = qmul(qz(-np.radians(cfg.declination_deg)), self.to_menu)  # filter frame -> world
        self.jit = False  # Madgwick compiled (ahrs_jit) instead of the ahrs package's per-sample update
        if self.name == "madgwick":
            gain = cfg.gain if cfg.gain is not None else (0.041 if cfg.use_mag else 0.033)
            self.f = Madgwick(gain=gain, **cfg.extra)  # with the numba backend: its gain and Dt only
            self.jit = cfg.backend == "numba"
        elif self.name == "mahony":
            self.f = Mahony(k_P=cfg.k_P, k_I=cfg.k_I, **cfg.extra)
        else:
            self.f = None  # built at initialisation (needs the magnetic reference)
            self._ekf_cls = EKF
        self.q: np.ndarray | None = None  # in the filter's frame
        self.mag_seen = False
        self._bad_since: float | None = None  # time from which the compass disagrees by > reset_deg
        self._b_good: np.ndarray | None = None  # Mahony's gyro-bias estimate at that time

    def _make_ekf(self, dip_rad: float) -> None:
        m_ref = np.array([0.0, np.cos(dip_rad), -np.sin(dip_rad)])  # ENU, normalised
        self.f = self._ekf_cls(frame="ENU", magnetic_ref=m_ref, noises=list(self.cfg.ekf_noises), **self.cfg.extra)

    def init(self, acc: np.ndarray, mag: np.ndarray | None) -> None:
        from ahrs.common.orientation import acc2q

        if mag is not None:
            q_menu = _ecompass_q(acc, mag)
            self.mag_seen = True
        else:
            q_menu = np.asarray(acc2q(np.array(acc, float)), float)
        self.q = qmul(qconj(self.to_menu), q_menu)
        if self.name == "ekf":
            self._make_ekf(self._dip(acc, mag))
            self.f.mag = None if mag is None else np.empty((0, 3))

    def _dip(self, acc: np.ndarray, mag: np.ndarray | None) -> float:
        if self.cfg.mag_dip_deg is not None:
            return float(np.radians(self.cfg.mag_dip_deg))
        if mag is None:
            return float(np.radians(60.0))  # placeholder until the first magnetometer sample
        up = acc / np.linalg.norm(acc)
        return float(np.arcsin(np.clip(-np.dot(mag, up) / np.linalg.norm(mag), -1.0, 1.0)))

    def _compass_error(self, mag: np.ndarray) -> float:
        """Heading correction (rad) that turns the estimate onto the compass: the magnetometer rotated into
        magnetic ENU by the estimate should point to +y (north)."""
        w, x, y, z = qmul1(self.to_menu, self.q)
        hx = (1 - 2 * (y * y + z * z)) * mag[0] + 2 * (x * y - w * z) * mag[1] + 2 * (x * z + w * y) * mag[2]
        hy = 2 * (x * y + w * z) * mag[0] + (1 - 2 * (x * x + z * z)) * mag[1] + 2 * (y * z - w * x) * mag[2]
        return float(np.angle(np.exp(1j * (np.pi / 2 - np.arctan2(hy, hx)))))

    def _turn(self, angle: float) -> None:
        """Rotate the estimate by ``angle`` about the vertical (world z = filter z for every filter)."""
        self.q = np.array(qmul1(qz(angle), self.q))

    def align_heading(self, acc: np.ndarray, mag: np.ndarray) -> None:
        """First magnetometer sample after an IMU-only start: rotate about world z to the compass."""
        self._turn(self._compass_error(mag))
        self.mag_seen = True
        if self.name == "ekf" and self.cfg.mag_dip_deg is None:
            self._make_ekf(self._dip(acc, mag))

    def step(self, t: float, dt: float, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray | None,
             mag_new: bool) -> np.ndarray:
        f, q = self.f, self.q
        if self.jit:
            from .ahrs_jit import madgwick_step

            q = np.empty(4)
            madgwick_step(self.q, gyr, acc, _NO_MAG if mag is None else mag, mag is not None, float(dt),
                          float(f.gain), float(f.Dt), q)
        elif self.name == "ekf":
            f.mag = None if mag is None else np.empty((0, 3))  # selects 3 or 6 measurements in ahrs' EKF
            q = f.update(q, gyr, -acc, mag, dt=dt)  # ahrs EKF compares with the gravity direction
        elif mag is None:
            q = f.updateIMU(q, gyr, acc, dt=dt)
        else:
            q = f.updateMARG(q, gyr, acc, mag, dt=dt)
        self.q = np.asarray(q, float)
        if mag_new and self.cfg.reset_deg is not None:
            err = self._compass_error(mag)
            if abs(err) <= np.radians(self.cfg.reset_deg):
                self._bad_since = None
            elif self._bad_since is None:
                self._bad_since = t
                if self.name == "mahony":
                    self._b_good = np.array(f.b, float)
            elif t - self._bad_since >= self.cfg.reset_s:
                self.q = qmul(qconj(self.to_menu), _ecompass_q(acc, mag))  # re-initialise, tilt too
                self._bad_since = None
                if self.name == "mahony":  # its integral term absorbed the disagreement: undo that
                    f.b = self._b_good
        return self.q


_NO_MAG = np.zeros(3)


# --------------------------------------------------------------------------------------------- API


class StreamingAttitude:
    """Causal AHRS, one IMU sample at a time; the same quaternions as :func:`estimate_attitude`.

    ``update_mag(t, mag)`` queues a magnetometer sample; ``update(t, acc, gyr)`` first consumes the
    queued magnetometer samples with time <= t (so they may be queued early), then runs one filter
    update and returns the device-to-world (ENU) quaternion (4,), w first. Biases are subtracted from
    every later sample; change them with :meth:`set_bias` (the back-end's feedback) or per call.
    """

    def __init__(self, cfg: AttitudeConfig | None = None, gyro_bias=None, acc_bias=None, mag_offset=None):
        self.cfg = cfg or AttitudeConfig()
        self._engine = _Engine(self.cfg)
        self._med_acc = CausalMedian(self.cfg.median_window)
        self._med_gyr = CausalMedian(self.cfg.median_window)
        self._med_mag = CausalMedian(self.cfg.median_window)
        self._pending: deque[tuple[float, np.ndarray]] = deque()
        self._mag: np.ndarray | None = None
        self._t: float | None = None
        self.mag_offset = _as_bias(mag_offset)
        self.set_bias(gyro_bias, acc_bias)

    def set_bias(self, gyro_bias=None, acc_bias=None) -> None:
        """Gyroscope (rad/s) and accelerometer (m/s^2) biases (3,) for the following samples."""
        self.gyro_bias = _as_bias(gyro_bias)
        self.acc_bias = _as_bias(acc_bias)

    def update_mag(self, t: float, mag: np.ndarray) -> None:
        if self._pending and t < self._pending[-1][0]:
            raise ValueError(f"magnetometer time goes backwards: {t} after {self._pending[-1][0]}")
        self._pending.append((float(t), np.asarray(mag, float)))

    def update(self, t: float, acc: np.ndarray, gyr: np.ndarray, gyro_bias=None, acc_bias=None) -> np.ndarray:
        if self._t is not None and t < self._t:
            raise ValueError(f"IMU time goes backwards: {t} after {self._t}")
        gb = self.gyro_bias if gyro_bias is None else _as_bias(gyro_bias)
        ab = self.acc_bias if acc_bias is None else _as_bias(acc_bias)
        a = self._med_acc(np.asarray(acc, float) - ab)
        g = self._med_gyr(np.asarray(gyr, float) - gb)
        mag_new = False
        while self._pending and self._pending[0][0] <= t:
            _, m = self._pending.popleft()
            if self.cfg.use_mag:
                self._mag = self._med_mag(m - self.mag_offset)
                mag_new = True
        eng = self._engine
        if self._t is None:
            eng.init(a, self._mag)
        else:
            if self._mag is not None and not eng.mag_seen:
                eng.align_heading(a, self._mag)
            eng.step(float(t), t - self._t, g, a, self._mag, mag_new)
        self._t = float(t)
        return np.array(qmul1(eng.to_world, eng.q))  # the numbers of _qmul, without its array overhead


def estimate_attitude(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, mag_t: np.ndarray | None = None,
                      mag: np.ndarray | None = None, cfg: AttitudeConfig | None = None, gyro_bias=None,
                      acc_bias=None, mag_offset=None) -> np.ndarray:
    """Device-to-world (ENU) quaternions (T, 4), w first, at the IMU times ``t``; see the module doc.

    ``gyro_bias``/``acc_bias``: (3,) or (T, 3); ``mag_offset``: (3,) hard-iron offset in mag's unit.
    """
    cfg = cfg or AttitudeConfig()
    return to_world(attitude_states(t, acc, gyr, mag_t, mag, cfg, gyro_bias, acc_bias, mag_offset), cfg)


def to_world(states: np.ndarray, cfg: AttitudeConfig) -> np.ndarray:
    """:func:`attitude_states`' filter-frame quaternions (T, 4) as device-to-world ones (:func:`estimate_attitude`)."""
    return qmul(_Engine(cfg).to_world, states) if len(states) else states


def resumable(cfg: AttitudeConfig) -> bool:
    """Whether :func:`attitude_states` can resume a run (``start`` > 0): the compiled Madgwick without the compass
    reset, whose whole state is the quaternion (Mahony's bias, the EKF's covariance and the reset's timer are not
    kept)."""
    return cfg.filter == "madgwick" and cfg.backend == "numba" and cfg.reset_deg is None


def attitude_states(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, mag_t: np.ndarray | None = None,
                    mag: np.ndarray | None = None, cfg: AttitudeConfig | None = None, gyro_bias=None,
                    acc_bias=None, mag_offset=None, start: int = 0, prev: np.ndarray | None = None) -> np.ndarray:
    """The AHRS of :func:`estimate_attitude` in the filter's frame (T, 4) (:func:`to_world` turns it to the world).

    Resumed (``start`` > 0, :func:`resumable` settings only): samples before ``start`` are ``prev[:start]``, the
    states of a run on inputs equal to these up to sample ``start - 1`` (e.g. before a bias correction that starts at
    ``start``, the back-end's feedback); the filter continues from ``prev[start - 1]``. The result is the full run's
    to the bit: the causal median and the filter read nothing later than the sample they make."""
    cfg = cfg or AttitudeConfig()
    t = np.asarray(t, float)
    n = len(t)
    acc = np.asarray(acc, float).reshape(n, 3)
    gyr = np.asarray(gyr, float).reshape(n, 3)
    if n and np.any(np.diff(t) < 0):
        raise ValueError("IMU time goes backwards")
    if (mag is None) != (mag_t is None):
        raise ValueError("give both mag_t and mag, or neither")
    if start:
        if not resumable(cfg):
            raise ValueError(f"attitude_states: a {cfg.filter} run (backend {cfg.backend}, reset_deg "
                             f"{cfg.reset_deg}) cannot be resumed; run it from the start")
        if prev is None or len(prev) != n or not 0 < start <= n:
            raise ValueError(f"attitude_states: resuming at sample {start} needs the previous run's {n} states")
    lo = max(0, start - cfg.median_window + 1)  # the first sample the medians from `start` on read
    a = np.empty((n, 3))
    g = np.empty((n, 3))
    ab, gb = _as_bias(acc_bias, n), _as_bias(gyro_bias, n)
    a[lo:] = causal_median(acc[lo:] - (ab[lo:] if np.ndim(ab) == 2 else ab), cfg.median_window)
    g[lo:] = causal_median(gyr[lo:] - (gb[lo:] if np.ndim(gb) == 2 else gb), cfg.median_window)
    # zero-order hold of the median-filtered magnetometer: latest sample with mag_t <= t
    idx = np.full(n, -1)
    m = None
    if cfg.use_mag and mag is not None and mag_t is not None and len(mag_t):
        mag_t = np.asarray(mag_t, float)
        if np.any(np.diff(mag_t) < 0):
            raise ValueError("magnetometer time goes backwards")
        m = causal_median(np.asarray(mag, float).reshape(len(mag_t), 3) - _as_bias(mag_offset),
                          cfg.median_window)
        idx = np.searchsorted(mag_t, t, side="right") - 1
    eng = _Engine(cfg)
    Q = np.empty((n, 4))
    k = start
    if start:
        Q[:start] = prev[:start]
        eng.q = Q[start - 1].copy()
        eng.mag_seen = bool(idx[start - 1] >= 0)  # the first magnetometer sample aligned the heading
    while k < n:
        if eng.jit and k > 0:  # compiled: runs until a sample that needs the Python engine (or the end)
            from .ahrs_jit import madgwick_run

            k = madgwick_run(Q, k, t, g, a, _NO_MAG.reshape(1, 3) if m is None else m, idx, float(eng.f.gain),
                             float(eng.f.Dt), cfg.reset_deg is not None, eng.mag_seen)
            if k == n:
                break
            eng.q = Q[k - 1].copy()
        mk = m[idx[k]] if idx[k] >= 0 else None
        if k == 0:
            eng.init(a[0], mk)
        else:
            if mk is not None and not eng.mag_seen:
                eng.align_heading(a[k], mk)
            eng.step(t[k], t[k] - t[k - 1], g[k], a[k], mk, idx[k] != idx[k - 1])
        Q[k] = eng.q
        k += 1
    return Q
