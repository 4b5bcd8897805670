"""Benchmark: the person-following episode's laser sensors and the estimators fed by them,
vmapped over episodes (float32).

Usage: python benchmarks/following_sensors.py [--episodes 256] [--repeats 7] [--quick]

Per 10 Hz frame, every episode of `sims.following.episode` casts one 667-beam scan
(`sims.following.lidar.scan`) against 40 circles (16 people's leg sections + 24 furniture legs)
and 4 walls, then runs the leg detector (`jaxtrack.perception.legs.detect`, max_segments=48,
max_people=8, with the previous frame's legs for the motion cue). The scene here has the same
sizes: a 10 x 8 m room, six four-legged tables and chairs (3 cm legs), eight people with two
6 cm legs each, all placed at random per episode, and the laser at a random pose.

The estimator pieces, on the same scans' people (8 laser people, 8 RGB-D detections around
them): one step of the leg tracker (`jaxtrack.tracking.leg_tracker`, 16 leg tracks), one step
of seed 004's people PF (`people_pf.step`, 256 particles, 8 clusters), and one update of the
`pf` user estimator (the people PF plus the tracker over its clusters). The ratio column is
each piece's time over the sensing step's (laser scan + leg detection).

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
    def sensing_step(k, p, c, w, prev_xy, prev_mask):
        return detect(lidar.scan(k, p, c, w, cfg), prev_xy, prev_mask)

    sense_b = jax.jit(jax.vmap(sensing_step))
    est_calls, est_args = _estimators(prev, pose, n, dtype)
    calls = {
        "laser scan (cast + noise)": (scan, (keys, pose, circles, walls)),
        "leg detection": (detect_b, (ranges, prev_xy, prev.legs_mask)),
        "sensing step (scan + legs)": (sense_b, (keys, pose, circles, walls, prev_xy,
                                                 prev.legs_mask)),
        **{name: (f, est_args[name]) for name, f in est_calls.items()},
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
    rows = [_common.timing_row((name,), t, n, unit="episode") for name, (t, _) in out.items()]
    ref = rows[2]
    print(_common.table(["piece"], [r.vs(ref) for r in rows], ratio="vs sensing step"))
    print(f"mean per scan: {float(jnp.mean(jnp.sum(det.segments.mask, -1))):.1f} segments, "
          f"{float(jnp.mean(jnp.sum(det.legs_mask, -1))):.1f} leg candidates, "
          f"{float(jnp.mean(jnp.sum(det.people.mask, -1))):.1f} people")


def _estimators(det, pose, n, dtype):
    """The estimator pieces (jit(vmap)) and their arguments on the scans' detections."""
    import jax
    import jax.numpy as jnp

    from jaxtrack import geometry
    from jaxtrack.perception import sensing
    from jaxtrack.tracking import leg_tracker, people_pf, user

    key = jax.random.PRNGKey(7)
    laser_xy = jax.vmap(geometry.from_frame)(pose, det.people.xy)         # [N, 8, 2]
    laser_mask = det.people.mask
    rgbd_xy = laser_xy + 0.2 * jax.random.normal(key, laser_xy.shape, dtype)
    rgbd_mask = laser_mask
    colour = jax.random.uniform(key, laser_xy.shape[:2] + (3,), dtype)
    legs_xy = jax.vmap(geometry.from_frame)(pose, det.legs_xy)
    zero = jnp.zeros(n, dtype)
    sensed = sensing.Sensed(laser_xy, laser_mask, laser_xy, rgbd_xy, rgbd_mask, colour, pose,
                            zero, zero, det.points, det.valid, camera_pan=zero,
                            legs_xy=legs_xy, legs_mask=det.legs_mask)
    keys = jax.random.split(key, n)

    lt_cfg = leg_tracker.LegTrackerConfig()
    lt0 = jax.vmap(lambda _: leg_tracker.init(lt_cfg, dtype))(zero)

    def leg_step(state, z):
        return leg_tracker.step(lt_cfg, state, z.legs_xy, z.legs_mask, z.returns_xy,
                                z.returns_mask, z.odom_pose, dt=0.1, max_people=8)

    pf_cfg = user.CONFIGS["pf"]
    est = user.build(pf_cfg)
    params = est.params(dtype=dtype)
    prior = user.Prior(laser_xy[:, 0], pose, colour[:, 0])
    st0 = jax.vmap(lambda k, p: est.init(k, params, p))(keys, prior)
    pf_params = params.pf

    def pf_step(k, state, z):
        scans = (people_pf.Scan(z.laser_xy, z.laser_mask, jnp.asarray(pf_cfg.laser_fov)),
                 people_pf.Scan(z.rgbd_xy, z.rgbd_mask, jnp.asarray(pf_cfg.rgbd_fov),
                                z.camera_pan))
        return people_pf.step(k, state, scans, z.odom_pose, pf_params)

    calls = {
        "leg tracker step (16 legs)": jax.jit(jax.vmap(leg_step)),
        "people PF step (256 particles)": jax.jit(jax.vmap(pf_step)),
        "pf estimator update (PF + cluster tracker)": jax.jit(jax.vmap(
            lambda k, s, z: est.update(k, s, z, params))),
    }
    args = {
        "leg tracker step (16 legs)": (lt0, sensed),
        "people PF step (256 particles)": (keys, st0.pf, sensed),
        "pf estimator update (PF + cluster tracker)": (keys, st0, sensed),
    }
    return calls, args


if __name__ == "__main__":
    main()
