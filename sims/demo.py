"""``jaxtrack demo``: both MJX scenes' batched closed-loop Monte-Carlo evaluations, small.

The humanoid reach (seed 000: `sims.cli.run_humanoid_reach`, the 15 tasks) and the person
following in the shop (seeds 001-004: `sims.following.report.run_person_following`), each at a
size that compiles and runs in under a minute on two CPU cores; each prints a one-line header
with the sizes it runs at, then its table. ``jaxtrack run humanoid-reach`` and ``jaxtrack run
person-following`` run the same scenes at full size (64 episodes per task, 256 episodes) with
every option.
"""

from __future__ import annotations

import sys
import time
from typing import NamedTuple

__all__ = ["HumanoidSize", "FollowingSize", "run"]


class HumanoidSize(NamedTuple):
    """The humanoid reach at demo size: episodes per task (of the 15), frames per episode (at
    the seed's 4 Hz), depth image resolution, particles of the ``pf`` tracker."""

    episodes: int = 4
    frames: int = 200
    resolution: tuple[int, int] = (80, 60)
    particles: int = 128


class FollowingSize(NamedTuple):
    """The person following at demo size: episodes, seconds per episode, particles of the
    ``pf`` estimator, distractors besides the user, the estimator (`jaxtrack.tracking.user`
    name) and episodes per compiled batch."""

    episodes: int = 32
    duration: float = 60.0
    particles: int = 256
    people: int = 4
    estimator: str = "pf"
    batch_size: int = 32


def run(which: str = "all", humanoid: HumanoidSize = HumanoidSize(),
        following: FollowingSize = FollowingSize(), seed: int = 0, stream=sys.stdout,
        progress: bool = True) -> dict:
    """Run the scene demos: ``which`` is ``"all"``, ``"humanoid"`` or ``"following"``.

    Args:
      which: the scenes to run.
      humanoid, following: their sizes (defaults: the demo's; smaller ones make a quick check).
      seed: PRNG seed of both scenes.
      stream: where the headers and tables go.
      progress: progress bars on stderr.

    Returns:
      ``{"humanoid": run_humanoid_reach's result, "following": run_person_following's result,
      "seconds": wall time}`` (only the scenes run).

    Example:
      >>> out = run("following", following=FollowingSize(episodes=2, duration=5.0))
      >>> out["following"]["metrics"]["following_rms"].shape
      (2,)
    """
    if which not in ("all", "humanoid", "following"):
        raise ValueError(f"which must be 'all', 'humanoid' or 'following'; got {which!r}")
    from sims.cli import run_humanoid_reach
    from sims.following.report import run_person_following
    from sims.humanoid.episode import EpisodeConfig

    t0 = time.perf_counter()
    out = {}
    if which in ("all", "humanoid"):
        h = humanoid
        seconds = h.frames * EpisodeConfig.frame_dt
        print(f"== humanoid reach (seed 000): 15 tasks x {h.episodes} episodes x {h.frames} "
              f"frames ({seconds:.0f} s), pf tracker with {h.particles} particles, "
              f"{h.resolution[0]}x{h.resolution[1]} depth image ==", file=stream, flush=True)
        out["humanoid"] = run_humanoid_reach(h.episodes, "pf", seed=seed,
                                             particles=h.particles, frames=h.frames,
                                             resolution=tuple(h.resolution), stream=stream,
                                             progress=progress)
        if which == "all":
            print(file=stream)
    if which in ("all", "following"):
        f = following
        particles = f" ({f.particles} particles)" if f.estimator.startswith("pf") else ""
        print(f"== person following (seeds 001-004): {f.episodes} episodes x {f.duration:.0f} s "
              f"in the shop, {f.estimator} estimator{particles}, {f.people} distractors ==",
              file=stream, flush=True)
        out["following"] = run_person_following(
            f.episodes, f.estimator, "A", f.people, seed=seed, duration=f.duration,
            particles=f.particles, batch_size=f.batch_size, stream=stream, layout="shop",
            progress=progress)
    out["seconds"] = time.perf_counter() - t0
    print(f"demo finished in {out['seconds']:.0f} s, compilation included. Full size: "
          "jaxtrack run humanoid-reach (64 episodes per task), jaxtrack run person-following "
          "(256 episodes)", file=stream)
    return out
