"""The four generative models of Appendix A.2–A.3, as pure JAX functions of (params, opt_state, key).

Every network is the core's `sf2_jax.networks.MLP` without LayerNorm (width 256, Table 2). Flow matching
uses the core's conventions: the path φ_k(ε, x) = k·x + (1 − k)·ε with target velocity x − ε, and samples
are `sf2_jax.ode.integrate` from ε ~ N(0, 1) over k ∈ [0, 1] in 100 Euler steps (Table 2).
- `fm_implicit`: flow matching on samples of the mixture (Section 2, "Flow Matching").
- `fm_explicit`: the explicit mixture objective of Appendix A.3, γ·L₁ + (1 − γ)·L₂ on samples of each
  component (`sf2_jax.losses.explicit_mixture_loss`), as SF²'s eq. (3) pairs every tuple with one
  transition term and one bootstrap term.
- `vae`: Gaussian encoder and decoder with a learned σ, standard-normal prior; loss = −log-likelihood + KL;
  samples include the decoder's noise.
- `gan`: non-saturating losses (Goodfellow et al. 2014), one discriminator then one generator update per
  step.
The VAE and the GAN learn from mixture samples (they have no explicit-mixture form); latent size 2; Adam
with Table 2's learning rate."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import optax
from sf2_common.errors import ConfigError

from sf2_jax.losses import explicit_mixture_loss
from sf2_jax.networks import MLP
from sf2_jax.ode import integrate

from .mixture import MEANS, STDS

__all__ = ["MODELS", "LABELS", "Settings", "Model", "make_model", "flow_matching_loss", "sample_mixture",
           "sample_component"]

MODELS = ("fm_explicit", "fm_implicit", "vae", "gan")
LABELS = {
    "fm_explicit": "Flow matching (explicit mixture)",
    "fm_implicit": "Flow matching (mixture samples)",
    "vae": "VAE",
    "gan": "GAN",
}
LATENT = 2
_MIN_STD = 1e-3


@dataclass(frozen=True)
class Settings:
    """Table 2 (Appendix E.2) unless noted."""

    steps: int = 1500
    batch_size: int = 32
    learning_rate: float = 1e-3
    ema_decay: float = 0.995
    eval_every: int = 200          # evaluations at 200, 400, …, and at the last step
    eval_samples: int = 4000
    integration_steps: int = 100   # Euler steps of flow sampling
    # one hidden layer of width 256: Table 2 gives the width only; with two layers the grid's flow sampling
    # alone costs ≈ 13 TFLOP, minutes on a 2-core CPU (results/two-gaussians/README.md compares both)
    hidden: tuple[int, ...] = (256,)

    def describe(self) -> str:
        return (f"{self.steps} steps, batch {self.batch_size} (the explicit objective draws a batch of each "
                f"component), Adam lr {self.learning_rate}, EMA decay {self.ema_decay} (evaluated: the EMA "
                f"parameters), evaluation every {self.eval_every} steps with {self.eval_samples} samples, "
                f"{self.integration_steps} Euler steps for flow sampling, MLPs with hidden widths "
                f"{self.hidden} and ReLU, latent size {LATENT} (VAE, GAN)")

    def eval_steps(self) -> tuple[int, ...]:
        """Training steps after which the EMA parameters are evaluated."""
        steps = list(range(self.eval_every, self.steps, self.eval_every))
        return tuple(steps + [self.steps])


# ------------------------------------------------------------------------------------------------- data
def sample_component(key, component: int, n: int, dtype=None):
    """n samples (n, 1) of p⁽¹⁾ (component 0) or p⁽²⁾ (component 1)."""
    dtype = dtype or jnp.result_type(float)
    return MEANS[component] + STDS[component] * jax.random.normal(key, (n, 1), dtype)


def sample_mixture(key, gamma, n: int, dtype=None):
    """n samples (n, 1) of γ·p⁽¹⁾ + (1 − γ)·p⁽²⁾ and their labels (n,) (True = first component)."""
    dtype = dtype or jnp.result_type(float)
    k_label, k_noise = jax.random.split(key)
    first = jax.random.uniform(k_label, (n,)) < gamma
    mean = jnp.where(first, MEANS[0], MEANS[1]).astype(dtype)
    std = jnp.where(first, STDS[0], STDS[1]).astype(dtype)
    return (mean + std * jax.random.normal(k_noise, (n,), dtype))[:, None], first


def flow_matching_loss(velocity_fn: Callable, x, eps, k):
    """mean_b‖v(φ_k(ε, x), k) − (x − ε)‖², φ_k(ε, x) = k·x + (1 − k)·ε (the implicit objective of A.3)."""
    x_k = k[:, None] * x + (1 - k[:, None]) * eps
    return jnp.mean(jnp.sum((velocity_fn(x_k, k) - (x - eps)) ** 2, axis=-1))


# ------------------------------------------------------------------------------------------------ models
@dataclass(frozen=True)
class Model:
    """init(key) → params; opt_init(params) → opt_state;
    update(params, opt_state, key, gamma) → (params, opt_state, loss);
    sample(params, key, n) → (n, 1) samples (the EMA'd params are passed here)."""

    name: str
    init: Callable[[Any], Any]
    opt_init: Callable[[Any], Any]
    update: Callable[..., tuple]
    sample: Callable[..., Any]


def _mlp(settings: Settings, out: int) -> MLP:
    return MLP(tuple(settings.hidden), out, use_layer_norm=False)


def _adam_step(opt, loss_fn):
    def step(params, opt_state, *args):
        loss, grads = jax.value_and_grad(loss_fn)(params, *args)
        updates, opt_state = opt.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, loss
    return step


def _flow(settings: Settings, explicit: bool) -> Model:
    net = _mlp(settings, 1)
    opt = optax.adam(settings.learning_rate)
    b = settings.batch_size

    def velocity(params):
        return lambda x, k: net.apply(params, jnp.concatenate([x, k[:, None].astype(x.dtype)], axis=-1))

    def init(key):
        return net.init(key, jnp.zeros((1, 2)))

    def loss_fn(params, key, gamma):
        v = velocity(params)
        if explicit:
            k1, k2, ke1, ke2, kk1, kk2 = jax.random.split(key, 6)
            x1, x2 = sample_component(k1, 0, b), sample_component(k2, 1, b)
            return explicit_mixture_loss(v, x1, x2, jax.random.normal(ke1, x1.shape, x1.dtype),
                                         jax.random.normal(ke2, x2.shape, x2.dtype),
                                         jax.random.uniform(kk1, (b,), x1.dtype),
                                         jax.random.uniform(kk2, (b,), x2.dtype), gamma)[0]
        kx, ke, kk = jax.random.split(key, 3)
        x, _ = sample_mixture(kx, gamma, b)
        return flow_matching_loss(v, x, jax.random.normal(ke, x.shape, x.dtype),
                                  jax.random.uniform(kk, (b,), x.dtype))

    def sample(params, key, n):
        eps = jax.random.normal(key, (n, 1), jnp.result_type(float))
        return integrate(velocity(params), eps, 1.0, settings.integration_steps, method="euler")

    name = "fm_explicit" if explicit else "fm_implicit"
    return Model(name, init, opt.init, _adam_step(opt, loss_fn), sample)


def _vae(settings: Settings) -> Model:
    enc, dec = _mlp(settings, 2 * LATENT), _mlp(settings, 2)
    opt = optax.adam(settings.learning_rate)
    b = settings.batch_size

    def decode(params, z):
        out = dec.apply(params["dec"], z)
        return out[:, :1], jax.nn.softplus(out[:, 1:]) + _MIN_STD

    def init(key):
        ke, kd = jax.random.split(key)
        return {"enc": enc.init(ke, jnp.zeros((1, 1))), "dec": dec.init(kd, jnp.zeros((1, LATENT)))}

    def loss_fn(params, key, gamma):
        kx, kz = jax.random.split(key)
        x, _ = sample_mixture(kx, gamma, b)
        h = enc.apply(params["enc"], x)
        mu_z, log_var_z = h[:, :LATENT], h[:, LATENT:]
        z = mu_z + jnp.exp(0.5 * log_var_z) * jax.random.normal(kz, mu_z.shape, mu_z.dtype)
        mu_x, std_x = decode(params, z)
        nll = jnp.sum(0.5 * ((x - mu_x) / std_x) ** 2 + jnp.log(std_x) + 0.5 * jnp.log(2 * jnp.pi), axis=-1)
        kl = 0.5 * jnp.sum(mu_z**2 + jnp.exp(log_var_z) - 1.0 - log_var_z, axis=-1)
        return jnp.mean(nll + kl)

    def sample(params, key, n):
        kz, kx = jax.random.split(key)
        mu_x, std_x = decode(params, jax.random.normal(kz, (n, LATENT), jnp.result_type(float)))
        return mu_x + std_x * jax.random.normal(kx, mu_x.shape, mu_x.dtype)

    return Model("vae", init, opt.init, _adam_step(opt, loss_fn), sample)


def _gan(settings: Settings) -> Model:
    gen, disc = _mlp(settings, 1), _mlp(settings, 1)
    opt = optax.adam(settings.learning_rate)
    b = settings.batch_size

    def init(key):
        kg, kd = jax.random.split(key)
        return {"gen": gen.init(kg, jnp.zeros((1, LATENT))), "disc": disc.init(kd, jnp.zeros((1, 1)))}

    def opt_init(params):
        return {"gen": opt.init(params["gen"]), "disc": opt.init(params["disc"])}

    def disc_loss(p_disc, p_gen, x, z):
        fake = jax.lax.stop_gradient(gen.apply(p_gen, z))
        return jnp.mean(jax.nn.softplus(-disc.apply(p_disc, x)) + jax.nn.softplus(disc.apply(p_disc, fake)))

    def gen_loss(p_gen, p_disc, z):
        return jnp.mean(jax.nn.softplus(-disc.apply(p_disc, gen.apply(p_gen, z))))

    def update(params, opt_state, key, gamma):
        kx, kz1, kz2 = jax.random.split(key, 3)
        x, _ = sample_mixture(kx, gamma, b)
        dtype = x.dtype
        p_disc, s_disc, _ = _adam_step(opt, disc_loss)(
            params["disc"], opt_state["disc"], params["gen"], x, jax.random.normal(kz1, (b, LATENT), dtype))
        p_gen, s_gen, loss = _adam_step(opt, gen_loss)(
            params["gen"], opt_state["gen"], p_disc, jax.random.normal(kz2, (b, LATENT), dtype))
        return {"gen": p_gen, "disc": p_disc}, {"gen": s_gen, "disc": s_disc}, loss

    def sample(params, key, n):
        return gen.apply(params["gen"], jax.random.normal(key, (n, LATENT), jnp.result_type(float)))

    return Model("gan", init, opt_init, update, sample)


def make_model(name: str, settings: Settings | None = None) -> Model:
    """One of `MODELS`."""
    settings = settings or Settings()
    if name == "fm_explicit":
        return _flow(settings, explicit=True)
    if name == "fm_implicit":
        return _flow(settings, explicit=False)
    if name == "vae":
        return _vae(settings)
    if name == "gan":
        return _gan(settings)
    raise ConfigError(f"model {name!r} is unknown: choose from {', '.join(MODELS)}")
