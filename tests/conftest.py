"""Test configuration: float64 on, and, with ``JAXTRACK_TEST_CACHE=1``, a persistent
compilation cache inside the clone (for the test processes and the processes they start).

x64 is enabled so that references (filterpy, scipy, closed forms) can be matched to 1e-9;
float32 tests cast their inputs explicitly.

The cache is off by default: on a fresh clone (CI) it only saves the compilations that fresh
processes repeat, and writing it serialises every executable, which once aborted a test
process inside XLA:CPU's ``serialize`` (jaxlib 0.10.2, the IMM tracker's scan). Turn it on
for repeated local runs.
"""

import os
from pathlib import Path

import jax
import numpy as np
import pytest

CACHE = str(Path(__file__).resolve().parent.parent / ".jax_cache")

# XLA:CPU's fusion emitters (on by default in jaxlib 0.10) compile the scenes' closed loops
# slowly: the service rollout compiles in 23 s without them against 31 s with them, and runs
# as fast (2.2 s for 2 episodes x 240 frames either way). Set before any computation initialises
# the backend, and in the environment, so the processes the tests start (commands, notebook
# kernels, Monte-Carlo workers) inherit it. Only for the jaxlib the project pins (an unknown
# XLA flag aborts the process).
# Not LLVM's optimisation level 0 (``--xla_backend_optimization_level=0``), although it
# compiles the suite about 25 % faster: with it, XLA:CPU (jaxlib 0.10.2) computes a HOG
# descriptor of a jitted crop wrongly (0.396 instead of 0.476 for one SVM score; the crop and
# the descriptor jitted apart agree with eager execution), which a test caught.
_FAST_COMPILE = "--xla_cpu_use_fusion_emitters=false"
if jax.__version_info__[:2] == (0, 10) and "xla_cpu_use_fusion_emitters" not in os.environ.get(
        "XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_FAST_COMPILE}".strip()
jax.config.update("jax_enable_x64", True)
if os.environ.get("JAXTRACK_TEST_CACHE", "0") not in ("", "0"):
    jax.config.update("jax_compilation_cache_dir", CACHE)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    # The processes the tests start (scene runs in fresh processes, the command line, notebook
    # kernels) share the cache: several compile the same scene functions; the first pays.
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", CACHE)
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")

# py-motmetrics 1.4 (a reference of the metric tests) calls ``np.asfarray``, which NumPy 2
# removed, in ``iou_matrix`` and ``norm2squared_matrix``.
if not hasattr(np, "asfarray"):
    np.asfarray = lambda a, dtype=np.float64: np.asarray(a, dtype=dtype)


# The test modules that take longest (seconds summed over their tests, 2026-12-04), run first:
# `--dist loadscope` hands each worker the next module when it finishes one, so the longest
# first (with ``--no-loadscope-reorder``: xdist would order them by their number of tests)
# leaves the short ones to even out the workers' ends.
_LONGEST_FIRST = (
    "tests/test_notebooks.py", "tests/sims/test_reproducibility.py",
    "tests/sims/humanoid/test_episode.py", "tests/tracking/test_tracker.py",
    "tests/sims/service/test_episode.py", "tests/sims/following/test_episode.py",
    "tests/tracking/test_user.py", "tests/io/test_replay.py", "tests/association/test_jpda.py",
    "tests/sims/humanoid/test_floor_objects.py", "tests/control/test_potential_field.py",
    "tests/test_fuzz.py", "tests/filters/test_particle.py", "tests/tracking/test_tracker_imm.py",
    "tests/perception/test_voxel_grid.py", "tests/sims/humanoid/test_gradients.py",
    "tests/tracking/test_leg_tracker.py", "tests/perception/test_rgbd_people.py",
    "tests/filters/test_imm.py", "tests/sims/test_demo.py", "tests/io/test_rgbd_replay.py",
    "tests/sims/following/test_crowd.py", "tests/sims/humanoid/test_routes.py",
    "tests/test_package.py", "tests/sims/following/test_pedestrians.py",
    "tests/sims/humanoid/test_walkers.py", "tests/io/test_gt_topic.py",
    "tests/sims/humanoid/test_scene.py", "tests/sims/service/test_report.py",
)


def pytest_collection_modifyitems(config, items):
    rank = {path: i for i, path in enumerate(_LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))


@pytest.fixture(scope="session")
def following_recording():
    """A 3 s simulated person-following recording (4 people) and its bag records:
    ``(scene, Recording, (LaserScans, Odometry, PersonDetections))``, shared by the recording and
    replay tests (one compilation)."""
    from sims.following import recording, scene

    sc = scene.build(num_people=4)
    rec = recording.record(jax.random.PRNGKey(2), sc, distractors=3, duration=3.0)
    return sc, rec, recording.to_records(rec)


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's compiled programs after each test module. A worker that keeps every program
    of ~600 tests alive holds tens of thousands of JIT code mappings; near the kernel's
    ``vm.max_map_count`` (65530 here) XLA:CPU aborts inside a compile (seen twice, at 93 % of
    the suite, in a different test each time)."""
    yield
    jax.clear_caches()
    import gc

    gc.collect()
