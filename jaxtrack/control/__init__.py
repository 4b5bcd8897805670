"""Controllers: pose reaching (seed 000, Algorithm 1), unicycle person following with a follower
point (seed 004, eq. 9), the person-interest-adapted potential field and the person-interest
case base (seed 002, II-B and II-C), a dynamic window for obstacles, routes around the static
obstacles of a map, the following behaviour that chains them, person costmaps (seed 003, IV) and
a grid planner with a pure-pursuit path follower; small box-constrained QPs and the preview-QP
walking pattern generator (seed 000, section 4)."""

from jaxtrack.control import (avoidance, behaviour, costmap, follower, grid_planner, pan_tilt,
                              person_interest, pose, potential_field, qp, route, walking_mpc)

__all__ = ["avoidance", "behaviour", "costmap", "follower", "grid_planner", "pan_tilt",
           "person_interest", "pose", "potential_field", "qp", "route", "walking_mpc"]
