"""The schema of the inertial odometry's training-data node (``data`` of ``experiment=inertial``), torch-free.

:class:`InertialDataConfig` (``conf/windows/inertial.yaml``; :class:`blenav.learn.inertial.data.InertialDataModule`).
:func:`blenav.configs.register_configs` stores it as ``windows/inertial_schema``, so a misspelt key in the ``data``
node fails when the config is composed. Imports neither torch nor lightning.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class InertialAugmentConfig:
    """Per-segment augmentation of the training windows (``data.augment``); every window of a segment gets the same
    draw, so a segment stays one consistent stretch of walk."""

    yaw: bool = True  # turn the frame (inputs and target) by a uniform yaw: a heading-agnostic network
    gyro_bias_std: float = 0.01  # rad/s added per axis
    acc_bias_std: float = 0.1  # m/s^2 added per axis
    scale_std: float = 0.02  # each sensor's readings times N(1, scale_std)
    drop_prob: float = 0.02  # share of samples replaced by the previous one (a dropped sample, held; drawn per window)


@dataclass
class InertialDataConfig:
    path: str = "???"
    extra_paths: list[str] = field(default_factory=list)  # further datasets trained on together with path
    # None: every labelled session with an IMU of the datasets; a list: only these ids (e.g. the train walks of
    # blenav-eval experiment=realwalks: $(python -m blenav.cli.realwalks train-ids DIR) for each dataset)
    sessions: list[str] | None = None
    attitude: str = "auto"  # the frame: auto (orientation.csv where present, else the AHRS), orientation, ahrs
    # walks with dense ground truth and its orientation (simulated walks): train in the ground truth's frame
    # (groundtruth; its targets are then exact) or in `attitude`'s (null)
    dense_attitude: str | None = "groundtruth"
    # the attitude's yaw: its own (attitude), the gyroscope's held to its running mean (gyro, blenav.filters.yaw_hold:
    # indoors the magnetometer's heading wanders from place to place, the gyroscope turns with the phone), or auto:
    # gyro for a session whose gyroscope is calibrated (session.yaml gyro_calibrated: a phone's), else attitude
    yaw: str = "auto"
    frame: str = "world"  # world (the attitude's frame, random yaws in training) | heading (each window's heading frame)
    rate_hz: float = 50.0  # the network's IMU rate (the IMU is resampled to it)
    window_s: float = 2.0  # seconds of IMU per window
    stride_s: float = 0.5  # one velocity per stride (the output interval)
    val_fraction: float = 0.15  # whole walks held out for validation (early stopping, the report)
    dense_segment_s: float = 1.0  # dense ground truth: supervised segments of this length
    waypoint_max_gap_s: float = 60.0  # waypoint ground truth: longer gaps between waypoints are not supervised
    batch_segments: int = 32  # segments per batch (a waypoint segment is many windows)
    augment: InertialAugmentConfig = field(default_factory=InertialAugmentConfig)
    num_workers: int = 0
    seed: int = 0

    @property
    def paths(self) -> list[str]:
        """``path`` and then ``extra_paths``: every dataset trained on."""
        return [str(self.path)] + [str(p) for p in (self.extra_paths or [])]
