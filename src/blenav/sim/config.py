"""Structured config of the world simulator (Hydra group ``sim/``).

A misspelt key fails at :func:`make_sim_config`: the preset YAML is merged into these dataclasses.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from omegaconf import DictConfig, OmegaConf

from .inertial import ImuConfig, MagConfig, OdometryConfig
from .layout import LayoutConfig
from .motion import MotionConfig
from .radio import BleConfig, RttConfig
from .receivers import TABLE_3_2


@dataclass
class VisualConfig:
    n_landmarks: int = 4
    radius_m: float = 1.5
    min_interval_s: float = 20.0
    pos_std_m: float = 0.1
    yaw_std_deg: float = 3.0


@dataclass
class SimConfig:
    name: str = "small"
    description: str = ""
    buildings: int = 1  # > 1: procedural buildings with layout_seed + k
    layout: LayoutConfig = field(default_factory=LayoutConfig)
    n_beacons: int = 8
    n_rtt_aps: int = 2
    beacon_height_m: float = 2.5
    ap_height_m: float = 2.8
    prior_map_std_m: float = 0.0  # Gaussian error of the written (prior) anchor positions, per axis
    ble: BleConfig = field(default_factory=BleConfig)
    rtt: RttConfig = field(default_factory=RttConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    mag: MagConfig = field(default_factory=MagConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    visual: VisualConfig = field(default_factory=VisualConfig)
    receivers: list[str] = field(default_factory=lambda: list(TABLE_3_2))  # cycled over sessions
    carriers: list[str] = field(default_factory=lambda: ["pedestrian"])  # cycled over sessions
    unlabelled_every: int = 0  # every k-th session has no ground truth (0: none)
    groundtruth_rate_hz: float = 10.0


def make_sim_config(node: DictConfig | dict | None) -> SimConfig:
    """Validate a preset against :class:`SimConfig` (unknown keys raise) and return the dataclass."""
    schema = OmegaConf.structured(SimConfig)
    merged = OmegaConf.merge(schema, node or {})
    cfg: SimConfig = OmegaConf.to_object(merged)  # type: ignore[assignment]
    unknown = [r for r in cfg.receivers if r not in TABLE_3_2]
    if unknown:
        raise ValueError(f"sim.receivers: unknown profile(s) {unknown}; known: {sorted(TABLE_3_2)}")
    bad = [c for c in cfg.carriers if c not in ("pedestrian", "robot", "static")]
    if bad:
        raise ValueError(f"sim.carriers: {bad} not in pedestrian, robot, static")
    return cfg

