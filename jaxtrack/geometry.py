r"""Planar rigid transforms (SE(2)): rotations, frame changes, pose composition, safe norms.

A pose is ``[x, y, theta]``: the position of a frame's origin and the heading of its x axis in
a parent frame. A point :math:`p` given in that frame is :math:`x + R(\theta) p` in the parent
frame (`from_frame`), and a parent point :math:`q` is :math:`R(\theta)^T (q - x)` in the frame
(`to_frame`), with

.. math:: R(\theta) = \begin{bmatrix} \cos\theta & -\sin\theta \\
                                      \sin\theta & \cos\theta \end{bmatrix}.

Every function broadcasts over leading axes (a pose ``[..., 3]`` against points ``[..., 2]``:
``to_frame(particles[:, None], points)`` gives every point in every particle's frame) and is
jittable, vmappable and differentiable; headings of composed poses are wrapped to
:math:`[-\pi, \pi)`.

Example:
  >>> robot = jnp.array([1.0, 2.0, jnp.pi / 2])
  >>> from_frame(robot, jnp.array([1.0, 0.0]))          # one metre ahead: (1, 3)
  >>> to_frame(robot, from_frame(robot, xy))            # xy again
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxtrack.angles import wrap

Array = jax.Array

__all__ = ["rotate", "unrotate", "to_frame", "from_frame", "compose", "inverse", "relative",
           "safe_norm", "safe_sqrt"]


def rotate(theta, v: Array) -> Array:
    r"""Vectors [..., 2] rotated by ``theta``: :math:`R(\theta) v`.

    A velocity in a robot's axes into the parent frame is ``rotate(heading, v)``; a parent-frame
    velocity into the robot's axes is ``rotate(-heading, v)``.

    Example:
      >>> rotate(jnp.pi / 2, jnp.array([1.0, 0.0]))  # (0, 1)
    """
    c, s = jnp.cos(theta), jnp.sin(theta)
    return jnp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], -1)


def unrotate(theta, v: Array) -> Array:
    r"""Vectors [..., 2] rotated by ``-theta``: :math:`R(\theta)^T v`, e.g. a world-frame
    velocity in the axes of a robot of heading ``theta``.

    Example:
      >>> unrotate(jnp.pi / 2, jnp.array([0.0, 1.0]))  # (1, 0)
    """
    c, s = jnp.cos(theta), jnp.sin(theta)
    return jnp.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1]], -1)


def to_frame(pose: Array, xy: Array) -> Array:
    r"""Parent-frame points [..., 2] into the frame of ``pose`` [..., 3]:
    :math:`R(\theta)^T (q - x)`.

    Example:
      >>> to_frame(jnp.array([1.0, 0.0, jnp.pi / 2]), jnp.array([1.0, 1.0]))  # (1, 0)
    """
    return unrotate(pose[..., 2], xy - pose[..., :2])


def from_frame(pose: Array, xy: Array) -> Array:
    r"""Points [..., 2] given in the frame of ``pose`` [..., 3] into the parent frame:
    :math:`x + R(\theta) p`.

    Example:
      >>> from_frame(jnp.array([1.0, 0.0, jnp.pi / 2]), jnp.array([1.0, 0.0]))  # (1, 1)
    """
    return pose[..., :2] + rotate(pose[..., 2], xy)


def compose(a: Array, b: Array) -> Array:
    r"""The pose :math:`a \oplus b` [..., 3]: the pose ``b`` [..., 3], given in the frame of
    ``a`` [..., 3], in ``a``'s parent frame: :math:`(x_a + R(\theta_a) x_b,\
    \operatorname{wrap}(\theta_a + \theta_b))`. Dead reckoning is
    ``pose = compose(pose, increment)``; a sensor's pose is ``compose(robot, mount)``.

    Example:
      >>> compose(jnp.array([0.0, 0.0, jnp.pi / 2]), jnp.array([1.0, 0.0, 0.0]))  # (0, 1, pi/2)
    """
    a, b = jnp.asarray(a), jnp.asarray(b)
    c, s = jnp.cos(a[..., 2]), jnp.sin(a[..., 2])
    return jnp.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1],
                      a[..., 1] + s * b[..., 0] + c * b[..., 1],
                      wrap(a[..., 2] + b[..., 2])], -1)


def inverse(pose: Array) -> Array:
    r"""The inverse pose :math:`\ominus p` [..., 3], :math:`(-R(\theta)^T x,\ -\theta)`: the
    parent frame's origin seen from the frame of ``pose``; ``compose(p, inverse(p))`` is the
    identity.

    Example:
      >>> inverse(jnp.array([1.0, 0.0, jnp.pi / 2]))  # (0, 1, -pi/2)
    """
    pose = jnp.asarray(pose)
    c, s = jnp.cos(pose[..., 2]), jnp.sin(pose[..., 2])
    x, y = pose[..., 0], pose[..., 1]
    return jnp.stack([-(c * x + s * y), s * x - c * y, wrap(-pose[..., 2])], -1)


def relative(a: Array, b: Array) -> Array:
    r"""The pose ``b`` [..., 3] seen from the frame of ``a`` [..., 3]:
    :math:`\ominus a \oplus b = (R(\theta_a)^T (x_b - x_a),\ \operatorname{wrap}(\theta_b -
    \theta_a))`, e.g. an odometry increment between two poses.

    Example:
      >>> relative(jnp.array([1.0, 0.0, jnp.pi / 2]), jnp.array([1.0, 1.0, jnp.pi]))
      ... # (1, 0, pi/2)
    """
    a, b = jnp.asarray(a), jnp.asarray(b)
    c, s = jnp.cos(a[..., 2]), jnp.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    return jnp.stack([c * dx + s * dy, -s * dx + c * dy, wrap(b[..., 2] - a[..., 2])], -1)


def safe_sqrt(x: Array) -> Array:
    r""":math:`\sqrt{x}` for :math:`x \ge 0`, 0 for :math:`x \le 0`, with a zero (not NaN)
    gradient at 0 (see `safe_norm`): sums of squares that are 0 for degenerate inputs (a
    one-point laser segment's width and scatter) stay differentiable.

    Example:
      >>> jax.grad(safe_sqrt)(0.0)                    # 0.0
    """
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def safe_norm(v: Array) -> Array:
    r"""Euclidean norm over the last axis, :math:`\|v\|`, with a zero (not NaN) gradient at
    :math:`v = 0`.

    The plain ``sqrt`` has an infinite derivative at 0; in a closed loop an output a loss does
    not use still receives a zero cotangent, and 0 * inf would make the whole gradient NaN.

    Example:
      >>> jax.grad(lambda v: safe_norm(v))(jnp.zeros(2))  # (0, 0)
    """
    sq = jnp.sum(v * v, -1)
    pos = sq > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0)
