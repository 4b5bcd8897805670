"""Test configuration: float64 on, and a persistent compilation cache inside the clone.

x64 is enabled so that references (filterpy, scipy, closed forms) can be matched to 1e-9;
float32 tests cast their inputs explicitly.
"""

from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_compilation_cache_dir", str(Path(__file__).resolve().parent.parent / ".jax_cache"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
