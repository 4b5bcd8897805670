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
