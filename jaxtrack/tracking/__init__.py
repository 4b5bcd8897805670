"""Tracking: the estimator protocol (`estimator`), the fixed-capacity multi-target tracker, the
people particle filter, particle clustering, appearance models, colour re-identification, track
stitching, each person's status (walking, standing, seated, hand-over; seed 003), and the
estimators built on them: of a followed user (`user`) and of a humanoid under
a ceiling camera (`humanoid` on depth, `colour_pf` on colour)."""

from jaxtrack.tracking import (appearance, clustering, colour_pf, estimator, humanoid,
                               people_pf, reid, status, stitching, user)
from jaxtrack.tracking.estimator import Estimator
from jaxtrack.tracking.tracker import (CONFIRMED, FREE, TENTATIVE, Detections, TrackerConfig,
                                       TrackerParams, Tracks, init, is_walking, make_detections,
                                       run, step)

__all__ = ["appearance", "clustering", "colour_pf", "estimator", "humanoid", "people_pf", "reid",
           "status", "stitching", "user", "Estimator", "TrackerConfig", "TrackerParams",
           "Tracks", "Detections", "init", "step", "run", "is_walking", "make_detections", "FREE",
           "TENTATIVE", "CONFIRMED"]
