"""The same bad input is rejected the same way by both cores: the same error type and, where the check is
one both cores share, the same message (docs/core-contract.md "Errors"). Every check runs on shapes and
static arguments only, before any framework op (nothing is traced or synchronized to reject an input).

Each case runs once per framework; a case with a message expects exactly that message from both. Shape
checks of batches and network inputs name the field and the sizes in each core's own wording (the cores'
unit tests pin those), so those cases expect the error type and the field's name.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
import sf2_jax
import sf2_torch
import torch
from cross_bridge import jx, th
from sf2_common.config import SF2Config
from sf2_common.errors import ConfigError, ShapeError

CFG = SF2Config.small(3, 2, feature_size=8, hidden_sizes=(16,), q_hidden_size=16, zeta_hidden_sizes=(16,),
                      embedding_size=4)
B, D, A, H = 4, CFG.obs_size, CFG.action_size, CFG.zeta_hidden_sizes[-1]


class Core:
    """One framework's calls with the JAX core's argument order (`params` only where JAX takes it)."""

    def __init__(self, name: str):
        self.name = name
        self.core = sf2_jax if name == "jax" else sf2_torch
        self._nets: dict = {}

    def a(self, x):
        return jx(x, "float64") if self.name == "jax" else th(x, "float64")

    def nets(self, algo: str):
        """(networks, params) of `algo`; params is None for torch, whose modules hold them."""
        if algo not in self._nets:
            if self.name == "jax":
                nets = self.core.networks.make_networks(CFG, algo)
                self._nets[algo] = nets, self.core.networks.init_params(nets, jax.random.PRNGKey(0))
            else:
                self._nets[algo] = self.core.networks.make_networks(CFG, algo, dtype=torch.float64), None
        return self._nets[algo]

    def _with_params(self, module, name: str, algo: str, *args, **kwargs):
        nets, params = self.nets(algo)
        fn = getattr(module, name)
        return fn(nets, params, *args, **kwargs) if self.name == "jax" else fn(nets, *args, **kwargs)

    def loss(self, name: str, algo: str, *args, **kwargs):
        return self._with_params(self.core.losses, name, algo, *args, **kwargs)

    def net(self, name: str, algo: str, *args, **kwargs):
        return self._with_params(self.core.networks, name, algo, *args, **kwargs)

    def batch(self, **shapes):
        """A batch of B transitions; `shapes` replaces a field by zeros of that shape."""
        rng = np.random.default_rng(0)
        fields = dict(obs=(B, D), action=(B, A), reward=(B,), discount=(B,), next_obs=(B, D), truncation=(B,))
        fields.update(shapes)
        return self.core.losses.Batch(**{k: self.a(rng.normal(size=s)) for k, s in fields.items()})

    def ema(self, target: str, online: str, tau):
        nets, params = self.nets("td3")
        if self.name == "jax":
            return self.core.losses.ema_update(params[target], params[online], tau)
        return self.core.losses.ema_update(getattr(nets, target), getattr(nets, online), tau)


def _z(*shape):
    return np.zeros(shape)


def _mixture(c: Core, eps1=(B, D), k1=(B,)):
    def v(x, k):
        return x
    return c.core.losses.explicit_mixture_loss(v, c.a(_z(B, D)), c.a(_z(B, D)), c.a(_z(*eps1)), c.a(_z(B, D)),
                                               c.a(_z(*k1)), c.a(_z(B)), 0.5)


def _contracted(c: Core, c_shape):
    m, _ = c.net("contract", "td3", c.a(np.ones((B, CFG.feature_size))))
    return c.net("velocity_contracted", "td3", c.a(_z(B, D)), c.a(_z(B)), m, c.a(_z(*c_shape)))


# (id, call(core), error type, the message both cores give, or None with a text each message contains)
SAME_MESSAGE = [
    ("ema_update rate above 1", lambda c: c.ema("target_psi", "psi", 1.5), ConfigError,
     "tau=1.5 is invalid: must satisfy 0 <= tau <= 1"),
    ("ema_update rate below 0", lambda c: c.ema("target_zeta", "zeta", -0.1), ConfigError,
     "tau=-0.1 is invalid: must satisfy 0 <= tau <= 1"),
    ("sac_critic_loss on TD3 networks",
     lambda c: c.loss("sac_critic_loss", "td3", c.batch(), c.a(_z(B, A))), ConfigError,
     "SAC losses need networks built with algo='sac', found algo='td3'"),
    ("sac_actor_loss on TD3 networks",
     lambda c: c.loss("sac_actor_loss", "td3", c.batch(), c.a(_z(B, A))), ConfigError,
     "SAC losses need networks built with algo='sac', found algo='td3'"),
    ("sac_alpha_loss on TD3 networks",
     lambda c: c.loss("sac_alpha_loss", "td3", c.batch(), c.a(_z(B, A))), ConfigError,
     "SAC losses need networks built with algo='sac', found algo='td3'"),
    ("explicit_mixture_loss noise of another shape", lambda c: _mixture(c, eps1=(B, D - 1)), ShapeError,
     f"eps must have shape ({B}, {D}) (same as x), found ({B}, {D - 1})"),
    ("explicit_mixture_loss flow times of another shape", lambda c: _mixture(c, k1=(B + 1,)), ShapeError,
     f"k must have shape ({B},) ((B,)), found ({B + 1},)"),
    ("velocity_contracted with a misshaped c", lambda c: _contracted(c, (B, D - 1)), ShapeError,
     f"contracted (M, c) must have shapes ({B}, {D}, {H}) (B, D, H) and ({B}, {D}), found ({B}, {D}, {H}) "
     f"and ({B}, {D - 1})"),
    ("integrate with an unknown method",
     lambda c: c.core.ode.integrate(lambda x, k: x, c.a(_z(B, D)), c.a(np.ones(B)), 1, "rk4"), ConfigError,
     "method='rk4' is invalid: must be one of 'midpoint', 'euler'"),
    ("integrate in 0 steps",
     lambda c: c.core.ode.integrate(lambda x, k: x, c.a(_z(B, D)), c.a(np.ones(B)), 0), ConfigError,
     "steps=0 is invalid: must be an integer >= 1"),
    ("integrate to end times of another shape",
     lambda c: c.core.ode.integrate(lambda x, k: x, c.a(_z(B, D)), c.a(np.ones(B + 1)), 1), ShapeError,
     f"k_end must have shape ({B},) (one end time per sample of x0), found ({B + 1},)"),
    ("make_networks with an unknown algorithm", lambda c: c.core.networks.make_networks(CFG, "ppo"),
     ConfigError, "algo='ppo' is invalid: must be one of 'td3', 'sac'"),
    ("make_networks without an SF2Config", lambda c: c.core.networks.make_networks({"obs_size": 3}, "td3"),
     ConfigError, "cfg must be an SF2Config, found dict"),
    ("td3_action of SAC networks", lambda c: c.net("td3_action", "sac", c.a(_z(B, D))), ConfigError,
     "td3_action needs networks built with algo='td3', found algo='sac'"),
    ("sac_sample of TD3 networks", lambda c: c.net("sac_sample", "td3", c.a(_z(B, D)), c.a(_z(B, A))),
     ConfigError, "sac_sample needs networks built with algo='sac', found algo='td3'"),
    ("flow-time embedding of odd size", lambda c: c.core.networks.flow_time_embedding(c.a(_z(B)), 7),
     ConfigError, "embedding size=7 is invalid: must be an even integer >= 2"),
    ("flow-time embedding of size 0", lambda c: c.core.networks.flow_time_embedding(c.a(_z(B)), 0),
     ConfigError, "embedding size=0 is invalid: must be an even integer >= 2"),
]

NAMED_FIELD = [
    ("ema_update of another architecture", lambda c: c.ema("target_psi", "zeta", 0.1), ShapeError,
     "ema_update needs target and online of the same architecture"),
    ("flow_loss on observations of another size",
     lambda c: c.loss("flow_loss", "td3", c.batch(obs=(B, D + 1)), c.a(_z(B, A)), c.a(_z(B, D)), c.a(_z(B))),
     ShapeError, "batch.obs"),
    ("td3_critic_loss on a 3-D batch",
     lambda c: c.loss("td3_critic_loss", "td3", c.batch(obs=(2, B, D)), c.a(_z(B, A))), ShapeError,
     "a 2-D batch"),
    ("flow_loss with a misshaped next action",
     lambda c: c.loss("flow_loss", "td3", c.batch(), c.a(_z(B, A + 1)), c.a(_z(B, D)), c.a(_z(B))),
     ShapeError, "next_action"),
    ("flow_loss with noise of another batch size",
     lambda c: c.loss("flow_loss", "td3", c.batch(), c.a(_z(B, A)), c.a(_z(B + 1, D)), c.a(_z(B))),
     ShapeError, "eps"),
    ("flow_loss with flow times of another shape",
     lambda c: c.loss("flow_loss", "td3", c.batch(), c.a(_z(B, A)), c.a(_z(B, D)), c.a(_z(B, 1))),
     ShapeError, "flow_time"),
    ("td3_critic_loss with rewards of another shape",
     lambda c: c.loss("td3_critic_loss", "td3", c.batch(reward=(B + 1,)), c.a(_z(B, A))), ShapeError,
     "batch.reward"),
    ("td3_critic_loss with misshaped smoothing noise",
     lambda c: c.loss("td3_critic_loss", "td3", c.batch(), c.a(_z(B, A + 1))), ShapeError, "smoothing"),
    ("sac_actor_loss with misshaped noise",
     lambda c: c.loss("sac_actor_loss", "sac", c.batch(), c.a(_z(B, A - 1))), ShapeError, "noise"),
    ("psi of observations of another size",
     lambda c: c.net("psi", "td3", c.a(_z(B, D + 1)), c.a(_z(B, A))), ShapeError, "obs_size"),
    ("q_values of features of another size",
     lambda c: c.net("q_values", "td3", c.a(_z(B, CFG.feature_size - 1))), ShapeError, "feature_size"),
]

CORES = {name: Core(name) for name in ("jax", "torch")}


@pytest.mark.parametrize("framework", ["jax", "torch"])
@pytest.mark.parametrize("call,error,message", [c[1:] for c in SAME_MESSAGE],
                         ids=[c[0] for c in SAME_MESSAGE])
def test_same_message_in_both_cores(framework, call, error, message):
    with pytest.raises(error) as err:
        call(CORES[framework])
    assert str(err.value) == message


@pytest.mark.parametrize("framework", ["jax", "torch"])
@pytest.mark.parametrize("call,error,text", [c[1:] for c in NAMED_FIELD], ids=[c[0] for c in NAMED_FIELD])
def test_same_error_naming_the_field_in_both_cores(framework, call, error, text):
    with pytest.raises(error) as err:
        call(CORES[framework])
    assert text in str(err.value)


@pytest.mark.parametrize("framework", ["jax", "torch"])
def test_rates_and_flow_times_in_range_pass(framework):
    """The boundaries are valid: EMA rates 0 and 1, an embedding of size 2, one ODE step."""
    c = CORES[framework]
    c.ema("target_psi", "psi", 0.0)
    c.ema("target_psi", "psi", 1.0)
    c.core.networks.flow_time_embedding(c.a(_z(B)), 2)
    c.core.ode.integrate(lambda x, k: x, c.a(_z(B, D)), c.a(np.ones(B)), 1)


def test_jax_checks_run_on_static_shapes_under_jit():
    """JAX's checks need no concrete values: a jitted EMA with a traced rate is not checked (and not
    synchronized), and a bad static rate is refused as the function is traced."""
    nets, params = CORES["jax"].nets("td3")
    ema = jax.jit(sf2_jax.losses.ema_update)
    ema(params["target_q"], params["q"], 0.5)
    with pytest.raises(ConfigError, match=r"tau=2.0 is invalid"):
        jax.jit(lambda t, o: sf2_jax.losses.ema_update(t, o, 2.0))(params["target_q"], params["q"])
