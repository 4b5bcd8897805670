"""Shared problems and jitted drivers for the Gaussian-filter tests.

JAX compiles are the cost of this suite, so the jitted drivers live at session scope (one
compile per input shape, reused by every test file), and the shared problems use one shape:
the 2-D constant-velocity model (n = 4) with position or range-bearing measurements (m = 2)
over T = 50 steps. Test data are generated with numpy (no JAX dispatch).
"""

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.filters import kalman
from jaxtrack.models import motion

jax.config.update("jax_enable_x64", True)  # also set by tests/conftest.py; kept for safety

CV_DT = 0.1
CV_Q = 0.5
CV_R = 0.05
CV_T = 50
RB_R_SHAPE = np.diag([1.0, 0.04])  # range-bearing noise shape, times r


# ---------------------------------------------------------------------------------------------
# Models (pure functions; also exposed as fixtures for the test modules)


def _cv_numpy(dt, q):
    """The CV model written out in numpy (data generation without JAX dispatch)."""
    F = np.kron(np.array([[1.0, dt], [0.0, 1.0]]), np.eye(2))
    Q = q * np.kron(np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]), np.eye(2))
    return F, Q


def random_spd(rng, n, scale=1.0, floor=0.1):
    """A random symmetric positive-definite [n, n] matrix, eigenvalues >= ``floor * scale``."""
    a = rng.standard_normal((n, n))
    return scale * (a @ a.T / n + floor * np.eye(n))


def simulate_linear(rng, F, Q, H, R, x0, T):
    """Draw a state path [T, n] and measurements [T, m] from the linear-Gaussian model."""
    lq, lr = np.linalg.cholesky(Q), np.linalg.cholesky(R)
    xs, zs, x = [], [], np.asarray(x0, float)
    for _ in range(T):
        x = F @ x + lq @ rng.standard_normal(len(x))
        xs.append(x)
        zs.append(H @ x + lr @ rng.standard_normal(H.shape[0]))
    return np.array(xs), np.array(zs)


def cv_matrices(log_q, log_r):
    """(F, Q, H, R) of the constant-velocity benchmark, differentiable in the log noises."""
    F, Q = motion.constant_velocity(CV_DT, jnp.exp(log_q))
    H = jnp.eye(2, 4, dtype=F.dtype)
    R = jnp.exp(log_r) * jnp.eye(2, dtype=F.dtype)
    return F, Q, H, R


def cv_range_bearing_model(log_q, log_r):
    """(F, Q, R) of the CV + range-bearing problem, differentiable in log q and log r.

    R = r diag(1, 0.04) (range in m^2, bearing in rad^2). Everything is built in the dtype of
    ``log_q``, so float32 in gives a float32 model.
    """
    dtype = jnp.result_type(log_q)
    F, Q = motion.constant_velocity(jnp.asarray(CV_DT, dtype), jnp.exp(log_q))
    return F, Q, jnp.exp(log_r) * jnp.asarray(RB_R_SHAPE, dtype)


@pytest.fixture(scope="session")
def random_spd_fn():
    return random_spd


@pytest.fixture(scope="session")
def cv_matrices_fn():
    return cv_matrices


@pytest.fixture(scope="session")
def cv_range_bearing_model_fn():
    return cv_range_bearing_model


# ---------------------------------------------------------------------------------------------
# Problems (numpy float64 data, session-scoped)


@pytest.fixture(scope="session")
def cv_problem():
    """A well-conditioned CV tracking problem: dict of float64 numpy arrays.

    Keys: F, Q, H, R, init_mean, init_cov, zs [T, 2], xs [T, 4], batch_zs [B, T, 2].
    """
    rng = np.random.default_rng(20240611)
    F, Q = _cv_numpy(CV_DT, CV_Q)
    H, R = np.eye(2, 4), CV_R * np.eye(2)
    x0 = np.array([1.0, -2.0, 0.8, 0.3])
    xs, zs = simulate_linear(rng, F, Q, H, R, x0, CV_T)
    batch = np.stack([simulate_linear(rng, F, Q, H, R, x0, CV_T)[1] for _ in range(5)])
    return dict(F=F, Q=Q, H=H, R=R, init_mean=x0 + 0.1, init_cov=np.diag([1.0, 1.0, 0.5, 0.5]),
                zs=zs, xs=xs, batch_zs=batch)


@pytest.fixture(scope="session")
def cv_range_bearing_problem():
    """A CV target seen by a range-bearing sensor at the origin (n = 4, m = 2, T = 50).

    The target stays in the first quadrant, away from the bearing cut at +-pi. Keys: log_q,
    log_r, init_mean, init_cov, zs [T, 2], batch_zs [B, T, 2] (numpy float64).
    """
    rng = np.random.default_rng(777)
    log_q, log_r = np.log(0.5), np.log(0.01)
    F, Q = _cv_numpy(CV_DT, 0.5)
    lq, lr = np.linalg.cholesky(Q), np.linalg.cholesky(0.01 * RB_R_SHAPE)

    def simulate():
        x, zs = np.array([6.0, 3.0, -0.5, 0.8]), []
        for _ in range(CV_T):
            x = F @ x + lq @ rng.standard_normal(4)
            z = np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])
            zs.append(z + lr @ rng.standard_normal(2))
        return np.array(zs)

    zs = simulate()
    batch = np.stack([simulate() for _ in range(4)])
    return dict(log_q=log_q, log_r=log_r, init_mean=np.array([6.1, 2.9, -0.4, 0.7]),
                init_cov=np.diag([0.1, 0.1, 0.1, 0.1]), zs=zs, batch_zs=batch)


@pytest.fixture(scope="session")
def badly_scaled_problem():
    """A 10,000-step CV problem in badly scaled units: ``(init, zs, F, Q, H, R)``, float64.

    The x axis is in units 1e4 times smaller than the y axis (state scales differ by 1e4), the
    process noise is tiny (q = 1e-6) and positions are measured precisely (R = 1e-6 I), so the
    covariances span ~15 orders of magnitude and position and velocity become almost perfectly
    correlated.
    """
    T = 10_000
    F, Q = _cv_numpy(0.1, 1e-6)
    scale = np.diag([1e4, 1.0, 1e4, 1.0])
    inv = np.diag(1.0 / np.diag(scale))
    F, Q, H, R = scale @ F @ inv, scale @ Q @ scale, np.eye(2, 4) @ inv, 1e-6 * np.eye(2)
    rng = np.random.default_rng(8)
    lq = np.linalg.cholesky(Q)
    x, zs = np.array([0.0, 0.0, 1e4, 0.5]), np.empty((T, 2))
    for t in range(T):
        x = F @ x + lq @ rng.standard_normal(4)
        zs[t] = H @ x + 1e-3 * rng.standard_normal(2)
    init = kalman.Gaussian(np.zeros(4), np.diag([1e8, 1.0, 1e8, 1.0]))
    return init, zs, F, Q, H, R


# ---------------------------------------------------------------------------------------------
# Jitted drivers shared across test modules


_KF_FILTER = jax.jit(kalman.filter, static_argnames=("time_varying",))


@pytest.fixture(scope="session")
def kf_filter_jit():
    """`kalman.filter` under `jax.jit` (``time_varying`` static); traceable (vmap, grad)."""
    return _KF_FILTER


@pytest.fixture(scope="session")
def kf_filter():
    """The jitted `kalman.filter`, returning numpy arrays.

    Tests index results a lot; indexing a jax array dispatches (and first compiles) a
    primitive per distinct index, which costs more than the filters themselves.
    """
    return lambda *args, **kwargs: jax.device_get(_KF_FILTER(*args, **kwargs))


# ---------------------------------------------------------------------------------------------
# Checks: scale-relative comparison (errors printed with JAXTRACK_REPORT_ERRORS=1), SPD


_ERRORS: dict[str, float] = {}


def scaled_error(actual, desired):
    """max |actual - desired| / max |desired|: the error relative to the array's scale."""
    actual, desired = np.asarray(actual, np.float64), np.asarray(desired, np.float64)
    scale = max(float(np.max(np.abs(desired))), np.finfo(np.float64).tiny)
    return float(np.max(np.abs(actual - desired))) / scale


@pytest.fixture
def assert_close(request):
    """``assert_close(actual, desired, tol, label)``: equal shapes, finite, and scale-relative
    error <= tol; the error is recorded under the test's id and ``label``."""

    def check(actual, desired, tol, label):
        assert np.shape(actual) == np.shape(desired), (label, np.shape(actual), np.shape(desired))
        assert np.all(np.isfinite(np.asarray(actual, np.float64))), f"{label}: not finite"
        err = scaled_error(actual, desired)
        key = f"{request.node.nodeid}::{label}"
        _ERRORS[key] = max(err, _ERRORS.get(key, 0.0))
        assert err <= tol, f"{label}: scale-relative error {err:.3g} > {tol:.1g}"

    return check


def pytest_terminal_summary(terminalreporter):
    if os.environ.get("JAXTRACK_REPORT_ERRORS") and _ERRORS:
        terminalreporter.section("measured scale-relative errors (tests/filters)")
        for key, err in sorted(_ERRORS.items()):
            terminalreporter.write_line(f"{err:10.3g}  {key}")


def assert_spd_sequence(covs):
    """Every covariance [T, n, n] finite, symmetric (1e-12 relative) and positive definite."""
    covs = np.asarray(covs, np.float64)
    assert np.all(np.isfinite(covs))
    scale = np.max(np.abs(covs), axis=(1, 2))
    asym = np.max(np.abs(covs - np.swapaxes(covs, 1, 2)), axis=(1, 2))
    assert np.all(asym <= 1e-12 * scale), f"max relative asymmetry {np.max(asym / scale):.3g}"
    min_eig = np.linalg.eigvalsh(covs)[:, 0]
    assert np.all(min_eig > 0), (
        f"{np.sum(min_eig <= 0)} of {len(covs)} covariances not positive definite, first at "
        f"step {np.argmax(min_eig <= 0)}, smallest eigenvalue {np.min(min_eig):.3g}")


@pytest.fixture(scope="session", name="assert_spd_sequence")
def assert_spd_sequence_fixture():
    return assert_spd_sequence
