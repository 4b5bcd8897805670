"""Tracking metrics for one episode, all jittable and vmappable: position and wrapped-angle
errors, NEES / NIS with chi-square consistency bounds, CLEAR MOT (MOTA, MOTP, identity
switches, fragmentations, mostly tracked / lost) and the OSPA / GOSPA set distances."""

from jaxtrack.metrics.clear_mot import ClearMOTResult, FrameEvents, clear_mot
from jaxtrack.metrics.clear_mot import combine as combine_clear_mot
from jaxtrack.metrics.errors import (angle_error, angle_mae, angle_rmse, chi2_bounds, chi2_ppf,
                                     nees, nis, position_error, rmse)
from jaxtrack.metrics.ospa import GOSPAResult, OSPAResult, gospa, ospa

__all__ = ["position_error", "rmse", "angle_error", "angle_rmse", "angle_mae", "nees", "nis",
           "chi2_ppf", "chi2_bounds", "clear_mot", "combine_clear_mot", "ClearMOTResult",
           "FrameEvents", "ospa", "gospa", "OSPAResult", "GOSPAResult"]
