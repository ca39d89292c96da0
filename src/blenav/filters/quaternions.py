"""w-first (Hamilton) quaternions of the AHRS (:mod:`blenav.filters.attitude`): products, conjugate, rotations
about z, and rotation matrices. A quaternion q (4,) or (..., 4) is [w, x, y, z]; q rotates device-frame vectors
into the world frame, v_world = R(q) v_device.
"""

from __future__ import annotations

import numpy as np

__all__ = ["qmul", "qmul1", "qconj", "qz", "quat_to_matrix", "matrix_to_quat"]


def qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of w-first quaternions, broadcasting over leading axes."""
    pw, px, py, pz = np.moveaxis(np.asarray(p, float), -1, 0)
    qw, qx, qy, qz = np.moveaxis(np.asarray(q, float), -1, 0)
    return np.stack([pw * qw - px * qx - py * qy - pz * qz,
                     pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx,
                     pw * qz + px * qy - py * qx + pz * qw], axis=-1)


def qmul1(p, q) -> tuple[float, float, float, float]:
    """Hamilton product of two single quaternions with Python floats (the per-sample path)."""
    pw, px, py, pz = (float(v) for v in p)
    qw, qx, qy, qz = (float(v) for v in q)
    return (pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw)


def qconj(q: np.ndarray) -> np.ndarray:
    return np.asarray(q, float) * np.array([1.0, -1.0, -1.0, -1.0])


def qz(angle: float) -> np.ndarray:
    return np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) w-first quaternions (normalised here) -> (..., 3, 3) rotation matrices."""
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z]) * (1.0 if w >= 0 else -1.0)
