"""Localization methods behind one interface (:class:`Localizer`, :class:`Estimate`), built from config.

A new method is one class deriving from :class:`Localizer`, one YAML file in ``conf/localizer/`` naming it as
``_target_``, and that name in :data:`blenav.trust.TARGETS`; the evaluation harness needs no change.
"""

from .base import (Estimate, FixConsumer, InertialModelConsumer, Localizer, ModelConsumer, PathLossCalibrated, Trained,
                   Transductive, build_localizer)
from .fixtrack import FixTrackLocalizer
from .inputs import Fixes, RoleFixes, RunInputs
from .particle import ParticleFilterLocalizer

__all__ = ["Estimate", "FixConsumer", "FixTrackLocalizer", "Fixes", "InertialModelConsumer", "Localizer", "ModelConsumer", "Trained",
           "ParticleFilterLocalizer", "PathLossCalibrated", "RoleFixes", "RunInputs", "Transductive", "build_localizer"]
