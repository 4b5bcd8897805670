"""jaxtrack: tracking people and humanoid robots in closed loop, in JAX.

Pure, jitted, vmappable and differentiable filters, data association and controllers, with MJX
simulations (in the separate ``sims`` package) for batched Monte-Carlo evaluation and gradient
tuning. ``import jaxtrack`` never imports MuJoCo.
"""

from jaxtrack import angles, filters, models, tracking

__version__ = "0.1.0"

__all__ = ["angles", "filters", "models", "tracking", "__version__"]
