"""Carrier motion: pedestrians walking the navigation graph, a wheeled robot, static surveys.

Output is a :class:`Trajectory` sampled at the IMU rate: positions (T, 3) in world metres (z = device
height incl. gait bounce), the body heading (rad CCW from +x) and the device-to-world orientation.

Pedestrian: visits random rooms along shortest navigation-graph routes, wanders to a random point in
each room and pauses there U(pause) s; nominal speed N(speed, speed_std) per session with slow AR(1)
variation, slowing in turns and at doors; corners are rounded by averaging the path over ``smooth_m``
of arc length; the gait adds vertical bounce (step frequency f = v / step_length) and lateral sway at f/2.
The phone is held in front, screen up, top pointing forward, pitched up by ``tilt_deg`` with small
oscillations at the step frequency and a slow yaw wobble.

Robot: the same routes at a slower, smoother speed with the phone mounted flat and no gait.
Static: a fingerprint survey, the device still at a sequence of points in free space for ``dwell_s``
each (three facing directions, as the thesis' rig), moved between them instantly; the session clock
runs continuously.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter1d, uniform_filter1d
from scipy.spatial.transform import Rotation

from .layout import Layout


@dataclass
class MotionConfig:
    imu_rate_hz: float = 200.0
    speed: float = 1.3
    speed_std: float = 0.12
    speed_ar_std: float = 0.08
    turn_slowdown: float = 0.8  # m of curvature radius scale for slowing in turns
    pause_min_s: float = 2.0
    pause_max_s: float = 15.0
    smooth_m: float = 1.0
    step_length: float = 0.7
    bounce_acc: float = 2.0  # m/s^2 vertical gait acceleration amplitude
    sway_acc: float = 0.6  # m/s^2 lateral
    device_height: float = 1.2
    tilt_deg: float = 30.0
    yaw_wobble_deg: float = 5.0
    turn_time_s: float = 0.35  # std of the Gaussian low-pass on heading (how quickly a walker turns)
    smooth_time_s: float = 0.15  # std of the Gaussian low-pass on the time parametrisation
    robot_speed: float = 0.5
    robot_height: float = 0.4
    dwell_s: float = 10.0
    survey_spacing_m: float = 2.0


@dataclass
class Trajectory:
    t: np.ndarray  # (T,) s
    xyz: np.ndarray  # (T, 3) m, world
    heading: np.ndarray  # (T,) rad, body facing direction
    rot: Rotation  # (T,) device -> world
    moving: np.ndarray  # (T,) bool
    breaks: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # first samples of new segments

    def segments(self) -> list[slice]:
        """Continuous pieces of the trajectory (a survey jumps between points off the clock)."""
        edges = [0, *self.breaks.tolist(), len(self.t)]
        return [slice(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]

    @property
    def duration(self) -> float:
        return float(self.t[-1])


def _route_points(layout: Layout, rng: np.random.Generator, duration_s: float, speed: float,
                  pause_range: tuple[float, float]):
    """Waypoint polyline through random rooms, and per-waypoint pause durations."""
    _, pred = layout.all_pairs()
    rooms = list(layout.room_node)
    cur = rooms[rng.integers(len(rooms))]
    pts = [layout.nodes[layout.room_node[cur]]]
    pauses = [0.0]
    travelled = 0.0
    while travelled / speed < duration_s * 1.3:
        nxt = rooms[rng.integers(len(rooms))]
        if nxt == cur:
            continue
        path = layout.route(layout.room_node[cur], layout.room_node[nxt], pred)
        for n in path[1:]:
            pts.append(layout.nodes[n])
            pauses.append(0.0)
        # wander to a free point of the room, pause, return to the centre
        r = next(r for r in layout.rooms if r.id == nxt)
        x0, y0, x1, y1 = r.rect
        for _ in range(20):
            p = np.array([rng.uniform(x0 + 0.6, x1 - 0.6), rng.uniform(y0 + 0.6, y1 - 0.6)])
            seg = np.linspace(pts[-1], p, 50)
            if layout.free(seg).all():
                pts += [p, layout.nodes[layout.room_node[nxt]]]
                pauses += [rng.uniform(*pause_range), 0.0]
                break
        travelled += sum(np.linalg.norm(np.diff(np.array(pts[-len(path) - 2:]), axis=0), axis=1))
        cur = nxt
    return np.array(pts), np.array(pauses)


def _resample(pts: np.ndarray, ds: float):
    """Arc-length resampling of a polyline; returns points (N, 2), arc length (N,), index of each vertex."""
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-6])
    pts = pts[keep]
    s_v = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    s = np.arange(0.0, s_v[-1], ds)
    xy = np.stack([np.interp(s, s_v, pts[:, 0]), np.interp(s, s_v, pts[:, 1])], axis=1)
    return xy, s, np.searchsorted(s, s_v), keep


def walk(layout: Layout, rng: np.random.Generator, cfg: MotionConfig, duration_s: float, kind: str) -> Trajectory:
    """Pedestrian (``kind='pedestrian'``) or robot (``'robot'``) trajectory of ``duration_s`` seconds."""
    robot = kind == "robot"
    v0 = cfg.robot_speed if robot else max(0.6, rng.normal(cfg.speed, cfg.speed_std))
    pts, pauses = _route_points(layout, rng, duration_s, v0, (cfg.pause_min_s, cfg.pause_max_s))
    ds = 0.05
    xy, s, vidx, keep = _resample(pts, ds)
    pauses = pauses[keep]
    win = int((cfg.smooth_m * (1.5 if robot else 1.0)) / ds) | 1
    xy = uniform_filter1d(uniform_filter1d(xy, win, axis=0, mode="nearest"), win, axis=0, mode="nearest")
    d = np.gradient(xy, ds, axis=0)
    head_s = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    curv = np.abs(np.gradient(head_s, ds))
    # speed along the path: per-session nominal, AR(1) wobble over ~10 m, slower in turns
    n = len(s)
    e = rng.standard_normal(n) * cfg.speed_ar_std * (0.3 if robot else 1.0)
    a = np.exp(-ds / 10.0)
    ar = _ar1(e * np.sqrt(1 - a * a), a)
    v = np.clip((v0 + ar) / (1.0 + cfg.turn_slowdown * curv), 0.15, 2.5)
    dt_s = ds / v
    # pauses at waypoints: add their duration to the time of the vertex sample
    extra = np.zeros(n)
    idx = np.clip(vidx, 0, n - 1)
    np.add.at(extra, idx, pauses[: len(idx)])
    t_s = np.concatenate([[0.0], np.cumsum(dt_s[:-1] + extra[:-1])])
    # time grid at IMU rate; position = interp of arc samples; pauses = held positions
    dt = 1.0 / cfg.imu_rate_hz
    t = np.arange(0.0, min(duration_s, t_s[-1]), dt)
    if t[-1] < duration_s - dt:  # route too short: extend by pausing at the end (documented: rare)
        t = np.arange(0.0, duration_s, dt)
    # build (time, arc) knots: each sample is at t_s; a pause makes the next knot later
    knots_t = np.concatenate([t_s, t_s[idx] + pauses[: len(idx)]])
    knots_s = np.concatenate([np.arange(n), idx.astype(float)])
    order = np.argsort(knots_t, kind="stable")
    kt, ks = knots_t[order], knots_s[order]
    si = np.interp(t, kt, ks)
    # low-pass the time parametrisation: piecewise-linear interpolation has velocity kinks at every knot
    sig = cfg.smooth_time_s * cfg.imu_rate_hz
    x = gaussian_filter1d(np.interp(si, np.arange(n), xy[:, 0]), sig, mode="nearest")
    y = gaussian_filter1d(np.interp(si, np.arange(n), xy[:, 1]), sig, mode="nearest")
    heading = gaussian_filter1d(np.interp(si, np.arange(n), head_s), cfg.turn_time_s * cfg.imu_rate_hz, mode="nearest")
    speed = np.hypot(np.gradient(x, dt), np.gradient(y, dt))
    moving = speed > 0.05
    if robot:
        z = np.full_like(t, cfg.robot_height)
        rot = Rotation.from_euler("z", (heading - np.pi / 2)[:, None])
        return Trajectory(t, np.stack([x, y, z], 1), heading, rot, moving)

    # gait: phase integrates the step frequency of the (smoothed) speed; amplitudes fade in and out
    # with the speed so that the acceleration stays A sin(phase) without blow-ups at starts and stops
    v_s = gaussian_filter1d(speed, 0.5 * cfg.imu_rate_hz, mode="nearest")
    f_step = v_s / cfg.step_length
    phase = 2 * np.pi * np.cumsum(f_step) * dt
    env = np.clip(v_s / v0, 0.0, 1.0)
    w = 2 * np.pi * v0 / cfg.step_length
    bounce = -(cfg.bounce_acc / w**2) * env * np.sin(phase)
    sway = -(cfg.sway_acc / (w / 2) ** 2) * env * np.sin(phase / 2)
    x = x - np.sin(heading) * sway
    y = y + np.cos(heading) * sway
    z = cfg.device_height + bounce
    wob = gaussian_filter1d(rng.standard_normal(len(t)), cfg.imu_rate_hz, mode="nearest")
    yaw = heading - np.pi / 2 + np.radians(cfg.yaw_wobble_deg) * wob / max(wob.std(), 1e-9)
    pitch = np.radians(cfg.tilt_deg) + np.radians(3) * env * np.sin(phase)
    roll = np.radians(2) * env * np.sin(phase / 2)
    rot = Rotation.from_euler("ZXY", np.stack([yaw, pitch, roll], 1))
    return Trajectory(t, np.stack([x, y, z], 1), heading, rot, moving)


def _ar1(e: np.ndarray, a: float) -> np.ndarray:
    """x[k] = a x[k-1] + e[k], via scipy's linear filter (no Python loop)."""
    from scipy.signal import lfilter

    return lfilter([1.0], [1.0, -a], e)


def survey(layout: Layout, rng: np.random.Generator, cfg: MotionConfig, duration_s: float) -> Trajectory:
    """Static fingerprint survey: still device at grid points of free space, dwell_s each."""
    g = cfg.survey_spacing_m
    xs, ys = np.meshgrid(np.arange(g / 2, layout.width_m, g), np.arange(g / 2, layout.height_m, g))
    cand = np.stack([xs.ravel(), ys.ravel()], 1)
    ok = layout.free(cand)
    for dx, dy in ((0.3, 0), (-0.3, 0), (0, 0.3), (0, -0.3)):  # keep clear of walls
        ok &= layout.free(cand + [dx, dy])
    cand = cand[ok]
    n_pts = max(1, int(np.ceil(duration_s / cfg.dwell_s)))
    pts = cand[rng.permutation(len(cand))[: n_pts]] if len(cand) >= n_pts else cand[rng.integers(len(cand), size=n_pts)]
    dt = 1.0 / cfg.imu_rate_hz
    t = np.arange(0.0, duration_s, dt)
    k = np.minimum((t // cfg.dwell_s).astype(int), len(pts) - 1)
    facing = rng.uniform(-np.pi, np.pi, len(pts))[k] + (np.arange(len(pts)) % 3 * 2 * np.pi / 3)[k]
    xyz = np.column_stack([pts[k], np.full(len(t), cfg.device_height)])
    rot = Rotation.from_euler("z", (facing - np.pi / 2)[:, None])
    return Trajectory(t, xyz, facing, rot, np.zeros(len(t), bool), np.flatnonzero(np.diff(k)) + 1)
