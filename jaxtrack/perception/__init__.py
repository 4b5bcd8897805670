"""Perception: depth point clouds to likelihoods and orientation (seed 000 depth tracker), laser
scans to legs and people (seed 004 leg detector)."""

from jaxtrack.perception import depth, legs

__all__ = ["depth", "legs"]
