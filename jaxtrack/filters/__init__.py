"""Bayesian filters: Kalman, extended and unscented Kalman, IMM, particle, heading filter."""

from jaxtrack.filters import ekf, heading, imm, kalman, particle, ukf

__all__ = ["kalman", "ekf", "ukf", "imm", "particle", "heading"]
