"""Colour re-identification: the user's colour learnt from the looks of their settled track."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtrack.tracking import reid

TRACKS = np.array([[1.0, 0.0], [3.0, 0.0]])  # the user's track (slot 0) and someone else's
LIVE = np.ones(2, bool)
AT_USER = np.array([[1.05, 0.0]])            # one detection, informing slot 0


def _learn(cfg, state, colour, settled=True, std=0.05, xy=AT_USER, dtype=jnp.float32):
    return reid.learn(cfg, state, jnp.asarray(TRACKS, dtype), jnp.asarray(LIVE), 0,
                      jnp.asarray(settled), jnp.asarray(xy, dtype),
                      jnp.asarray(colour, dtype)[None], jnp.ones(1, bool), std)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_learnt_colour_is_the_mean_of_the_looks(dtype):
    rng = np.random.default_rng(0)
    true = np.array([0.6, 0.3, 0.2])
    looks = np.clip(true + 0.05 * rng.normal(size=(21, 3)), 0, 1)   # looks[0]: the shown one
    cfg = reid.ReidConfig()
    state = reid.init(cfg, jnp.asarray(looks[0], dtype), jnp.arange(2))
    learn = jax.jit(lambda s, c: _learn(cfg, s, c, dtype=dtype))
    for c in looks[1:]:
        state = learn(state, c)
    assert state.colour.dtype == dtype and state.looks.dtype == dtype
    tol = 1e-6 if dtype == jnp.float32 else 1e-12
    np.testing.assert_allclose(state.colour, looks.mean(0), atol=tol)
    assert float(state.looks) == 21.0
    # Averaging 21 looks lands nearer the true colour than the shown look (this draw).
    assert np.linalg.norm(looks.mean(0) - true) < np.linalg.norm(looks[0] - true)


def test_beyond_max_looks_the_mean_runs_with_weight_one_over_max_looks():
    cfg = reid.ReidConfig(max_looks=4, learn_gate=1e6)
    state = reid.init(cfg, jnp.array([0.5, 0.5, 0.5]), jnp.arange(2))
    c = 0.5
    for look in (0.6, 0.7, 0.4, 0.5, 0.9):
        state = _learn(cfg, state, jnp.full(3, look))
        n = min(float(state.looks), 4.0)
        c_ref = c + (look - c) / n
        assert float(state.colour[0]) == pytest.approx(c_ref, abs=1e-6)
        c = c_ref
    assert float(state.looks) == 4.0


@pytest.mark.parametrize("case", ["outside the gate", "not settled", "not informing",
                                  "learning off", "no colour shown"])
def test_looks_that_must_not_teach_leave_the_colour(case):
    cfg = reid.ReidConfig(max_looks=0) if case == "learning off" else reid.ReidConfig()
    shown = jnp.full(3, jnp.nan) if case == "no colour shown" else jnp.array([0.8, 0.2, 0.2])
    state = reid.init(cfg, shown, jnp.arange(2))
    look = jnp.array([0.2, 0.2, 0.8]) if case == "outside the gate" else jnp.array([0.82, 0.2, 0.2])
    xy = np.array([[2.0, 0.0]]) if case == "not informing" else AT_USER  # between both tracks
    new = _learn(cfg, state, look, settled=case != "not settled", xy=xy)
    np.testing.assert_array_equal(new.colour, state.colour)
    assert float(new.looks) == 1.0


def test_learning_turns_a_look_alike_beyond_the_shown_look_into_evidence_against():
    # The shown look is a noisy draw: here it lies 0.14 from the user's true colour, toward a
    # distractor 0.3 away, so the distractor reads as the user from that one look. After 30
    # looks of the user's settled track the learnt colour sits near the true one, and the
    # distractor's look is evidence against.
    rng = np.random.default_rng(1)
    user_colour = np.array([0.84, 0.30, 0.30])
    other = np.array([0.66, 0.04, 0.22])
    shown = user_colour + 0.45 * (other - user_colour)
    cfg = reid.ReidConfig()
    state = reid.init(cfg, jnp.asarray(shown, jnp.float32), jnp.arange(2))

    def other_evidence(s):
        return float(reid.evidence(cfg, s, jnp.asarray(TRACKS, jnp.float32), jnp.asarray(LIVE),
                                   jnp.asarray(AT_USER, jnp.float32),
                                   jnp.asarray(other, jnp.float32)[None], jnp.ones(1, bool),
                                   0.05)[0])

    assert other_evidence(state) > 0.0
    for c in np.clip(user_colour + 0.05 * rng.normal(size=(30, 3)), 0, 1):
        state = _learn(cfg, state, c)
    assert float(state.looks) > 20
    assert np.linalg.norm(np.asarray(state.colour) - user_colour) < 0.05
    assert other_evidence(state) < -2.0


def test_predictive_variance_widens_the_evidence_of_few_looks():
    # One shown look: a new look of the user is N(c_u, 2 sigma^2); many looks: sigma^2.
    cfg = reid.ReidConfig(evidence=(-1e9, 1e9))
    state = reid.init(cfg, jnp.array([0.5, 0.5, 0.5]), jnp.arange(2))
    look = jnp.array([[0.6, 0.5, 0.5]])
    sigma = 0.05
    for looks in (1.0, 50.0):
        s = state._replace(looks=jnp.asarray(looks))
        e = reid.evidence(cfg, s, jnp.asarray(TRACKS), jnp.asarray(LIVE), jnp.asarray(AT_USER),
                          look, jnp.ones(1, bool), sigma)
        v = sigma**2 * (1 + 1 / looks)
        ref = -0.5 * 0.01 / v - 1.5 * np.log(2 * np.pi * v)
        assert float(e[0]) == pytest.approx(ref, rel=1e-5)
        assert float(e[1]) == 0.0


def test_learning_is_differentiable_in_the_colour_std():
    cfg = reid.ReidConfig()
    state = reid.init(cfg, jnp.array([0.8, 0.2, 0.2]), jnp.arange(2))
    g = jax.grad(lambda s: _learn(cfg, state, jnp.array([0.82, 0.21, 0.2]), std=s).colour.sum()
                 + reid.evidence(cfg, state, jnp.asarray(TRACKS), jnp.asarray(LIVE),
                                 jnp.asarray(AT_USER), jnp.array([[0.8, 0.2, 0.2]]),
                                 jnp.ones(1, bool), s).sum())(0.05)
    assert np.isfinite(float(g))


def test_bad_learning_settings_are_refused():
    with pytest.raises(ValueError, match="max_looks"):
        reid.ReidConfig(max_looks=-1)
    with pytest.raises(ValueError, match="learn_gate"):
        reid.ReidConfig(learn_gate=0.0)


def test_no_detections_and_nan_colours_teach_nothing():
    cfg = reid.ReidConfig()
    state = reid.init(cfg, jnp.array([0.8, 0.2, 0.2]), jnp.arange(2))
    empty = reid.learn(cfg, state, jnp.asarray(TRACKS), jnp.asarray(LIVE), 0, jnp.asarray(True),
                       jnp.zeros((0, 2)), jnp.zeros((0, 3)), jnp.zeros(0, bool), 0.05)
    np.testing.assert_array_equal(empty.colour, state.colour)
    assert float(empty.looks) == 1.0
    nan = _learn(cfg, state, jnp.array([jnp.nan, 0.2, 0.2]))
    np.testing.assert_array_equal(nan.colour, state.colour)
    assert float(nan.looks) == 1.0
