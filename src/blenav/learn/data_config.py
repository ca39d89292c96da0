"""The schemas of the training-data nodes (``data`` of conf/train.yaml and conf/eval.yaml), torch-free.

:class:`WindowDataConfig` (``conf/windows/default.yaml``, RSSI windows of the cross-phone localizers,
:class:`blenav.learn.data.WindowDataModule`) and :class:`MapPriorDataConfig` (``conf/windows/mapprior.yaml``,
odometry windows and map crops of the map prior, :class:`blenav.learn.mapprior_data.MapPriorDataModule`).
:func:`blenav.configs.register_configs` stores them as ``windows/schema`` and ``windows/mapprior_schema``, so a
misspelt key in a ``data`` node fails when the config is composed. This module imports neither torch nor
lightning: the entry points register the schemas without loading them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any


class WindowSteps(StrEnum):
    """How a window's H steps are taken: ``time`` (steps of 1 / step_hz s along a walk) or ``scan`` (H
    consecutive scans at one point: fingerprint surveys such as the UJI set)."""

    time = "time"
    scan = "scan"


@dataclass
class WindowDataConfig:
    """RSSI windows of one building split by device model (see :func:`blenav.features.windows.split_by_device`).

    ``known_devices`` / ``unlabelled_devices`` None: derived (the train devices / none); an experiment may
    give simulator defaults that follow ``train_devices`` (conf/experiment/crossphone_003.yaml)."""

    path: str = "???"
    building: str | None = None  # required when the dataset holds several buildings
    sessions: list[str] | None = None  # only these session ids (before the device split); None: all
    beacons: Any = None  # None: every BLE beacon; int k: spread_beacons(k) on the floor; list: those ids
    train_devices: list | None = None
    test_devices: list | None = None
    unlabelled_devices: list | None = None
    known_devices: list | None = None  # brand J of eq. 3.1 (statistics M); None: the train devices
    holdout: float = 0.25  # share of a trained-and-tested device's labelled sessions kept for testing
    unlabelled_share: float = 0.5
    val_fraction: float = 0.2
    # validation windows at most (a seeded subset of the validation sessions' windows; None: all): a validation
    # check then costs the same on a 50k-window survey as on a 2k one (issue 16)
    val_max_windows: int | None = 2048
    history: int = 5
    step_hz: float = 1.0
    steps: WindowSteps = WindowSteps.time  # scan: fingerprint surveys, H consecutive scans at one point
    # windows per optimizer step: a number, or auto (blenav.learn.data.auto_batch_size: 256, or 128 on a survey
    # of fewer than 2,560 training windows, with twice the auto step budget)
    batch_size: Any = "auto"
    seed: int = 0
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        self.steps = WindowSteps(self.steps)  # a plain string from code: checked here as at composition
        b = self.batch_size
        if b != "auto" and (isinstance(b, bool) or not isinstance(b, int) or b < 1):
            raise ValueError(f"data.batch_size={b!r}: a positive integer or auto")


@dataclass
class AugmentConfig:
    """Per-window augmentation of the map prior's odometry windows (``data.augment``)."""

    bias_std: float = 0.5  # multiplicative velocity bias ~ N(1, bias_std) per window (Roy)
    bias_min: float = 0.1  # the bias is clipped to at least this (a window never runs backwards)
    noise_px: float = 0.25  # N(0, noise_px) pixels added to each point (Roy)
    rot_std_deg: float = 0.0  # heading error ~ N(0, rot_std_deg) per window (0: none, as Roy)


@dataclass
class MapPriorDataConfig:
    path: str = "???"
    val_fraction: float = 0.2  # whole sessions of the training buildings held out for val_seen
    val_buildings: list | None = None  # building ids held out entirely (val_unseen); None: none
    window_s: float = 5.0  # n of Roy: seconds of odometry per window
    step_hz: float = 1.0  # odometry samples per second in a window
    kernel_hz: float = 10.0  # ground truth densified at this rate for the target kernel
    max_gap_s: float = 1.0  # a window must not span a ground-truth gap longer than this
    # sessions whose ground truth is surveyed waypoints (session.yaml groundtruth_kind: waypoints, e.g. ILC 2.0
    # imports): the longest gap between two waypoints a window may span; positions between waypoints are linear
    # interpolation made at training time (never written to the dataset)
    waypoint_max_gap_s: float = 30.0
    extra_paths: list[str] = field(default_factory=list)  # further datasets trained on together with path
    # None: every labelled session of the datasets; a list: only these session ids, e.g. the train walks of
    # blenav-eval experiment=realwalks: $(python -m blenav.cli.realwalks train-ids DIR) for each dataset
    sessions: list[str] | None = None
    crop_px: int = 64
    crop_jitter: float = 0.25  # window end within +- crop_jitter * crop_px of the crop centre
    samples_per_epoch: int = 2048
    val_samples: int = 512  # per validation split, fixed for the run
    batch_size: int = 32
    feasible_tbar: float = 0.93  # T_bar threshold of a "feasible region" (T >= T_max / e at 14 * 0.93 = 13)
    target_scale: float = 1.0e-6  # T = target_scale * exp(target_gain * T_bar) (Roy)
    target_gain: float = 14.0
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    num_workers: int = 0
    seed: int = 0

    @property
    def n_points(self) -> int:
        return int(round(self.window_s * self.step_hz)) + 1

    @property
    def paths(self) -> list[str]:
        """``path`` and then ``extra_paths``: every dataset trained on."""
        return [str(self.path)] + [str(p) for p in (self.extra_paths or [])]

    @property
    def n_kernel(self) -> int:
        return int(round(self.window_s * self.kernel_hz)) + 1
