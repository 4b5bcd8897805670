"""Bayesian filters: Kalman, extended and unscented Kalman, heading filter."""

from jaxtrack.filters import ekf, heading, kalman, ukf

__all__ = ["kalman", "ekf", "ukf", "heading"]
