"""Motion and measurement models (pure functions returning arrays and callables)."""

from jaxtrack.models import measurement, motion

__all__ = ["motion", "measurement"]
