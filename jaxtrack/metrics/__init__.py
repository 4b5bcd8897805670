"""Tracking metrics for one episode, all jittable and vmappable: position and wrapped-angle
errors, NEES / NIS with chi-square consistency bounds, CLEAR MOT (MOTA, MOTP, identity
switches, fragmentations, mostly tracked / lost), the identity metrics IDF1 / IDP / IDR, HOTA
with DetA / AssA / LocA, and the OSPA / GOSPA set distances."""

from jaxtrack.metrics.clear_mot import ClearMOTResult, FrameEvents, clear_mot
from jaxtrack.metrics.clear_mot import combine as combine_clear_mot
from jaxtrack.metrics.errors import (angle_error, angle_mae, angle_rmse, chi2_bounds, chi2_ppf,
                                     nees, nis, position_error, rmse)
from jaxtrack.metrics.hota import HOTAResult, hota
from jaxtrack.metrics.hota import combine as combine_hota
from jaxtrack.metrics.identity import IdentityResult, identity_metrics
from jaxtrack.metrics.identity import combine as combine_identity
from jaxtrack.metrics.ospa import GOSPAResult, OSPAResult, gospa, ospa

__all__ = ["position_error", "rmse", "angle_error", "angle_rmse", "angle_mae", "nees", "nis",
           "chi2_ppf", "chi2_bounds", "clear_mot", "combine_clear_mot", "ClearMOTResult",
           "FrameEvents", "identity_metrics", "combine_identity", "IdentityResult", "hota",
           "combine_hota", "HOTAResult", "ospa", "gospa", "OSPAResult", "GOSPAResult"]
