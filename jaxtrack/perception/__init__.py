"""Perception: depth point clouds to likelihoods and orientation (seed 000 depth tracker)."""

from jaxtrack.perception import depth

__all__ = ["depth"]
