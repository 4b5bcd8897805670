"""Bayesian filters: Kalman, extended and unscented Kalman, particle, heading filter."""

from jaxtrack.filters import ekf, heading, kalman, particle, ukf

__all__ = ["kalman", "ekf", "ukf", "particle", "heading"]
