"""Multi-target tracking: particle clustering into people (track management follows)."""

from jaxtrack.tracking import clustering

__all__ = ["clustering"]
