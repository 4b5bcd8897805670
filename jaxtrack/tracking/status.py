r"""Person status and heading from a tracker's state (seed 003, section III-D).

The seed's navigation needs, for every tracked person, a position, a heading and a status --
standing, walking, seated or hand-over -- which selects the shape of the person's cost
(`jaxtrack.control.costmap`). It derives both from the tracker's constant-velocity estimate:

- the heading is the direction of the velocity, :math:`\phi = \operatorname{atan2}(v_y, v_x)`,
  while the person walks; below the threshold the velocity's direction is noise, so the
  previous heading is kept;
- a person is *walking* if the speed exceeds :math:`v_0 = 0.1` m/s ("obtained heuristically",
  seed 003);
- a still person is *seated* inside a sitting area (the detectors cannot tell sitting from
  standing, so the seed marks the couch as a sitting area), *hand-over* inside a hand-over area
  (the seed's "postman area": "when there is a person standing in this area, the robot knows
  that this is the person to approach"), else *standing*.

.. math::
    s = \begin{cases} \text{WALKING} & \|v\| > v_0 \\
                      \text{HANDOVER} & \|v\| \le v_0,\ p \in \text{hand-over areas} \\
                      \text{SEATED} & \|v\| \le v_0,\ p \in \text{sitting areas} \\
                      \text{STANDING} & \text{otherwise.} \end{cases}

A new track's velocity is a guess (its prior spread is about 1 m/s), and a still person's
estimated speed wanders around the threshold, so with the velocity's covariance
:math:`P_v` (``velocity_cov``) a person walks only when the speed is also *significant*:
:math:`v^T P_v^{-1} v > \chi^2_2{}^{-1}(\alpha)` (``significance`` :math:`\alpha`, 0.99 by
default in `from_tracks`): a person sat on the couch is not called walking, and the costmap
keeps their TV interaction, while their first track estimates settle.

A person walking through an area keeps the walking status (the seed's areas are for still
people); where a hand-over area overlaps a sitting area, hand-over wins (the robot was sent to
that person). Areas are oriented boxes (`Areas`), a fixed-size array with a mask.

The status codes are the module constants `WALKING`, `STANDING`, `SEATED`, `HANDOVER`; the
first two equal the mode indices of the tracker's walking / standing IMM
(`jaxtrack.tracking.tracker.WALKING`, `STANDING`), so the most probable mode of an IMM track is
already its status before the areas are applied. `jaxtrack.control.costmap` uses the same
constants.

The status is a discrete decision; its output carries no gradient (the heading does, with
respect to the velocity, while walking).

Example:
  >>> couch = Areas.create(center=[[2.0, 1.0]], half_size=[[1.0, 0.4]])
  >>> s = classify(jnp.array([[2.0, 1.1]]), jnp.zeros((1, 2)), jnp.zeros(1), sitting=couch)
  >>> s.status                                    # [SEATED]
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxtrack import _checks, geometry
from jaxtrack.tracking import tracker as tracker_module

Array = jax.Array

__all__ = ["WALKING", "STANDING", "SEATED", "HANDOVER", "NUM_STATUSES", "NAMES",
           "WALKING_SPEED", "Areas", "PersonStatus", "inside", "classify", "from_tracks"]

WALKING, STANDING, SEATED, HANDOVER = 0, 1, 2, 3
"""Status codes (int32). WALKING and STANDING equal the tracker's IMM mode indices."""
NUM_STATUSES = 4
NAMES = ("walking", "standing", "seated", "hand-over")
"""Names of the status codes, indexed by code."""
WALKING_SPEED = 0.1
"""Speed (m/s) above which a person is walking (seed 003, section III-D)."""


class Areas(NamedTuple):
    r"""A fixed number A of oriented boxes in the map frame, with a mask.

    A point :math:`x` is inside box :math:`a` if :math:`|R(\theta_a)^T (x - c_a)| \le h_a`
    componentwise (boundary included). Build with `Areas.create`.

    Attributes:
      center: [A, 2] box centres (m).
      half_size: [A, 2] half extents along the box's own x and y axes (m), > 0.
      angle: [A] box orientation :math:`\theta_a` (rad); 0 for axis-aligned boxes.
      mask: [A] bools, the boxes in use.
    """

    center: Array
    half_size: Array
    angle: Array
    mask: Array

    @classmethod
    def create(cls, center, half_size, angle=None, mask=None, dtype=None) -> "Areas":
        """Boxes from centres [A, 2] and half sizes [A, 2] (angles and mask optional).

        Example:
          >>> sofa = Areas.create([[2.0, 1.0]], [[1.0, 0.4]], angle=[0.3])
          >>> none = Areas.create(np.zeros((0, 2)), np.zeros((0, 2)))   # no areas
        """
        _checks.check_shape("center", center, (None, 2), "[A, 2]")
        a = _checks.shape_of(center)[0]
        _checks.check_shape("half_size", half_size, (a, 2), "[A, 2]")
        _checks.check_finite("center", center)
        _checks.check_finite("half_size", half_size)
        if _checks.is_concrete(half_size) and not np.all(np.asarray(half_size) > 0):
            raise ValueError(f"half_size must be > 0; got {half_size}")
        if angle is not None:
            _checks.check_shape("angle", angle, (a,), "[A]")
            _checks.check_finite("angle", angle)
        if mask is not None:
            _checks.check_shape("mask", mask, (a,), "[A]")
        dtype = dtype if dtype is not None else jnp.result_type(float)
        angle = jnp.zeros(a, dtype) if angle is None else jnp.asarray(angle, dtype)
        mask = jnp.ones(a, bool) if mask is None else jnp.asarray(mask, bool)
        return cls(jnp.asarray(center, dtype), jnp.asarray(half_size, dtype), angle, mask)


class PersonStatus(NamedTuple):
    """Per-track status.

    Attributes:
      status: [K] int32 status codes (`STANDING` for masked tracks).
      heading: [K] heading (rad): of the velocity while walking, else the previous heading.
      speed: [K] speed (m/s).
      mask: [K] bools, the tracks classified (the input mask, and finite inputs).
    """

    status: Array
    heading: Array
    speed: Array
    mask: Array


def inside(areas: Areas, xy: Array) -> Array:
    r"""Whether points lie in any box of ``areas`` (masked boxes excluded).

    Args:
      areas: `Areas` with A boxes (A may be 0).
      xy: [..., 2] points in the map frame.

    Returns:
      [...] bools.

    Example:
      >>> inside(Areas.create([[0.0, 0.0]], [[1.0, 0.5]]), jnp.array([[0.9, 0.4], [0.0, 0.6]]))
    """
    _check_areas("areas", areas)
    _checks.check_shape("xy", xy, (*_checks.shape_of(xy)[:-1], 2), "[..., 2]")
    return _inside(areas, jnp.asarray(xy))


def classify(position: Array, velocity: Array, previous_heading: Array, mask: Array | None = None,
             *, sitting: Areas | None = None, handover: Areas | None = None,
             walking_speed=WALKING_SPEED, velocity_cov: Array | None = None,
             significance=0.99) -> PersonStatus:
    r"""Status and heading of K tracks (module docstring; seed 003, section III-D).

    Pure and batched over tracks; ``vmap`` over episodes by the caller. Tracks with non-finite
    position or velocity are treated as masked.

    Args:
      position: [K, 2] positions in the map frame (m).
      velocity: [K, 2] velocities (m/s).
      previous_heading: [K] headings (rad) kept while a person is still.
      mask: optional [K] bools, the live tracks (default all).
      sitting: optional `Areas`, the sitting areas (seated if still inside one).
      handover: optional `Areas`, the hand-over areas (hand-over if still inside one).
      walking_speed: :math:`v_0` (m/s), > 0; the seed's 0.1 by default.

    Returns:
      `PersonStatus` with [K] status, heading, speed and mask.

    Example:
      >>> s = classify(jnp.zeros((2, 2)), jnp.array([[0.0, 0.5], [0.02, 0.0]]), jnp.zeros(2))
      >>> s.status, s.heading                         # [WALKING, STANDING], [pi/2, 0]
    """
    _checks.check_shape("position", position, (None, 2), "[K, 2]")
    k = _checks.shape_of(position)[0]
    _checks.check_shape("velocity", velocity, (k, 2), "[K, 2]")
    _checks.check_shape("previous_heading", previous_heading, (k,), "[K]")
    if mask is not None:
        _checks.check_shape("mask", mask, (k,), "[K]")
    if sitting is not None:
        _check_areas("sitting", sitting)
    if handover is not None:
        _check_areas("handover", handover)
    _checks.check_shape("walking_speed", walking_speed, (), "scalar")
    if _checks.is_concrete(walking_speed) and not float(walking_speed) > 0:
        raise ValueError(f"walking_speed must be > 0; got {walking_speed}")
    if velocity_cov is not None:
        _checks.check_shape("velocity_cov", velocity_cov, (k, 2, 2), "[K, 2, 2]")
    _checks.check_probability("significance", significance)
    if _checks.is_concrete(significance) and not 0 < float(significance) < 1:
        raise ValueError(f"significance must be in (0, 1); got {significance}")
    position, velocity, previous_heading = (jnp.asarray(x) for x in
                                            (position, velocity, previous_heading))
    dtype = jnp.result_type(position.dtype, velocity.dtype, previous_heading.dtype, jnp.float32)
    mask = jnp.ones(k, bool) if mask is None else jnp.asarray(mask, bool)
    threshold = None
    if velocity_cov is not None:
        velocity_cov = jnp.asarray(velocity_cov, dtype)
        threshold = -2.0 * jnp.log1p(-jnp.asarray(significance, dtype))   # chi2, 2 dof
    return _classify(position.astype(dtype), velocity.astype(dtype),
                     previous_heading.astype(dtype), mask, sitting, handover,
                     jnp.asarray(walking_speed, dtype), velocity_cov, threshold)


def from_tracks(tracks: tracker_module.Tracks, *, sitting: Areas | None = None,
                handover: Areas | None = None, walking_speed=WALKING_SPEED,
                confirmed_only: bool = False, significance=0.99) -> PersonStatus:
    """`classify` applied to a multi-target tracker's state.

    Position and velocity are ``tracks.mean[:, :2]`` and ``[:, 2:]``; the previous heading is
    ``tracks.heading`` (which the tracker itself holds while a person is still). Live tracks
    (not `jaxtrack.tracking.tracker.FREE`) are classified, or only the confirmed ones with
    ``confirmed_only`` (a tentative track may be clutter; a costmap that ignores it risks less
    of a detour and more of a collision, hence the default).

    Args:
      tracks: `jaxtrack.tracking.tracker.Tracks` with K slots.
      sitting, handover, walking_speed: as in `classify`.
      confirmed_only: classify confirmed tracks only.
      significance: of the speed test with the tracks' velocity covariances (`classify`).

    Returns:
      `PersonStatus` [K].

    Example:
      >>> people = from_tracks(state, sitting=couch)             # state from tracker.step
    """
    if not isinstance(tracks, tracker_module.Tracks):
        raise TypeError(f"tracks must be a tracker.Tracks; got {type(tracks).__name__}")
    if confirmed_only:
        live = tracks.status == tracker_module.CONFIRMED
    else:
        live = tracks.status != tracker_module.FREE
    return classify(tracks.mean[:, :2], tracks.mean[:, 2:], tracks.heading, live,
                    sitting=sitting, handover=handover, walking_speed=walking_speed,
                    velocity_cov=tracks.cov[:, 2:, 2:], significance=significance)


# ---------------------------------------------------------------------------------------------
# Private


def _inside(areas, xy):
    dtype = jnp.result_type(xy.dtype, jnp.float32)
    xy = xy.astype(dtype)
    centre = areas.center.astype(dtype)
    # every point in every box's frame: [..., A, 2]
    q = geometry.unrotate(areas.angle.astype(dtype), xy[..., None, :] - centre)
    within = jnp.all(jnp.abs(q) <= areas.half_size.astype(dtype), -1) & areas.mask
    return jnp.any(within, -1)


@jax.jit
def _classify(position, velocity, previous_heading, mask, sitting, handover, walking_speed,
              velocity_cov=None, threshold=None):
    finite = (jnp.all(jnp.isfinite(position), -1) & jnp.all(jnp.isfinite(velocity), -1)
              & jnp.isfinite(previous_heading))
    mask = mask & finite
    # sanitise masked rows first, so their NaNs reach neither the outputs nor the gradients
    position = jnp.where(mask[:, None], position, 0.0)
    velocity = jnp.where(mask[:, None], velocity, 0.0)
    previous_heading = jnp.where(mask, previous_heading, 0.0)
    speed = geometry.safe_norm(velocity)
    walking = mask & (speed > walking_speed)
    if velocity_cov is not None:
        cov = jnp.where(mask[:, None, None], velocity_cov, jnp.eye(2, dtype=velocity.dtype))
        cov = 0.5 * (cov + jnp.swapaxes(cov, -1, -2))
        d2 = jnp.sum(velocity * jnp.linalg.solve(cov, velocity[..., None])[..., 0], -1)
        walking = walking & (d2 > threshold)
    safe_v = jnp.where(walking[:, None], velocity, jnp.ones_like(velocity))
    heading = jnp.where(walking, jnp.arctan2(safe_v[:, 1], safe_v[:, 0]), previous_heading)
    still = mask & ~walking
    seated = still & (_inside(sitting, position) if sitting is not None else False)
    hand = still & (_inside(handover, position) if handover is not None else False)
    status = jnp.full(mask.shape, STANDING, jnp.int32)
    status = jnp.where(walking, WALKING, status)
    status = jnp.where(seated, SEATED, status)
    status = jnp.where(hand, HANDOVER, status)
    return PersonStatus(status.astype(jnp.int32), heading, speed, mask)


def _check_areas(name, areas):
    if not isinstance(areas, Areas):
        raise TypeError(f"{name} must be a status.Areas; got {type(areas).__name__}")
    _checks.check_shape(f"{name}.center", areas.center, (None, 2), "[A, 2]")
    a = _checks.shape_of(areas.center)[0]
    _checks.check_shape(f"{name}.half_size", areas.half_size, (a, 2), "[A, 2]")
    _checks.check_shape(f"{name}.angle", areas.angle, (a,), "[A]")
    _checks.check_shape(f"{name}.mask", areas.mask, (a,), "[A]")
