"""Controllers: pose reaching (seed 000, Algorithm 1), unicycle person following with a follower
point (seed 004, eq. 9) and the person-interest-adapted potential field (seed 002, II-C)."""

from jaxtrack.control import avoidance, follower, pose, potential_field

__all__ = ["avoidance", "follower", "pose", "potential_field"]
