"""Tracking metrics for one episode, all jittable and vmappable: position and wrapped-angle
errors, NEES / NIS with chi-square consistency bounds."""

from jaxtrack.metrics.errors import (angle_error, angle_mae, angle_rmse, chi2_bounds, chi2_ppf,
                                     nees, nis, position_error, rmse)

__all__ = ["position_error", "rmse", "angle_error", "angle_rmse", "angle_mae", "nees", "nis",
           "chi2_ppf", "chi2_bounds"]
