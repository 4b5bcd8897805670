"""jaxtrack: tracking people and humanoid robots in closed loop, in JAX.

Pure, jitted, vmappable and differentiable filters, data association and controllers, with MJX
simulations (in the separate ``sims`` package) for batched Monte-Carlo evaluation and gradient
tuning. ``import jaxtrack`` never imports MuJoCo.
"""

import importlib

from jaxtrack import (angles, association, control, filters, geometry, metrics, models,
                      montecarlo, perception, tracking, tuning)

__version__ = "0.1.0"

__all__ = ["angles", "association", "control", "filters", "geometry", "metrics", "models",
           "montecarlo",
           "perception", "plotting", "tracking", "tuning", "__version__"]


def __getattr__(name):
    # matplotlib is only imported when plots are asked for.
    if name == "plotting":
        return importlib.import_module("jaxtrack.plotting")
    raise AttributeError(f"module 'jaxtrack' has no attribute {name!r}")
