"""The schema of the cross-phone training-data node (``data`` of conf/train.yaml and conf/eval.yaml), torch-free.

:class:`WindowDataConfig` (``conf/windows/default.yaml``, RSSI windows of the cross-phone localizers,
:class:`blenav.learn.crossphone.data.WindowDataModule`; the map prior's is :mod:`blenav.learn.mapprior.data_config`).
:func:`blenav.configs.register_configs` stores it as ``windows/schema``, so a misspelt key in a ``data`` node fails
when the config is composed. This module imports neither torch nor lightning: the entry points register the
schemas without loading them.
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
    # windows per optimizer step: a number, or auto (blenav.learn.crossphone.data.auto_batch_size: 256, or 128 on a survey
    # of fewer than 2,560 training windows, with twice the auto step budget)
    batch_size: Any = "auto"
    seed: int = 0
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        self.steps = WindowSteps(self.steps)  # a plain string from code: checked here as at composition
        b = self.batch_size
        if b != "auto" and (isinstance(b, bool) or not isinstance(b, int) or b < 1):
            raise ValueError(f"data.batch_size={b!r}: a positive integer or auto")
