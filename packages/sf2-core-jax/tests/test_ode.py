import numpy as np
import pytest
from sf2_jax import ConfigError, ShapeError
from sf2_jax.ode import integrate

RATE = np.array([0.7, -1.3])


def linear(x, k):
    assert k.shape == x.shape[:-1]
    return RATE * x


def error(steps, method):
    x0 = np.array([[1.0, 2.0], [-0.5, 0.3], [0.2, -1.0]])
    k_end = np.array([1.0, 0.4, 0.0])
    exact = x0 * np.exp(RATE * k_end[:, None])
    return np.max(np.abs(np.asarray(integrate(linear, x0, k_end, steps, method)) - exact))


def test_single_steps_are_the_textbook_formulas():
    x0, k = np.array([[1.5, -2.0]]), np.array([0.6])
    ah = RATE * k[0]
    np.testing.assert_allclose(integrate(linear, x0, k, 1, "euler"), x0 * (1 + ah), rtol=1e-14)
    np.testing.assert_allclose(integrate(linear, x0, k, 1, "midpoint"), x0 * (1 + ah + ah**2 / 2), rtol=1e-14)


@pytest.mark.parametrize("method, order", [("euler", 1), ("midpoint", 2)])
def test_convergence_order(method, order):
    errs = [error(n, method) for n in (8, 16, 32)]
    for coarse, fine in zip(errs, errs[1:]):
        assert abs(np.log2(coarse / fine) - order) < 0.15
    assert error(32, method) < (5e-2 if order == 1 else 1e-3)


def test_time_dependent_field_uses_step_times():
    # dx/dk = 2k: x(k) = x0 + k²; midpoint is exact for a linear-in-k field; Euler gives k²(1 − 1/T).
    def field(x, k):
        return np.broadcast_to(2 * np.asarray(k)[:, None], x.shape)

    x0, k = np.zeros((2, 1)), np.array([1.0, 0.5])
    np.testing.assert_allclose(integrate(field, x0, k, 3, "midpoint")[:, 0], k**2, rtol=1e-14)
    np.testing.assert_allclose(integrate(field, x0, k, 4, "euler")[:, 0], k**2 * (1 - 1 / 4), rtol=1e-14)


def test_errors():
    x0, k = np.zeros((2, 1)), np.ones(2)
    with pytest.raises(ConfigError, match="'midpoint', 'euler'"):
        integrate(linear, x0, k, 1, "rk4")
    with pytest.raises(ConfigError, match="steps"):
        integrate(linear, x0, k, 0, "euler")
    with pytest.raises(ShapeError, match="k_end"):
        integrate(linear, x0, np.ones(3), 1, "euler")
