"""Inputs and outputs of the learned inertial odometry (issue 31; Roy section 3.2 takes its odometry from a data-driven
inertial model, RoNIN / IDOL, refs. 24-27 of the thesis): the IMU in a gravity-aligned frame, cut into windows, and
the network's per-window velocities integrated into an odometry track.

The frame. Every IMU sample (accelerometer incl. gravity, m/s^2; gyroscope, rad/s; device frame) is rotated into the
frame of the device attitude q (device -> world, w first): ``a_w = R(q) a``, ``w_w = R(q) w``, and gravity is taken
off the vertical (``a_w[2] -= g``); the device's axes in that frame (the columns of R(q)) are channels too. The frame's z
is up; its yaw is whatever the attitude's yaw is (the phone's
rotation vector: magnetic north; blenav's AHRS: magnetic north; a simulator's ground truth: the world). The network
is trained with the frame turned by random yaws (heading-agnostic, :mod:`blenav.learn.inertial.data`), so the
velocity it returns is in the same frame as its input: world-aligned exactly as far as the attitude's yaw is.

The heading frame (``frame: heading``; the default is ``world``). Each window is turned about z by -psi_k, psi_k the heading of the
device's +y axis (mean over the window, horizontal part; its z axis where +y is near vertical), so its input does not
depend on which way the walker faces: the network is exactly yaw-equivariant, and its velocity (in the window's frame)
is turned back by +psi_k (:func:`heading_frame`, :func:`rotate_velocity`). ``frame: world`` feeds the attitude's frame
as it is (the network must learn the equivariance; training turns it by random yaws).

The grid. The rotated IMU is resampled linearly to ``rate_hz`` (the network's rate, in its metadata) on
``t_i = t_0 + i / rate_hz``. Window k (k = 0 .. K-1) ends at sample ``(k + 1) n_s`` (``n_s = stride_s * rate_hz``)
and holds the ``n_w`` samples up to it (``window_s * rate_hz``); samples before the walk's first are the first
sample repeated (a phone at rest before it moved). The network returns the mean velocity (m/s, 2-D, frame above)
over window k's last ``stride_s`` seconds, ``[t_{k n_s}, t_{(k+1) n_s}]``, and its log variance: the windows' output
intervals tile the walk, and the odometry track is their cumulative sum (:func:`integrate`).

Torch-free (numpy): training (:mod:`blenav.learn.inertial`), the evaluation and the runtime
(:mod:`blenav.runtime.inertial`) prepare windows with these functions (the rotation into the frame:
:func:`blenav.filters.inertial_odometry.world_frame_imu`), so the three cannot disagree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from blenav.limits import LimitError, check_memory, check_range

__all__ = ["GRAVITY", "CHANNELS", "YAW_PAIRS", "FRAMES", "heading_frame", "rotate_velocity", "InertialGrid", "windows", "n_windows", "padded", "cut", "turn_pairs", "integrate", "segment_weights",
           "displacement_errors"]

GRAVITY = 9.80665
#: the network's input channels, in order: world-frame acceleration without gravity (m/s^2), world-frame rate (rad/s),
#: and the device's x, y and z axes in the world frame (unit vectors: the columns of R(q)), so the network sees where the
#: phone points (a phone held in front walks along its +y axis: PDR's heading) as well as how it moves
CHANNELS = ("ax_w", "ay_w", "az_w", "gx_w", "gy_w", "gz_w", "ex_x", "ex_y", "ex_z", "ey_x", "ey_y", "ey_z",
            "ez_x", "ez_y", "ez_z")
#: the (x, y) channel pairs a yaw of the frame turns (every vector's horizontal part)
YAW_PAIRS = ((0, 1), (3, 4), (6, 7), (9, 10), (12, 13))
#: the network's input frame: ``heading`` (each window turned so the phone's mean heading is +x: heading-agnostic, the
#: network's output turned back) or ``world`` (the attitude's frame as it is)
FRAMES = ("heading", "world")
#: the device +y axis' horizontal length below which a window's heading comes from its z axis (a phone upright in a
#: pocket or at the ear points +y up)
MIN_HORIZONTAL = 0.2


@dataclass(frozen=True)
class InertialGrid:
    """The sampling contract of a network (stored in its checkpoint and ONNX metadata): ``rate_hz`` samples per
    second, windows of ``window_s`` seconds every ``stride_s`` seconds (the output interval)."""

    rate_hz: float = 50.0
    window_s: float = 2.0
    stride_s: float = 0.5

    def __post_init__(self):
        for name in ("rate_hz", "window_s", "stride_s"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"inertial grid: {name} must be a positive number, got {v!r}")
        if abs(self.n_stride - self.stride_s * self.rate_hz) > 1e-6 or abs(self.n_window - self.window_s * self.rate_hz) > 1e-6:
            raise ValueError(f"inertial grid: window_s ({self.window_s}) and stride_s ({self.stride_s}) must be whole "
                             f"numbers of samples at {self.rate_hz} Hz")
        if self.n_window < self.n_stride:
            raise ValueError(f"inertial grid: window_s {self.window_s} is shorter than stride_s {self.stride_s}")

    @property
    def n_window(self) -> int:
        return int(round(self.window_s * self.rate_hz))

    @property
    def n_stride(self) -> int:
        return int(round(self.stride_s * self.rate_hz))

    def as_dict(self) -> dict:
        return {"rate_hz": float(self.rate_hz), "window_s": float(self.window_s), "stride_s": float(self.stride_s)}

    @classmethod
    def from_meta(cls, node, where: str, field: str = "grid") -> "InertialGrid":
        """The grid of a stranger's file (a checkpoint's meta, an export's meta.json): every number bounded
        (:func:`blenav.limits.check_range`) before use, errors naming ``where`` and the field."""
        g = node if isinstance(node, dict) else {}
        try:
            grid = cls(check_range(g.get("rate_hz"), "rate_hz", where, field=f"{field}.rate_hz"),
                       check_range(g.get("window_s"), "window_s", where, field=f"{field}.window_s"),
                       check_range(g.get("stride_s"), "window_s", where, field=f"{field}.stride_s"))
        except LimitError:
            raise
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
        check_range(grid.n_window, "history", where, field=f"{field} (window samples)")
        return grid


def n_windows(n_samples: int, grid: InertialGrid) -> int:
    """K: the windows of a walk of ``n_samples`` resampled IMU samples (module doc; 0 when shorter than one stride)."""
    return max((int(n_samples) - 1) // grid.n_stride, 0)


def padded(X: np.ndarray, grid: InertialGrid) -> np.ndarray:
    """The resampled IMU ``X`` (N, C) with its first sample repeated ``n_window - 1`` times in front (a phone at rest
    before it moved) and cut after the last window's end: what :func:`cut` slices windows from."""
    K = n_windows(len(X), grid)
    return np.concatenate([np.repeat(X[:1], grid.n_window - 1, axis=0), X[: K * grid.n_stride + 1]], axis=0)


def cut(Xp: np.ndarray, grid: InertialGrid, index: np.ndarray) -> np.ndarray:
    """(len(index), n_window, C) float32: windows ``index`` of a :func:`padded` IMU (only those are copied)."""
    view = sliding_window_view(Xp, grid.n_window, axis=0)  # (N', C, n_w): view[j] = Xp[j : j + n_w]
    # window k ends at X sample (k + 1) n_s = padded index (k + 1) n_s + n_w - 1: it starts at padded (k + 1) n_s
    return np.ascontiguousarray(view[grid.n_stride * (np.asarray(index) + 1)].transpose(0, 2, 1), dtype=np.float32)


def windows(X: np.ndarray, grid: InertialGrid) -> np.ndarray:
    """(K, n_window, C) float32 windows of the resampled IMU ``X`` (N, C) (module doc: window k ends at sample
    (k + 1) n_stride; K = (N - 1) // n_stride, zero when the walk is shorter than one stride). Their memory,
    K n_window C 4 bytes (n_window / n_stride times the IMU's), is checked first (:func:`blenav.limits.check_memory`):
    a stranger's grid (a 1 ms stride) cannot claim hundreds of GB."""
    K = n_windows(len(X), grid)
    if K <= 0:
        return np.zeros((0, grid.n_window, X.shape[1]), np.float32)
    check_memory(4.0 * K * grid.n_window * X.shape[1], f"{K:,} IMU windows of {grid.n_window} samples",
                 "inertial odometry")
    return cut(padded(X, grid), grid, np.arange(K))


def integrate(t0: float, grid: InertialGrid, velocity: np.ndarray, log_var: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The odometry track of per-window velocities: (t (K+1,) s, xy (K+1, 2) m from 0, var (K+1,) m^2).

    ``velocity`` (K, 2) m/s, window k's mean over [t0 + k stride, t0 + (k+1) stride]; ``log_var`` (K, 2) its log
    variance ((m/s)^2). ``var`` is the cumulative isotropic variance of the position (the mean of the two axes'
    stride^2 exp(log_var), summed: windows taken as independent), 0 at the start; zeros without ``log_var``."""
    v = np.asarray(velocity, float).reshape(-1, 2)
    s = float(grid.stride_s)
    t = t0 + s * np.arange(len(v) + 1)
    xy = np.vstack([np.zeros((1, 2)), np.cumsum(v * s, axis=0)])
    if log_var is None:
        var = np.zeros(len(t))
    else:
        step_var = s * s * np.exp(np.clip(np.asarray(log_var, float).reshape(-1, 2), -30.0, 30.0)).mean(axis=1)
        var = np.concatenate([[0.0], np.cumsum(step_var)])
    return t, xy, var


def segment_weights(t0: float, grid: InertialGrid, K: int, a: np.ndarray, b: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How the windows' output intervals make up segments [a_j, b_j] (s): the displacement over segment j is
    ``sum_k w_jk v_k`` with w_jk the seconds of window k's interval inside the segment (the segment integral of the
    predicted velocity). Returns sparse triples (segment index (M,), window index (M,), weight (M,) s) over the K
    windows; a segment's part outside the windows' span has no window (its weights sum to less than b - a)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    s = float(grid.stride_s)
    lo = t0 + s * np.arange(K)
    seg, win, w = [], [], []
    for j, (aj, bj) in enumerate(zip(a, b)):
        k0 = max(int(np.floor((aj - t0) / s)), 0)
        k1 = min(int(np.ceil((bj - t0) / s)), K)
        if k1 <= k0:
            continue
        ks = np.arange(k0, k1)
        ov = np.minimum(lo[ks] + s, bj) - np.maximum(lo[ks], aj)
        keep = ov > 1e-9
        seg.append(np.full(int(keep.sum()), j))
        win.append(ks[keep])
        w.append(ov[keep])
    if not seg:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(seg).astype(np.int64), np.concatenate(win).astype(np.int64), np.concatenate(w)


def displacement_errors(t: np.ndarray, xy: np.ndarray, a: np.ndarray, b: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(S,) m: |(p(b_j) - p(a_j)) - d_j| of a track (t (T,) s, xy (T, 2) m; linear between its samples, held before
    its first and after its last) over segments [a_j, b_j] with true displacements d_j (S, 2): the 2021 indoor
    challenge's per-segment error of a step / odometry model (issue 31, ``segment_error_m``)."""
    t, xy = np.asarray(t, float), np.asarray(xy, float)
    pa = np.stack([np.interp(a, t, xy[:, j]) for j in (0, 1)], axis=-1)
    pb = np.stack([np.interp(b, t, xy[:, j]) for j in (0, 1)], axis=-1)
    return np.linalg.norm(pb - pa - np.asarray(d, float).reshape(-1, 2), axis=1)


def turn_pairs(W: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Every (x, y) channel pair (:data:`YAW_PAIRS`) of ``W`` (K, n, C) turned by the angle with cos c (K,), sin s (K,)."""
    W = np.array(W, dtype=np.float32, copy=True)
    c, s = c[:, None].astype(np.float32), s[:, None].astype(np.float32)
    for i, j in YAW_PAIRS:
        x, y = W[..., i].copy(), W[..., j].copy()
        W[..., i], W[..., j] = c * x - s * y, s * x + c * y
    return W


def heading_frame(W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(windows turned into their heading frame (K, n, C) float32, psi (K,) rad): module doc."""
    h = W[:, :, 9:11].mean(axis=1)
    z = W[:, :, 12:14].mean(axis=1)
    use = np.linalg.norm(h, axis=1) >= MIN_HORIZONTAL
    v = np.where(use[:, None], h, z)
    psi = np.arctan2(v[:, 1], v[:, 0])
    return turn_pairs(W, np.cos(-psi), np.sin(-psi)), psi


def rotate_velocity(v: np.ndarray, log_var: np.ndarray, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Velocities (K, 2) and per-axis log variances (K, 2) of the heading frame turned back into the attitude's frame
    by psi (K,) rad: v_w = R(psi) v; the variances are the diagonal of R diag(var) R^T."""
    c, s = np.cos(psi), np.sin(psi)
    vw = np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], axis=1)
    var = np.exp(np.asarray(log_var, float))
    varw = np.stack([c * c * var[:, 0] + s * s * var[:, 1], s * s * var[:, 0] + c * c * var[:, 1]], axis=1)
    return vw, np.log(varw)
