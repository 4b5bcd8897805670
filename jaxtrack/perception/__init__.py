"""Perception: depth point clouds to likelihoods and orientation (seed 000 depth tracker), laser
scans to legs and people (seed 004 leg detector), and the sensing step of a person-following
robot (laser and RGB-D people into the estimators' frame)."""

from jaxtrack.perception import depth, legs, sensing

__all__ = ["depth", "legs", "sensing"]
