"""Benchmark: the person-following episode's laser sensors, vmapped over episodes (float32).

Usage: python benchmarks/following_sensors.py [--episodes 256] [--repeats 7] [--quick]

Per 10 Hz frame, every episode of `sims.following.episode` casts one 667-beam scan
(`sims.following.lidar.scan`) against 40 circles (16 people's leg sections + 24 furniture legs)
and 4 walls, then runs the leg detector (`jaxtrack.perception.legs.detect`, max_segments=48,
max_people=8, with the previous frame's legs for the motion cue). The scene here has the same
sizes: a 10 x 8 m room, six four-legged tables and chairs (3 cm legs), eight people with two
6 cm legs each, all placed at random per episode, and the laser at a random pose.

Each piece is ``jit(vmap(f))`` over ``--episodes`` episodes; the table gives microseconds per
episode (call time / episodes) and the first call's extra time (tracing + compilation). Timing
is `benchmarks._common.time_interleaved` (median over clean repeats, round-robin) on all the
cores the process may use, as the episode runs. Measured runs:
``benchmarks/results/following_sensors.md``.
"""

from __future__ import annotations

import functools

import _common

PACKAGES = ["jaxtrack", "jax", "jaxlib", "numpy", "mujoco", "mujoco-mjx"]


def scenes(key, episodes, dtype):
    """Random scenes: (laser poses [N, 3], Circles [N, 40], Walls [N, 4])."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from sims.following import lidar

    k_tab, k_ppl, k_dir, k_pose = jax.random.split(key, 4)
    hw, hh = 5.0, 4.0
    corner = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    tables = jax.random.uniform(k_tab, (episodes, 6, 2), dtype, -1.0, 1.0) * jnp.array(
        [hw - 0.6, hh - 0.6], dtype)
    furn = (tables[:, :, None] + jnp.asarray(0.35 * corner, dtype)).reshape(episodes, 24, 2)
    people = jax.random.uniform(k_ppl, (episodes, 8, 2), dtype, -1.0, 1.0) * jnp.array(
        [hw - 0.5, hh - 0.5], dtype)
    heading = jax.random.uniform(k_dir, (episodes, 8), dtype, -np.pi, np.pi)
    side = jnp.stack([-jnp.sin(heading), jnp.cos(heading)], -1)
    feet = people[:, :, None] + 0.12 * jnp.stack([side, -side], 2)     # [N, 8, 2, 2]
    centers = jnp.concatenate([feet.reshape(episodes, 16, 2), furn], 1)
    radii = jnp.concatenate([jnp.full((episodes, 16), 0.06, dtype),
                             jnp.full((episodes, 24), 0.03, dtype)], 1)
    circles = lidar.Circles(centers, radii, jnp.ones((episodes, 40), bool))
    corners = np.array([[hw, -hh], [hw, hh], [-hw, hh], [-hw, -hh]])
    ends = np.stack([corners, np.roll(corners, -1, axis=0)], 1)
    walls = lidar.Walls(jnp.broadcast_to(jnp.asarray(ends, dtype), (episodes, 4, 2, 2)),
                        jnp.ones((episodes, 4), bool))
    pose = jax.random.uniform(k_pose, (episodes, 3), dtype, -1.0, 1.0) * jnp.array(
        [hw - 1.0, hh - 1.0, np.pi], dtype)
    return pose, circles, walls


def main(argv=None):
    ap = _common.parser(__doc__, timing=True)
    ap.sized("--episodes", 256, 8, "episodes vmapped")
    return _common.report(run, ap.parse_args(argv))


def run(args):
    import jax
    import jax.numpy as jnp

    from jaxtrack.perception import legs
    from sims.following import lidar

    dtype = jnp.float32
    n = args.episodes
    cfg = lidar.LaserConfig()
    angles = lidar.beam_angles(cfg, dtype)
    key = jax.random.PRNGKey(args.seed)
    pose, circles, walls = scenes(key, n, dtype)
    keys = jax.random.split(jax.random.PRNGKey(1 + args.seed), n)

    scan = jax.jit(jax.vmap(functools.partial(lidar.scan, cfg=cfg)))
    ranges = scan(keys, pose, circles, walls)
    params = legs.LegParams()

    def detect(r, prev_xy, prev_mask):
        return legs.detect(r, angles, params, max_segments=48, max_people=8,
                           prev_legs=(prev_xy, prev_mask))

    detect_b = jax.jit(jax.vmap(detect))
    prev = jax.jit(jax.vmap(lambda r: legs.detect(r, angles, params, max_segments=48,
                                                  max_people=8)))(ranges)
    # The motion cue sees last frame's legs a little displaced.
    prev_xy = prev.legs_xy + 0.02
    calls = {
        "laser scan (cast + noise)": (scan, (keys, pose, circles, walls)),
        "leg detection": (detect_b, (ranges, prev_xy, prev.legs_mask)),
    }
    header = _common.header(
        PACKAGES, f"{n} episodes vmapped, float32, {cfg.num_beams} beams, 40 circles + 4 "
        f"walls, max_segments=48, max_people=8")
    print("\n".join(header), flush=True)
    out = _common.time_interleaved(calls, repeats=args.repeats, min_repeat_s=args.min_repeat_s,
                                   compiled=tuple(calls))
    det = out["leg detection"][1]
    header.append(_common.load_line("end"))
    print("\n" + "\n".join(header) + "\n")
    print(_common.table(["piece"], [_common.timing_row((name,), t, n, unit="episode")
                                    for name, (t, _) in out.items()], ratio=None))
    print(f"mean per scan: {float(jnp.mean(jnp.sum(det.segments.mask, -1))):.1f} segments, "
          f"{float(jnp.mean(jnp.sum(det.legs_mask, -1))):.1f} leg candidates, "
          f"{float(jnp.mean(jnp.sum(det.people.mask, -1))):.1f} people")


if __name__ == "__main__":
    main()
