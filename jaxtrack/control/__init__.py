"""Controllers: pose reaching (seed 000, Algorithm 1), unicycle person following with a follower
point (seed 004, eq. 9), the person-interest-adapted potential field (seed 002, II-C), a dynamic
window for obstacles, routes around the static obstacles of a map, and the following behaviour
that chains them."""

from jaxtrack.control import (avoidance, behaviour, follower, pan_tilt, pose, potential_field,
                              route)

__all__ = ["avoidance", "behaviour", "follower", "pan_tilt", "pose", "potential_field", "route"]
