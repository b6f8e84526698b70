"""The MinAtar system's bad input is rejected the same way by both cores: the same error type and message
(docs/core-contract.md "Errors"), as tests/test_validation_cross.py does for the vector networks.

Shapes, dtypes and static arguments are checked before any framework op; action indices and flow times
are also checked by value where that costs no device synchronization (JAX outside a trace and on the CPU,
torch on the CPU and outside torch.compile): here, on the CPU. Each case runs once per framework.
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

SHAPE = (3, 2, 2)
CFG = SF2Config(obs_size=12, action_size=3, feature_size=4, hidden_sizes=(4,), q_hidden_size=4,
                zeta_hidden_sizes=(4,), embedding_size=2)
B, D, A, F, H = 4, CFG.obs_size, CFG.action_size, CFG.feature_size, CFG.zeta_hidden_sizes[-1]


class Core:
    """One framework's calls with the JAX core's argument order (`params` only where JAX takes it)."""

    def __init__(self, name: str):
        self.name = name
        self.core = sf2_jax if name == "jax" else sf2_torch
        self._nets: dict = {}

    def a(self, x, dtype="float64"):
        return jx(x, dtype) if self.name == "jax" else th(x, dtype)

    def nets(self, method: str):
        """(networks, params) of `method`; params is None for torch, whose modules hold them."""
        if method not in self._nets:
            nwi = self.core.networks_image
            if self.name == "jax":
                nets = nwi.make_image_networks(CFG, SHAPE, method)
                params = nwi.init_image_params(nets, jax.random.key(0))
            else:
                nets, params = nwi.make_image_networks(CFG, SHAPE, method, dtype=torch.float64), None
            self._nets[method] = nets, params
        return self._nets[method]

    def _call(self, module, fn: str, method: str, *args, **kwargs):
        nets, params = self.nets(method)
        fn = getattr(module, fn)
        return fn(nets, params, *args, **kwargs) if self.name == "jax" else fn(nets, *args, **kwargs)

    def net(self, fn: str, method: str, *args, **kwargs):
        return self._call(self.core.networks_image, fn, method, *args, **kwargs)

    def loss(self, fn: str, method: str, *args, **kwargs):
        return self._call(self.core.losses_onpolicy, fn, method, *args, **kwargs)

    def grids(self, *shape, dtype="float64"):
        shape = shape or (B, *SHAPE)
        return self.a((np.random.default_rng(0).uniform(size=shape) < 0.5), dtype)

    def actions(self, values=(0, 1, 2, 1), dtype="int64"):
        return self.a(np.asarray(values), dtype)

    def batch(self, **fields):
        """A batch of B transitions; `fields` replaces a field."""
        rng = np.random.default_rng(1)
        base = dict(obs=self.grids(), action=self.actions(), reward=self.a(rng.normal(size=B)),
                    discount=self.a(np.ones(B)), next_obs=self.grids(), truncation=self.a(np.zeros(B)))
        return self.core.losses.Batch(**{**base, **fields})

    def flow(self, method="sf2", batch=None, next_action=None, eps=None, k=None):
        size = D if method == "sf2" else self.core.networks_image.LATENT_SIZE
        fn = "image_flow_loss" if method == "sf2" else "latent_flow_loss"
        next_action = self.actions() if next_action is None else next_action
        return self.loss(fn, method, batch or self.batch(), next_action,
                         self.a(np.zeros((B, size))) if eps is None else eps,
                         self.a(np.full(B, 0.5)) if k is None else k)

    def rollout(self, fn: str, gamma=0.9, lam=0.95, **shapes):
        fields = dict(reward=(3, 2), discount=(3, 2), truncation=(3, 2), next_value=(3, 2))
        if fn == "gae":
            fields = dict(reward=(3, 2), discount=(3, 2), truncation=(3, 2), value=(3, 2), next_value=(3, 2))
        fields.update(shapes)
        args = [self.a(np.zeros(s)) for s in fields.values()]
        return getattr(self.core.losses_onpolicy, fn)(*args, gamma, lam)

    def ema(self, tau):
        nets, params = self.nets("sf2")
        if self.name == "jax":
            return self.core.losses.ema_update(params["target_psi"], params["psi"], tau)
        return self.core.losses.ema_update(nets.target_psi, nets.psi, tau)


def _z(*shape):
    return np.zeros(shape)


# (id, call(core), error type, the message both cores give)
SAME_MESSAGE = [
    ("make_image_networks with an unknown method",
     lambda c: c.core.networks_image.make_image_networks(CFG, SHAPE, "dqn"), ConfigError,
     "method='dqn' is invalid: must be one of 'ppo', 'ppo_q', 'sf2', 'sf2_ae'"),
    ("make_image_networks without an SF2Config",
     lambda c: c.core.networks_image.make_image_networks({"obs_size": 12}, SHAPE, "ppo"), ConfigError,
     "cfg must be an SF2Config, found dict"),
    ("make_image_networks with a grid of another size",
     lambda c: c.core.networks_image.make_image_networks(CFG, (3, 2, 3), "ppo"), ConfigError,
     "obs_shape=(3, 2, 3) has 18 cells, but cfg.obs_size = 12: they must be equal"),
    ("make_image_networks with a grid one cell high",
     lambda c: c.core.networks_image.make_image_networks(CFG, (1, 6, 2), "ppo"), ConfigError,
     "obs_shape=(1, 6, 2) is invalid: must be (height, width, channels), integers with height and width "
     ">= 2 and channels >= 1"),
    ("policy_logits of grids of another shape", lambda c: c.net("policy_logits", "ppo", c.grids(B, 2, 3, 2)),
     ShapeError, f"obs must have shape (B, 3, 2, 2) (a batch of grids, NHWC), found ({B}, 2, 3, 2)"),
    ("policy_logits of flattened grids", lambda c: c.net("policy_logits", "ppo", c.grids(B, D)),
     ShapeError, f"obs must have shape (B, 3, 2, 2) (a batch of grids, NHWC), found ({B}, {D})"),
    ("policy_logits of a bool grid", lambda c: c.net("policy_logits", "ppo", c.grids(dtype="bool")),
     ShapeError, "obs must be a floating-point array (the grid's cells as 0.0 and 1.0), found dtype bool"),
    ("autoencoder_loss of an integer grid",
     lambda c: c.loss("autoencoder_loss", "sf2_ae", c.grids(dtype="int64")), ShapeError,
     "obs must be a floating-point array (the grid's cells as 0.0 and 1.0), found dtype int64"),
    ("image_flow_loss with a bool next grid", lambda c: c.flow(batch=c.batch(next_obs=c.grids(dtype="bool"))),
     ShapeError, "batch.next_obs must be a floating-point array (the grid's cells as 0.0 and 1.0), found "
     "dtype bool"),
    ("image_flow_loss with next grids of another batch size",
     lambda c: c.flow(batch=c.batch(next_obs=c.grids(B + 1, *SHAPE))), ShapeError,
     f"batch.next_obs must have shape ({B}, 3, 2, 2) (a batch of grids, NHWC), found ({B + 1}, 3, 2, 2)"),
    ("q_critic_loss with an action index A", lambda c: c.loss("q_critic_loss", "sf2", c.grids(),
                                                              c.actions((0, 1, 2, 3)), c.a(_z(B))),
     ShapeError, "action must hold action indices in [0, 3), found values from 0 to 3"),
    ("q_critic_loss with a negative action", lambda c: c.loss("q_critic_loss", "ppo_q", c.grids(),
                                                              c.actions((0, -1, 2, 1)), c.a(_z(B))),
     ShapeError, "action must hold action indices in [0, 3), found values from -1 to 2"),
    ("psi of float actions", lambda c: c.net("psi", "sf2", c.grids(), c.actions(dtype="float64")),
     ShapeError, "action must be an integer array of action indices, found dtype float64"),
    ("ppo_policy_loss with one-hot actions",
     lambda c: c.loss("ppo_policy_loss", "ppo", c.grids(), c.a(np.eye(A)[[0, 1, 2, 1]], "int64"), c.a(_z(B)),
                      c.a(_z(B))),
     ShapeError, f"action must have shape ({B},) (one action index per sample), found ({B}, {A})"),
    ("image_flow_loss with a next action out of range", lambda c: c.flow(next_action=c.actions((0, 5, 1, 1))),
     ShapeError, "next_action must hold action indices in [0, 3), found values from 0 to 5"),
    ("image_flow_loss with a batch action out of range",
     lambda c: c.flow(batch=c.batch(action=c.actions((3, 0, 1, 1)))),
     ShapeError, "batch.action must hold action indices in [0, 3), found values from 0 to 3"),
    ("image_flow_loss with a flow time above 1", lambda c: c.flow(k=c.a([0.0, 0.5, 1.5, 1.0])),
     ShapeError, "flow_time must lie in [0, 1], found values from 0.0 to 1.5"),
    ("latent_flow_loss with a negative flow time", lambda c: c.flow("sf2_ae", k=c.a([0.25, -0.5, 0.5, 1.0])),
     ShapeError, "flow_time must lie in [0, 1], found values from -0.5 to 1.0"),
    ("image_flow_loss with flow times of another shape", lambda c: c.flow(k=c.a(_z(B, 1))), ShapeError,
     f"flow_time must have shape ({B},) (one flow time per sample), found ({B}, 1)"),
    ("image_flow_loss with rewards of another shape", lambda c: c.flow(batch=c.batch(reward=c.a(_z(B + 1)))),
     ShapeError, f"batch.reward must have shape ({B},) (one value per sample), found ({B + 1},)"),
    ("ema_update of the image targets, rate above 1", lambda c: c.ema(1.5), ConfigError,
     "tau=1.5 is invalid: must satisfy 0 <= tau <= 1"),
    ("ema_update of the image targets, rate below 0", lambda c: c.ema(-0.25), ConfigError,
     "tau=-0.25 is invalid: must satisfy 0 <= tau <= 1"),
    ("zeta_hidden with flow times of another batch",
     lambda c: c.net("zeta_hidden", "sf2", c.a(_z(B, D)), c.a(_z(B + 1))), ShapeError,
     f"x and flow_time must have shapes (B, {D}) and (B,), found ({B}, {D}) and ({B + 1},)"),
    ("velocity_contracted with a misshaped c",
     lambda c: c.net("velocity_contracted", "sf2", c.a(_z(B, D)), c.a(_z(B)), c.a(_z(B, H, 2)),
                     c.a(_z(B, 3))),
     ShapeError, f"contracted (M, c) must have shapes ({B}, {H}, 2) (B, H_zeta, C) and ({B}, 2) (B, C), "
     f"found ({B}, {H}, 2) and ({B}, 3)"),
    ("state_value of SF² networks", lambda c: c.net("state_value", "sf2", c.grids()), ConfigError,
     "state_value needs image networks built with method 'ppo', found method='sf2'"),
    ("image_flow_loss of SF² w AE networks",
     lambda c: c.loss("image_flow_loss", "sf2_ae", c.batch(), c.actions(), c.a(_z(B, D)), c.a(_z(B))),
     ConfigError,
     "image_flow_loss needs image networks built with method 'sf2', found method='sf2_ae'"),
    ("q_critic_loss of PPO (V) networks",
     lambda c: c.loss("q_critic_loss", "ppo", c.grids(), c.actions(), c.a(_z(B))), ConfigError,
     "q_critic_loss needs image networks built with method 'ppo_q' or 'sf2' or 'sf2_ae', found method='ppo'"),
    ("encode with SF² w/o AE networks", lambda c: c.net("encode", "sf2", c.grids()), ConfigError,
     "encode needs image networks built with method 'sf2_ae', found method='sf2'"),
    ("v_critic_loss with old values of another shape",
     lambda c: c.loss("v_critic_loss", "ppo", c.grids(), c.a(_z(B + 1)), c.a(_z(B))), ShapeError,
     f"old_value must have shape ({B},) (one value per sample), found ({B + 1},)"),
    ("v_critic_loss with a clip range of 0",
     lambda c: c.loss("v_critic_loss", "ppo", c.grids(), c.a(_z(B)), c.a(_z(B)), 0.0), ConfigError,
     "clip_eps=0.0 is invalid: must satisfy 0 < clip_eps <= 1"),
    ("ppo_policy_loss with a negative entropy weight",
     lambda c: c.loss("ppo_policy_loss", "ppo", c.grids(), c.actions(), c.a(_z(B)), c.a(_z(B)), 0.2, -0.01),
     ConfigError, "entropy_coef=-0.01 is invalid: must satisfy entropy_coef >= 0"),
    ("lambda_returns with γ above 1", lambda c: c.rollout("lambda_returns", gamma=1.5), ConfigError,
     "gamma=1.5 is invalid: must satisfy 0 <= gamma <= 1"),
    ("gae with a negative λ", lambda c: c.rollout("gae", lam=-0.1), ConfigError,
     "lam=-0.1 is invalid: must satisfy 0 <= lam <= 1"),
    ("lambda_returns of a 1-D rollout", lambda c: c.rollout("lambda_returns", reward=(3,)), ShapeError,
     "reward must have shape (T, N) (T steps of N environments), found (3,)"),
    ("gae with values of another shape", lambda c: c.rollout("gae", value=(3, 1)), ShapeError,
     "value must have shape (3, 2) (T, N), that of reward, found (3, 1)"),
]

NAMED_FIELD = [
    ("image_flow_loss with noise of another size",
     lambda c: c.flow(eps=c.a(_z(B, D - 1))), ShapeError, "eps"),
    ("latent_flow_loss with grid-sized noise", lambda c: c.flow("sf2_ae", eps=c.a(_z(B, D))), ShapeError,
     "eps"),
    ("q_head of features of another size", lambda c: c.net("q_head", "sf2", c.a(_z(B, F + 1))), ShapeError,
     "feature_size"),
    ("decode_logits of latents of another size", lambda c: c.net("decode_logits", "sf2_ae", c.a(_z(B, 8))),
     ShapeError, "latent size"),
    ("zeta of grids of another size", lambda c: c.net("zeta", "sf2", c.a(_z(B, D + 1)), c.a(_z(B))),
     ShapeError, "obs_size"),
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
def test_boundaries_pass(framework):
    """Actions 0 and A − 1, flow times 0 and 1, rates 0 and 1 are valid."""
    c = CORES[framework]
    c.flow(next_action=c.actions((0, 2, 2, 0)), k=c.a([0.0, 1.0, 0.5, 1.0]))
    c.flow("sf2_ae", batch=c.batch(action=c.actions((2, 2, 0, 0))), k=c.a([1.0, 0.0, 0.0, 1.0]))
    c.ema(0.0)
    c.ema(1.0)
    c.rollout("lambda_returns", gamma=1.0, lam=0.0)
    c.loss("ppo_policy_loss", "ppo", c.grids(), c.actions(), c.a(_z(B)), c.a(_z(B)), 1.0, 0.0)


def test_jax_value_checks_need_concrete_values():
    """Under `jax.jit` an action's or a flow time's value is not read (no synchronization): an out-of-range
    value passes the trace, while shapes and dtypes are still refused as it is traced."""
    c = CORES["jax"]
    nets, params = c.nets("sf2")
    loss = jax.jit(lambda b, a2, e, k: sf2_jax.losses_onpolicy.image_flow_loss(nets, params, b, a2, e, k))
    loss(c.batch(), c.actions((0, 1, 2, 7)), c.a(_z(B, D)), c.a([0.5, 2.0, 0.5, 0.5]))
    with pytest.raises(ShapeError, match="must be a floating-point array"):
        loss(c.batch(obs=c.grids(dtype="bool")), c.actions(), c.a(_z(B, D)), c.a(_z(B)))
