"""Monte-Carlo evaluation: determinism across batch sizes and devices, resume, summaries."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack import montecarlo


def episode(key, params):
    """A small filtering-like episode: per-episode scalar metrics plus a trajectory."""
    k1, k2 = jax.random.split(key)
    walk = jnp.cumsum(jax.random.normal(k1, (8,)) * params["scale"])
    noise = jax.random.normal(k2, (8,)) * 0.1
    return {"final": walk[-1], "rmse": jnp.sqrt(jnp.mean(noise**2)), "trajectory": walk,
            "maybe_nan": jnp.where(walk[0] > 1.5, jnp.nan, walk[0])}


PARAMS = {"scale": jnp.float32(1.0)}


def test_results_do_not_depend_on_batch_size_and_summary_matches_numpy():
    key = jax.random.PRNGKey(3)
    a = montecarlo.evaluate(episode, PARAMS, key, 50, batch_size=7, progress=False)
    b = montecarlo.evaluate(episode, PARAMS, key, 50, batch_size=50, progress=False)
    for k in ("final", "rmse", "trajectory"):
        np.testing.assert_array_equal(a.metrics[k], b.metrics[k])
    assert a.metrics["trajectory"].shape == (50, 8)
    # Independent reference: the same episodes computed one by one.
    keys = jax.random.split(key, 50)
    ref = np.array([float(episode(k, PARAMS)["final"]) for k in keys[:5]])
    np.testing.assert_allclose(a.metrics["final"][:5], ref, rtol=1e-6)
    x = np.asarray(a.metrics["final"], np.float64)
    s = a.summary["final"]
    np.testing.assert_allclose([s.mean, s.std, s.median], [x.mean(), x.std(ddof=1),
                                                           np.median(x)], rtol=1e-6)
    np.testing.assert_allclose([s.q05, s.q95], np.quantile(x, [0.05, 0.95]), rtol=1e-6)
    half = 1.96 * x.std(ddof=1) / np.sqrt(50)
    np.testing.assert_allclose([s.ci_low, s.ci_high], [x.mean() - half, x.mean() + half],
                               rtol=1e-6)
    assert "trajectory" not in a.summary  # not a scalar per episode
    nan_s = a.summary["maybe_nan"]
    assert nan_s.num_nonfinite == int(np.sum(~np.isfinite(a.metrics["maybe_nan"])))
    assert nan_s.num_finite + nan_s.num_nonfinite == 50 and np.isfinite(nan_s.mean)


def test_interrupted_run_resumes_and_equals_uninterrupted(tmp_path):
    key = jax.random.PRNGKey(11)
    out = tmp_path / "mc.npz"
    calls = []

    def stop_after_two(done, total):
        calls.append(done)
        if len(calls) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        montecarlo.evaluate(episode, PARAMS, key, 23, batch_size=5, out=out, progress=False,
                            on_batch=stop_after_two, block=5)
    assert out.exists() and calls == [5, 10]
    resumed_calls = []
    res = montecarlo.evaluate(episode, PARAMS, key, 23, batch_size=5, out=out, progress=False,
                              on_batch=lambda d, t: resumed_calls.append(d), block=5)
    assert resumed_calls == [15, 20, 23]  # nothing recomputed
    full = montecarlo.evaluate(episode, PARAMS, key, 23, batch_size=5, progress=False, block=5)
    for k in ("final", "rmse", "trajectory"):
        np.testing.assert_array_equal(res.metrics[k], full.metrics[k])
    # A finished file is reused as is; another key is refused.
    again = montecarlo.evaluate(episode, PARAMS, key, 23, batch_size=5, out=out, progress=False,
                                block=5)
    np.testing.assert_array_equal(again.metrics["final"], full.metrics["final"])
    with pytest.raises(ValueError, match="different run"):
        montecarlo.evaluate(episode, PARAMS, jax.random.PRNGKey(12), 23, out=out,
                            progress=False)


def test_same_results_on_one_and_four_devices():
    script = textwrap.dedent("""
        import jax, jax.numpy as jnp, numpy as np, sys
        sys.path.insert(0, %r)
        from test_montecarlo import episode, PARAMS
        from jaxtrack import montecarlo
        assert len(jax.devices()) == 4, jax.devices()
        key = jax.random.PRNGKey(5)
        one = montecarlo.evaluate(episode, PARAMS, key, 30, batch_size=8,
                                  devices=jax.devices()[:1], progress=False)
        four = montecarlo.evaluate(episode, PARAMS, key, 30, batch_size=8, progress=False)
        assert four.num_devices == 4 and one.num_devices == 1
        for k in ("final", "rmse", "trajectory"):
            np.testing.assert_array_equal(one.metrics[k], four.metrics[k])
        print("OK", float(np.abs(one.metrics["final"] - four.metrics["final"]).max()))
    """) % str(Path(__file__).parent)
    env = dict(os.environ, JAX_PLATFORMS="cpu",
               XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} "
                         "--xla_force_host_platform_device_count=4")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.startswith("OK 0.0")


def test_progress_and_summary_are_printed(capsys):
    montecarlo.evaluate(episode, PARAMS, jax.random.PRNGKey(0), 12, batch_size=6, block=6)
    err = capsys.readouterr().err
    # The bar's last state (tqdm) counts all episodes and batches, with a rate.
    last = err.split("Monte-Carlo summary")[0].replace("\r", "\n").strip().splitlines()[-1]
    assert "12/12 episodes" in last and "episodes/s" in last and "batch 2/2" in last
    assert "Monte-Carlo summary over 12 episodes" in err and "95% CI" in err


def test_nothing_is_printed_without_progress(capsys):
    montecarlo.evaluate(episode, PARAMS, jax.random.PRNGKey(0), 12, batch_size=6,
                        progress=False)
    assert capsys.readouterr() == ("", "")


def test_warm_up_compiles_once_for_the_evaluation_that_follows():
    traces = []

    def counted(key, params):
        traces.append(1)  # runs at trace time only
        return episode(key, params)

    seconds = montecarlo.warm_up(counted, PARAMS, jax.random.PRNGKey(0), 12)
    assert seconds > 0 and len(traces) == 1
    res = montecarlo.evaluate(counted, PARAMS, jax.random.PRNGKey(5), 12, batch_size=6,
                              progress=False)
    assert len(traces) == 1
    ref = montecarlo.evaluate(episode, PARAMS, jax.random.PRNGKey(5), 12, batch_size=6,
                              progress=False)
    np.testing.assert_array_equal(res.metrics["final"], ref.metrics["final"])


def test_bad_arguments_raise():
    key = jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match="num_episodes"):
        montecarlo.evaluate(episode, PARAMS, key, 0, progress=False)
    with pytest.raises(ValueError, match="batch_size"):
        montecarlo.evaluate(episode, PARAMS, key, 4, batch_size=0, progress=False)
    with pytest.raises(ValueError, match="npz"):
        montecarlo.evaluate(episode, PARAMS, key, 4, out="results.csv", progress=False)
    with pytest.raises(TypeError, match="callable"):
        montecarlo.evaluate(None, PARAMS, key, 4, progress=False)
