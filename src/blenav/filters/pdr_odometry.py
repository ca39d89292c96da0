"""PDR odometry of a phone walk without ``odometry.csv`` (issue 17, the ILC 2.0 recordings): detected steps along
the phone's heading, world-aligned, as the odometry track Roy's odometry increment (eq. 3.7) and the learned map
prior (eq. 3.8) read; and one step length fitted on labelled walks.

:func:`pdr_odometry` is :func:`blenav.filters.motion_pdr.pdr_track` on a session: the heading from the phone's
rotation vector (``heading='orientation'``, ``orientation.csv``) or from blenav's Madgwick AHRS with magnetometer
(``'ahrs'``: the same AHRS, hard-iron offset and cache entry as the filters' PDR motion model,
:func:`blenav.filters.runner.session_imu`); magnetic-north referenced, so world-aligned on an east/north floor
frame. :func:`fit_step_length` divides the surveyed path length between each walk's first and last waypoints by
the steps detected there. Both share a walk's step flags through the caller's ``cache``.
:class:`blenav.localizers.realwalk.RealWalkPF` runs a particle filter on them.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from blenav.data.session import gyro_calibrated_of
from blenav.errors import MissingStream

from .attitude import AttitudeConfig
from .measurement import AnchorTable
from .motion_pdr import pdr_track
from .runner import session_imu
from .steps import SessionArrays, StepDetectorConfig, detect_steps
from .yaw_hold import hold_yaw, resolve_yaw

__all__ = ["HEADINGS", "HEADING_SOURCES", "DEFAULT_STEP_M", "pdr_odometry", "fit_step_length", "fitted_step_length", "attitude_at", "attitude_track",
           "resolve_heading"]

HEADINGS = ("orientation", "ahrs")
#: what a method may ask for: a heading source, or auto (the rotation vector where the walk has one, else the AHRS)
HEADING_SOURCES = HEADINGS + ("auto",)
DEFAULT_STEP_M = 0.7
_NO_ANCHORS = AnchorTable.empty()


def resolve_heading(session, heading: str) -> str:
    """``auto``: the phone's rotation vector where the walk has one (orientation.csv), else blenav's AHRS; any other
    source unchanged."""
    if heading != "auto":
        return heading
    return "orientation" if (session.root / "orientation.csv").is_file() else "ahrs"


def attitude_at(q_t: np.ndarray, q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(len(t), 4): the attitude sample of the track (``q_t`` (Q,) s increasing, ``q`` (Q, 4)) at or before each time
    ``t``, the first one before the track starts (as a phone's latest rotation vector at each IMU sample)."""
    i = np.clip(np.searchsorted(q_t, t, side="right") - 1, 0, len(q_t) - 1)
    return q[i]


def attitude_track(session, heading: str, att: AttitudeConfig | None = None, steps: StepDetectorConfig | None = None,
                   cache: dict | None = None, yaw: str = "attitude") -> tuple[np.ndarray, np.ndarray]:
    """(q_t (Q,) s, q (Q, 4) w, x, y, z): the device->world orientation of ``session`` from ``heading``:
    ``orientation`` (the phone's rotation vector, orientation.csv), ``ahrs`` (blenav's Madgwick AHRS, the PDR motion
    model's, hard-iron offset per ``att``), ``auto`` (:func:`resolve_heading`) or ``groundtruth`` (the ground truth's
    orientation: simulated walks, for training only). :class:`MissingStream` when the source is absent.

    ``yaw``: ``attitude`` (the source's own yaw), ``gyro`` (:func:`blenav.filters.yaw_hold.hold_yaw`: the gyroscope's
    yaw held to the source's running mean; the track is then at the IMU times) or ``auto`` (``gyro`` where the
    session's gyroscope is calibrated, ``session.gyro_calibrated``, else ``attitude``)."""
    yaw = resolve_yaw(yaw, gyro_calibrated_of(getattr(session, "meta", None) or {}))  # Session.gyro_calibrated's rule
    if yaw == "gyro":
        q_t, q = attitude_track(session, heading, att, steps, cache)
        imu = session.imu
        if len(imu) < 2:
            raise MissingStream(f"session {session.id} has no IMU data, which the gyroscope's yaw needs")
        imu_t = imu["t"].to_numpy(float)
        return imu_t, hold_yaw(imu_t, imu[["gx", "gy", "gz"]].to_numpy(float), attitude_at(q_t, q, imu_t))
    heading = resolve_heading(session, heading)
    att, steps = att or AttitudeConfig(), steps or StepDetectorConfig()
    if heading == "orientation":
        o = session.orientation if (session.root / "orientation.csv").is_file() else None
        if o is None or not len(o):
            raise MissingStream(f"session {session.id} has no orientation.csv (the phone's rotation vector), which "
                                f"the PDR heading 'orientation' needs")
        return o["t"].to_numpy(float), o[["qw", "qx", "qy", "qz"]].to_numpy(float)
    if heading == "groundtruth":
        gt = session.groundtruth
        if session.groundtruth_sparse or len(gt) < 2 or not {"qw", "qx", "qy", "qz"} <= set(gt.columns) \
                or not np.isfinite(gt[["qw", "qx", "qy", "qz"]].to_numpy(float)).all():
            raise MissingStream(f"session {session.id} has no ground-truth orientation track")
        return gt["t"].to_numpy(float), gt[["qw", "qx", "qy", "qz"]].to_numpy(float)
    if heading != "ahrs":
        raise ValueError(f"heading must be one of {HEADING_SOURCES + ('groundtruth',)}, got {heading!r}")
    arrays = SessionArrays.from_session(session, _NO_ANCHORS)
    q, _ = session_imu(session.id, arrays, att, steps, cache)  # the PDR motion model's AHRS (hard-iron removed)
    return arrays.imu_t, q


def _step_flags(session, steps: StepDetectorConfig | None, cache: dict | None) -> np.ndarray:
    """(T,) bool: the steps detected in the session's imu.csv (:func:`detect_steps`), once per ``cache`` (the
    PDR odometry and the step-length fit of the same walk share them)."""
    steps = steps or StepDetectorConfig()
    key = ("rw-steps", session.id, repr(steps))
    if cache is not None and key in cache:
        return cache[key]
    imu = session.imu
    flags = detect_steps(imu["t"].to_numpy(float), imu[["ax", "ay", "az"]].to_numpy(float), steps)
    if cache is not None:
        cache[key] = flags
    return flags


def pdr_odometry(session, heading: str = "orientation", step_length: float = DEFAULT_STEP_M,
                 att: AttitudeConfig | None = None, steps: StepDetectorConfig | None = None,
                 cache: dict | None = None, yaw: str = "attitude") -> pd.DataFrame:
    """The session's PDR odometry (DataFrame t, x, y: s, world-aligned m from 0), as ``odometry.csv`` holds it.
    ``yaw``: the heading source's own yaw or the gyroscope's held to it (:func:`attitude_track`).

    Raises :class:`MissingStream` without IMU data or (``heading='orientation'``) without orientation.csv."""
    if heading not in HEADING_SOURCES:
        raise ValueError(f"odometry.heading must be one of {HEADING_SOURCES}, got {heading!r}")
    heading = resolve_heading(session, heading)
    att, steps = att or AttitudeConfig(), steps or StepDetectorConfig()
    key = ("rw-pdr", session.id, heading, yaw, float(step_length), repr(att), repr(steps))
    if cache is not None and key in cache:
        return cache[key]
    imu = session.imu
    if len(imu) < 2:
        raise MissingStream(f"session {session.id} has no IMU data, which the PDR odometry needs")
    q_t, q = attitude_track(session, heading, att, steps, cache, yaw)
    t, xy = pdr_track(imu["t"].to_numpy(float), imu[["ax", "ay", "az"]].to_numpy(float), q_t, q, step_length, steps,
                      flags=_step_flags(session, steps, cache))
    df = pd.DataFrame({"t": t, "x": xy[:, 0], "y": xy[:, 1]})
    if cache is not None:
        cache[key] = df
    return df


def fit_step_length(sessions: list, steps: StepDetectorConfig | None = None, cache: dict | None = None) -> dict:
    """One step length (m) for the walker of ``sessions`` (labelled): the surveyed path length between each walk's
    first and last waypoint (straight lines between waypoints, so a lower bound of the walked length) summed over
    the walks, over the steps detected in those spans. Returns ``{"step_length_m", "walks", "steps", "path_m"}``."""
    path = n = 0.0
    used = 0
    for s in sessions:
        gt, imu = s.groundtruth, s.imu
        if len(gt) < 2 or len(imu) < 2:
            continue
        t_steps = imu["t"].to_numpy(float)[_step_flags(s, steps, cache)]
        t0, t1 = float(gt["t"].iloc[0]), float(gt["t"].iloc[-1])
        k = int(((t_steps > t0) & (t_steps <= t1)).sum())
        d = np.diff(gt[["x", "y"]].to_numpy(float), axis=0)
        path += float(np.hypot(d[:, 0], d[:, 1]).sum())
        n += k
        used += 1
    if n < 10:
        raise MissingStream(f"fewer than 10 steps detected between the waypoints of {used} train walk(s): no step "
                            f"length to fit")
    return {"step_length_m": path / n, "walks": used, "steps": int(n), "path_m": path}


def fitted_step_length(sessions: list, steps: StepDetectorConfig | None, cache: dict) -> dict:
    """:func:`fit_step_length` of ``sessions`` with the detector ``steps`` (None: the default), once per (walks,
    detector) in ``cache``: every method fitting on the same train walks shares it."""
    steps = steps or StepDetectorConfig()
    key = ("rw-step-length", tuple(s.id for s in sessions), repr(steps))
    if key not in cache:
        cache[key] = fit_step_length(sessions, steps, cache)
    return cache[key]
