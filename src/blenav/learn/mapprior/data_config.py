"""The schema of the map prior's training-data node (``data`` of ``experiment=mapprior``), torch-free.

:class:`MapPriorDataConfig` (``conf/windows/mapprior.yaml``, odometry windows and map crops of the map prior,
:class:`blenav.learn.mapprior.data.MapPriorDataModule`). :func:`blenav.configs.register_configs` stores it as
``windows/mapprior_schema``, so a misspelt key in a ``data`` node fails when the config is composed. This module
imports neither torch nor lightning: the entry points register the schemas without loading them.
"""

from __future__ import annotations

from dataclasses import dataclass, field


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
