"""Multi-target tracking: the fixed-capacity tracker, particle clustering, appearance models."""

from jaxtrack.tracking import appearance, clustering
from jaxtrack.tracking.tracker import (CONFIRMED, FREE, TENTATIVE, Detections, TrackerConfig,
                                       TrackerParams, Tracks, init, is_walking, make_detections,
                                       run, step)

__all__ = ["appearance", "clustering", "TrackerConfig", "TrackerParams", "Tracks", "Detections",
           "init", "step", "run", "is_walking", "make_detections", "FREE", "TENTATIVE",
           "CONFIRMED"]
