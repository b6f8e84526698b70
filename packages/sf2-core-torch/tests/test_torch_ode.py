from __future__ import annotations

import pytest
import torch
from sf2_torch import ConfigError, ShapeError, ode


def _linear_error(method: str, steps: int) -> float:
    a = torch.tensor([[-1.3], [0.7], [2.0]], dtype=torch.float64)
    x0 = torch.tensor([[1.0, -2.0], [0.5, 0.1], [3.0, 1.0]], dtype=torch.float64)
    k_end = torch.tensor([1.0, 0.4, 0.8], dtype=torch.float64)
    x = ode.integrate(lambda x, k: a * x, x0, k_end, steps, method)
    exact = x0 * torch.exp(a * k_end[:, None])
    return float((x - exact).abs().max())


@pytest.mark.parametrize("method, order", [("midpoint", 2), ("euler", 1)])
def test_order_against_closed_form(method, order):
    errors = [_linear_error(method, n) for n in (8, 16, 32)]
    for coarse, fine in zip(errors, errors[1:]):
        assert abs(coarse / fine - 2**order) < 0.25 * 2**order, errors


def test_one_step_formulas_and_time_argument():
    calls = []

    def field(x, k):
        calls.append(k.clone())
        return torch.stack([k, x[:, 0]], -1)

    x0 = torch.tensor([[1.0, 2.0]], dtype=torch.float64)
    k = torch.tensor([0.5], dtype=torch.float64)
    x = ode.integrate(field, x0, k, 1, "midpoint")
    h = 0.5
    x_mid = x0[0] + h / 2 * torch.tensor([0.0, 1.0], dtype=torch.float64)
    expected = x0[0] + h * torch.tensor([h / 2, x_mid[0]], dtype=torch.float64)
    torch.testing.assert_close(x[0], expected)
    assert [float(c) for c in calls] == [0.0, 0.25]
    calls.clear()
    ode.integrate(field, x0, k, 4, "euler")
    assert [float(c) for c in calls] == [0.0, 0.125, 0.25, 0.375]


def test_errors():
    x0 = torch.zeros(2, 3)
    with pytest.raises(ConfigError, match="'midpoint', 'euler'"):
        ode.integrate(lambda x, k: x, x0, torch.ones(2), 1, "rk4")
    with pytest.raises(ConfigError, match="steps=0"):
        ode.integrate(lambda x, k: x, x0, torch.ones(2), 0, "euler")
    with pytest.raises(ShapeError, match=r"\(2,\)"):
        ode.integrate(lambda x, k: x, x0, torch.ones(3), 1, "euler")
