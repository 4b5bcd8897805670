"""Controllers: pose reaching (seed 000, Algorithm 1)."""

from jaxtrack.control import pose

__all__ = ["pose"]
