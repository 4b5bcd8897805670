"""Multi-target tracking: the fixed-capacity tracker, the people particle filter, particle
clustering, appearance models."""

from jaxtrack.tracking import appearance, clustering, people_pf
from jaxtrack.tracking.tracker import (CONFIRMED, FREE, TENTATIVE, Detections, TrackerConfig,
                                       TrackerParams, Tracks, init, is_walking, make_detections,
                                       run, step)

__all__ = ["appearance", "clustering", "people_pf", "TrackerConfig", "TrackerParams", "Tracks", "Detections",
           "init", "step", "run", "is_walking", "make_detections", "FREE", "TENTATIVE",
           "CONFIRMED"]
