"""Networks of SF²: ψ, ζ, twin Q heads, TD3 and SAC policies, observation normalizer, flow-time embedding.

Paper: Definition 3.1 (u = ζ(x, k)ᵀψ(s, a)), Appendix E (architectures);
docs/core-contract.md "Networks". JAX is functional: `make_networks(cfg, algo)` returns a `Networks`
container of flax.linen modules (no parameters), `init_params(nets, key)` returns the parameter dict of
canonical groups, and the helpers below (`psi`, `zeta`, `velocity`, ...) apply a group to inputs.

Each network's flax `params` collection uses the canonical layer names `dense_{i}` / `layer_norm_{i}`
(and `head_{0,1}` for Q), so it flattens directly to the canonical names of `sf2_jax.params`.
Every input is shape-checked on its static shape: a wrong observation or action size raises `ShapeError`
naming the expected and the found sizes before any framework op runs.
"""

from __future__ import annotations

import math
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct
from sf2_common.config import SF2Config
from sf2_common.embedding import EMBEDDING_K_GRID, embedding_turns
from sf2_common.errors import ConfigError, ShapeError

__all__ = [
    "ALGOS", "LAYER_NORM_EPS", "MLP", "TwinQ", "Networks", "make_networks", "init_params", "init_normalizer",
    "normalize", "update_normalizer", "flow_time_embedding", "psi", "zeta", "zeta_hidden",
    "zeta_last_layer", "velocity", "contract", "velocity_contracted", "q_values", "td3_action",
    "sac_distribution", "sac_sample", "sac_mode", "check_last",
]

ALGOS = ("td3", "sac")
LAYER_NORM_EPS = 1e-6
# LeCun-uniform: U(±√(3/fan_in)) for every Dense kernel; biases are zero (flax default).
LECUN_UNIFORM = nn.initializers.variance_scaling(1.0, "fan_in", "uniform")

Params = dict[str, Any]


# --------------------------------------------------------------------------------------------- modules
class MLP(nn.Module):
    """Hidden layers Dense → ReLU → LayerNorm(ε = 1e-6), then a last Dense (Appendix E).

    Submodules are `dense_0..dense_n` and `layer_norm_0..layer_norm_{n-1}` (n = len(hidden_sizes)).
    `hidden(x)` is everything before the last Dense (ζ's h in the fast path, docs/core-contract.md
    "Networks").
    """

    hidden_sizes: tuple[int, ...]
    out_size: int
    use_layer_norm: bool = True

    def setup(self):
        sizes = (*self.hidden_sizes, self.out_size)
        self.dense = [nn.Dense(n, kernel_init=LECUN_UNIFORM) for n in sizes]
        if self.use_layer_norm:
            # use_fast_variance=False: var = mean((x − mean)²), the formula torch uses too.
            self.layer_norm = [nn.LayerNorm(epsilon=LAYER_NORM_EPS, use_fast_variance=False)
                               for _ in self.hidden_sizes]

    def hidden(self, x):
        for i in range(len(self.hidden_sizes)):
            x = nn.relu(self.dense[i](x))
            if self.use_layer_norm:
                x = self.layer_norm[i](x)
        return x

    def __call__(self, x):
        return self.dense[-1](self.hidden(x))


class TwinQ(nn.Module):
    """Two independent Q heads `head_0`, `head_1`: Dense(F → hidden) → ReLU → Dense(→ 1), no LayerNorm."""

    hidden_size: int

    def setup(self):
        self.head_0 = MLP((self.hidden_size,), 1, use_layer_norm=False)
        self.head_1 = MLP((self.hidden_size,), 1, use_layer_norm=False)

    def __call__(self, features):
        return jnp.concatenate([self.head_0(features), self.head_1(features)], axis=-1)


@struct.dataclass
class Networks:
    """The config, the algorithm and the (parameter-free) flax modules of one SF² agent.

    A pytree with no leaves and hashable, so it can be passed to `jax.jit` either way.
    """

    cfg: SF2Config = struct.field(pytree_node=False)
    algo: str = struct.field(pytree_node=False)
    psi: MLP = struct.field(pytree_node=False)
    zeta: MLP = struct.field(pytree_node=False)
    q: TwinQ = struct.field(pytree_node=False)
    policy: MLP = struct.field(pytree_node=False)


def make_networks(cfg: SF2Config, algo: str) -> Networks:
    """Build the networks of one SF² agent.

    ψ: MLP(hidden_sizes → F) on [normalize(s), a]; ζ: MLP(zeta_hidden_sizes → F·D) on [x, embedding(k)];
    Q: twin heads on ψ; policy: MLP(hidden_sizes → A (TD3) or 2A (SAC)) on normalize(s) (Appendix E).

    Args:
      cfg: the `SF2Config`.
      algo: "td3" or "sac".

    Returns:
      The `Networks` (parameter-free flax modules: `init_params` makes the parameters).

    Raises:
      ConfigError: `cfg` is not an `SF2Config`, or `algo` is neither "td3" nor "sac".
    """
    if not isinstance(cfg, SF2Config):
        raise ConfigError(f"cfg must be an SF2Config, found {type(cfg).__name__}")
    if algo not in ALGOS:
        raise ConfigError(f"algo={algo!r} is invalid: must be one of {', '.join(repr(a) for a in ALGOS)}")
    ln = cfg.layer_norm
    policy_out = cfg.action_size if algo == "td3" else 2 * cfg.action_size
    return Networks(
        cfg=cfg,
        algo=algo,
        psi=MLP(cfg.hidden_sizes, cfg.feature_size, use_layer_norm=ln),
        zeta=MLP(cfg.zeta_hidden_sizes, cfg.feature_size * cfg.obs_size, use_layer_norm=ln),
        q=TwinQ(cfg.q_hidden_size),
        policy=MLP(cfg.hidden_sizes, policy_out, use_layer_norm=ln),
    )


def init_normalizer(size: int, dtype=None) -> Params:
    """The initial running observation statistics.

    Args:
      size: D.
      dtype: of the statistics (default: JAX's default float type).

    Returns:
      {"count": 0, "mean": zeros (D,), "summed_var": zeros (D,), "std": ones (D,)}.
    """
    dtype = _default_dtype(dtype)
    return {
        "count": jnp.zeros((), dtype),
        "mean": jnp.zeros((size,), dtype),
        "summed_var": jnp.zeros((size,), dtype),
        "std": jnp.ones((size,), dtype),
    }


def init_params(nets: Networks, key: jax.Array, dtype=None) -> Params:
    """Initialise the parameters of every canonical group.

    The groups: `obs_norm`, `psi`, `zeta`, `q`, `policy`, `target_psi`, `target_zeta`, `target_q`, and
    `target_policy` (TD3) or `log_alpha` (SAC, = cfg.init_log_alpha); targets are copies of the online
    networks; kernels LeCun-uniform, biases zero.

    Args:
      nets: the `Networks`.
      key: a PRNG key.
      dtype: of every parameter (default: JAX's default float type, float64 under `jax_enable_x64`).

    Returns:
      {group: nested params} (`sf2_jax.params` flattens it to canonical names).
    """
    cfg = nets.cfg
    dtype = _default_dtype(dtype)
    D, A, E = cfg.obs_size, cfg.action_size, cfg.embedding_size
    k_psi, k_zeta, k_q, k_policy = jax.random.split(key, 4)
    f32 = jnp.float32

    def cast(tree):
        return jax.tree_util.tree_map(lambda v: jnp.asarray(v, dtype), tree)

    online = {
        "psi": nets.psi.init(k_psi, jnp.zeros((1, D + A), f32))["params"],
        "zeta": nets.zeta.init(k_zeta, jnp.zeros((1, D + E), f32))["params"],
        "q": nets.q.init(k_q, jnp.zeros((1, cfg.feature_size), f32))["params"],
        "policy": nets.policy.init(k_policy, jnp.zeros((1, D), f32))["params"],
    }
    online = cast(online)
    params = {"obs_norm": init_normalizer(D, dtype), **online}
    copy = lambda tree: jax.tree_util.tree_map(jnp.copy, tree)  # noqa: E731
    for name in ("psi", "zeta", "q"):
        params[f"target_{name}"] = copy(online[name])
    if nets.algo == "td3":
        params["target_policy"] = copy(online["policy"])
    else:
        params["log_alpha"] = jnp.asarray(cfg.init_log_alpha, dtype)
    return params


def _default_dtype(dtype):
    return jnp.dtype(jnp.result_type(float) if dtype is None else dtype)


# ------------------------------------------------------------------------------------------ shape checks
def check_last(name: str, x, expected: int, what: str) -> None:
    """Check the last dimension of an input on its static shape (free under `jax.jit`).

    Args:
      name: the argument's name, for the message.
      x: the array.
      expected: its last dimension.
      what: the config field `expected` is, for the message ("obs_size", "action_size", ...).

    Raises:
      ShapeError: `x` is a scalar or its last dimension differs, naming both sizes.
    """
    shape = jnp.shape(x)
    if len(shape) == 0 or shape[-1] != expected:
        found = shape[-1] if len(shape) else "a scalar"
        raise ShapeError(f"{name}: expected last dimension {expected} ({what}), found {found} "
                         f"(shape {tuple(shape)})")


def _check_batch_dims(name: str, x, batch_shape: tuple, ref: str):
    shape = tuple(jnp.shape(x))
    if shape != tuple(batch_shape):
        raise ShapeError(f"{name}: expected shape {tuple(batch_shape)} (the batch shape of {ref}), "
                         f"found {shape}")


def _check_leading(name: str, x, batch_shape: tuple, ref: str):
    shape = tuple(jnp.shape(x))
    if shape[:-1] != tuple(batch_shape):
        raise ShapeError(f"{name}: expected batch shape {tuple(batch_shape)} (that of {ref}), "
                         f"found {shape[:-1]} (shape {shape})")


def _group(nets: Networks, params: Params, name: str, target: bool) -> Params:
    key = f"target_{name}" if target else name
    if key not in params:
        raise ConfigError(f"params has no group {key!r} (algo {nets.algo!r}); groups: {sorted(params)}")
    return params[key]


# ------------------------------------------------------------------------------------------ normalizer
def normalize(obs, stats: Params):
    """Normalize observations with running statistics (Brax `running_statistics`): (obs − mean) / std.

    Args:
      obs: (..., D).
      stats: `init_normalizer`'s mapping (the `obs_norm` group).

    Returns:
      (..., D).

    Raises:
      ShapeError: `obs` of another last dimension.
    """
    check_last("obs", obs, jnp.shape(stats["mean"])[-1], "obs_size")
    return (obs - stats["mean"]) / stats["std"]


def update_normalizer(stats: Params, obs_batch, cfg: SF2Config) -> Params:
    """Brax's running-statistics update with a batch of observations (Welford).

    std = clip(√(summed_var / count), normalizer_std_min, normalizer_std_max); every leading dimension of
    `obs_batch` is a sample.

    Args:
      stats: the current statistics (`init_normalizer`'s mapping).
      obs_batch: (..., D).
      cfg: the `SF2Config` (D and the std clip).

    Returns:
      The new statistics.

    Raises:
      ShapeError: `obs_batch` of another last dimension.
    """
    check_last("obs_batch", obs_batch, cfg.obs_size, "obs_size")
    batch = jnp.reshape(obs_batch, (-1, cfg.obs_size))
    count = stats["count"] + batch.shape[0]
    diff_to_old_mean = batch - stats["mean"]
    mean = stats["mean"] + jnp.sum(diff_to_old_mean, axis=0) / count
    diff_to_new_mean = batch - mean
    summed_var = stats["summed_var"] + jnp.sum(diff_to_old_mean * diff_to_new_mean, axis=0)
    std = jnp.clip(jnp.sqrt(summed_var / count), cfg.normalizer_std_min, cfg.normalizer_std_max)
    return {"count": count, "mean": mean, "summed_var": summed_var, "std": std}


# ------------------------------------------------------------------------------------------ ψ and ζ
# Exact phase reduction of the flow-time embedding: the tables come from sf2_common.embedding.


def flow_time_embedding(k, size: int):
    """The sinusoidal embedding of the flow time k (the authors' `scalar_positional_embedding`).

    out[2i] = sin(10⁴·k·ω_i), out[2i+1] = cos(10⁴·k·ω_i), ω_i = exp(−2i·ln(10⁴)/size). The phase is reduced
    exactly before sin/cos (docs/parity.md, "flow-time embedding"): with G_i = 10⁴·ω_i / 2π turns,
    k = k_hi + k_lo (k_hi = round(4096·k)/4096) and G = G_hi + G_lo (G_hi on 11 bits),
    t = (k_hi·G_hi − round(k_hi·G_hi)) + (k_hi·G_lo + k_lo·G), phase 2π·t; k_hi·G_hi and its fractional part
    are exact in float32, so the float32 phase is accurate to ~1e-6 rad instead of one ulp of a phase
    near 10⁴.

    Args:
      k: the flow time, any shape (...).
      size: E, an even integer >= 2.

    Returns:
      (..., size).

    Raises:
      ConfigError: `size` odd or < 2.
    """
    if size < 2 or size % 2:
        raise ConfigError(f"embedding size={size!r} is invalid: must be an even integer >= 2")
    k = jnp.asarray(k)
    if not jnp.issubdtype(k.dtype, jnp.floating):
        k = k.astype(jnp.result_type(float))
    turns, hi, lo = (jnp.asarray(v, dtype=k.dtype) for v in embedding_turns(size))
    k_hi = jnp.round(k * EMBEDDING_K_GRID) / EMBEDDING_K_GRID
    k_lo, k_hi = (k - k_hi)[..., None], k_hi[..., None]
    t_hi = k_hi * hi
    t = (t_hi - jnp.round(t_hi)) + (k_hi * lo + k_lo * turns)
    arg = t * jnp.asarray(2.0 * math.pi, dtype=k.dtype)
    return jnp.stack([jnp.sin(arg), jnp.cos(arg)], axis=-1).reshape(*k.shape, size)


def psi(nets: Networks, params: Params, obs, action, target: bool = False):
    """ψ(s, a), the time-invariant state-action feature (Definition 3.1), on [normalize(s), a].

    Args:
      nets: the `Networks`.
      params: the parameters (`init_params`).
      obs: raw observations (B, D) (normalized here with the `obs_norm` statistics).
      action: (B, A).
      target: the target network instead of the online one.

    Returns:
      (B, F).

    Raises:
      ShapeError: `obs` or `action` of another last dimension.
    """
    cfg = nets.cfg
    check_last("obs", obs, cfg.obs_size, "obs_size")
    check_last("action", action, cfg.action_size, "action_size")
    x = jnp.concatenate([normalize(obs, params["obs_norm"]), action], axis=-1)
    return nets.psi.apply({"params": _group(nets, params, "psi", target)}, x)


def _zeta_input(nets: Networks, x, k):
    cfg = nets.cfg
    check_last("x", x, cfg.obs_size, "obs_size")
    x, k = jnp.asarray(x), jnp.asarray(k)
    if k.ndim == 0:
        k = jnp.broadcast_to(k, x.shape[:-1])
    _check_batch_dims("flow_time", k, x.shape[:-1], "x")
    dtype = jnp.result_type(x.dtype, k.dtype, float)
    embedding = flow_time_embedding(k.astype(dtype), cfg.embedding_size)
    return jnp.concatenate([x.astype(dtype), embedding], axis=-1)


def zeta(nets: Networks, params: Params, x, k, target: bool = False):
    """ζ(x, k), the time-conditioned matrix field, on [x, embedding(k)].

    Entry (d, f) of the (D, F) matrix is ζ's output d·F + f (row-major).

    Args:
      nets: the `Networks`.
      params: the parameters (`init_params`).
      x: (B, D), in normalized-observation space.
      k: the flow time (B,) (or a scalar).
      target: the target network instead of the online one.

    Returns:
      (B, D, F).

    Raises:
      ShapeError: `x` of another last dimension, or `k` of another batch shape.
    """
    cfg = nets.cfg
    out = nets.zeta.apply({"params": _group(nets, params, "zeta", target)}, _zeta_input(nets, x, k))
    return out.reshape(*out.shape[:-1], cfg.obs_size, cfg.feature_size)


def zeta_hidden(nets: Networks, params: Params, x, k, target: bool = False):
    """h(x, k): ζ's MLP up to, not including, its last Dense (the fast path's h).

    Args:
      nets: the `Networks`.
      params: the parameters (`init_params`).
      x: (B, D).
      k: the flow time (B,) (or a scalar).
      target: the target network instead of the online one.

    Returns:
      (B, H).

    Raises:
      ShapeError: `x` of another last dimension, or `k` of another batch shape.
    """
    return nets.zeta.apply({"params": _group(nets, params, "zeta", target)}, _zeta_input(nets, x, k),
                           method=MLP.hidden)


def zeta_last_layer(nets: Networks, params: Params, target: bool = False):
    """ζ's last Dense layer in canonical layout.

    Args:
      nets: the `Networks`.
      params: the parameters (`init_params`).
      target: the target network instead of the online one.

    Returns:
      (kernel W (H, F·D), bias b (F·D,)).
    """
    last = _group(nets, params, "zeta", target)[f"dense_{len(nets.cfg.zeta_hidden_sizes)}"]
    return last["kernel"], last["bias"]


def velocity(nets: Networks, params: Params, x, k, features, target: bool = False):
    """The plain velocity u = ζ(x, k)ᵀψ: u_d = Σ_f ζ(x, k)_{d f} ψ_f (Definition 3.1); materializes ζ.

    Args:
      nets: the `Networks`.
      params: the parameters (`init_params`).
      x: (B, D).
      k: the flow time (B,).
      features: ψ (B, F).
      target: the target network instead of the online one.

    Returns:
      (B, D).

    Raises:
      ShapeError: an input of another shape.
    """
    check_last("features", features, nets.cfg.feature_size, "feature_size")
    return jnp.einsum("...df,...f->...d", zeta(nets, params, x, k, target), features)


def contract(nets: Networks, params: Params, features, target: bool = False):
    """Contract ζ's last layer with ψ once, for the fast path (docs/core-contract.md "Networks").

    M[b, d, h] = Σ_f W[h, d·F + f] ψ[b, f] and c[b, d] = Σ_f b[d·F + f] ψ[b, f]; compute once per (ζ, ψ) and
    reuse for every evaluation at new (x, k). The kernel is re-laid (D, H, F) once per contraction (the stored
    parameter keeps its canonical layout), so one GEMM emits M as (B, D·H) and every `velocity_contracted`
    reduces over M's minor axis (docs/decisions/flow-loss-layout.md).

    Args:
      nets: the `Networks`.
      params: the parameters (`init_params`).
      features: ψ (B, F).
      target: the target network instead of the online one.

    Returns:
      (M (B, D, H), c (B, D)).

    Raises:
      ShapeError: `features` of another last dimension.
    """
    cfg = nets.cfg
    check_last("features", features, cfg.feature_size, "feature_size")
    W, b = zeta_last_layer(nets, params, target)
    W_t = jnp.transpose(W.reshape(W.shape[0], cfg.obs_size, cfg.feature_size), (1, 0, 2))  # (D, H, F)
    b = b.reshape(cfg.obs_size, cfg.feature_size)
    return jnp.einsum("bf,dhf->bdh", features, W_t), jnp.einsum("bf,df->bd", features, b)


def velocity_contracted(nets: Networks, params: Params, x, k, M, c, target: bool = False):
    """The fast velocity u = einsum('bh,bdh->bd', h(x, k), M) + c, equal to `velocity`.

    u is linear in ζ's last layer, so (M, c) from `contract` give it without building ζ (B, D, F).

    Args:
      nets: the `Networks`.
      params: the parameters (`init_params`).
      x: (B, D).
      k: the flow time (B,).
      M: (B, D, H) from `contract`.
      c: (B, D) from `contract`.
      target: the target network instead of the online one.

    Returns:
      (B, D).

    Raises:
      ShapeError: `x`, `k`, M or c of another shape.
    """
    h = zeta_hidden(nets, params, x, k, target)
    x_shape = tuple(jnp.shape(x))
    if tuple(jnp.shape(M)) != (*x_shape, jnp.shape(h)[-1]) or tuple(jnp.shape(c)) != x_shape:
        raise ShapeError(
            f"contracted (M, c) must have shapes {(*x_shape, jnp.shape(h)[-1])} (B, D, H) and {x_shape}, "
            f"found {tuple(jnp.shape(M))} and {tuple(jnp.shape(c))}"
        )
    return jnp.einsum("bh,bdh->bd", h, M) + c


# ------------------------------------------------------------------------------------------ Q and policies
def q_values(nets: Networks, params: Params, features, target: bool = False):
    """The twin Q heads on features (Appendix D): column j is head j.

    Args:
      nets: the `Networks`.
      params: the parameters (`init_params`).
      features: ψ (B, F).
      target: the target network instead of the online one.

    Returns:
      (B, 2).

    Raises:
      ShapeError: `features` of another last dimension.
    """
    check_last("features", features, nets.cfg.feature_size, "feature_size")
    return nets.q.apply({"params": _group(nets, params, "q", target)}, features)


def _require(nets: Networks, algo: str, fn: str):
    if nets.algo != algo:
        raise ConfigError(f"{fn} needs networks built with algo={algo!r}, found algo={nets.algo!r}")


def td3_action(nets: Networks, params: Params, obs, target: bool = False):
    """The TD3 policy's action tanh(MLP(normalize(s))).

    Args:
      nets: the `Networks`.
      params: the parameters (`init_params`).
      obs: raw observations (B, D).
      target: the target policy instead of the online one.

    Returns:
      (B, A) in [−1, 1].

    Raises:
      ConfigError: networks built for another algorithm.
      ShapeError: `obs` of another last dimension.
    """
    _require(nets, "td3", "td3_action")
    check_last("obs", obs, nets.cfg.obs_size, "obs_size")
    out = nets.policy.apply({"params": _group(nets, params, "policy", target)},
                            normalize(obs, params["obs_norm"]))
    return jnp.tanh(out)


def sac_distribution(nets: Networks, params: Params, obs):
    """The SAC policy's pre-tanh Gaussian: loc = out[:, :A], σ = softplus(out[:, A:]) + min_std.

    Args:
      nets: the `Networks`.
      params: the parameters (`init_params`).
      obs: raw observations (B, D).

    Returns:
      (loc (B, A), σ (B, A)).

    Raises:
      ConfigError: networks built for another algorithm.
      ShapeError: `obs` of another last dimension.
    """
    _require(nets, "sac", "sac_distribution")
    cfg = nets.cfg
    check_last("obs", obs, cfg.obs_size, "obs_size")
    out = nets.policy.apply({"params": params["policy"]}, normalize(obs, params["obs_norm"]))
    A = cfg.action_size
    return out[..., :A], jax.nn.softplus(out[..., A:]) + cfg.min_std


def sac_sample(nets: Networks, params: Params, obs, noise):
    """A tanh-Gaussian sample of the SAC policy with explicit standard-normal noise, and its log-density.

    u = loc + σξ, a = tanh(u),
    log π(a|s) = Σ_i[−½ξ_i² − log σ_i − ½ log 2π] − Σ_i 2(log 2 − u_i − softplus(−2u_i)).

    Args:
      nets: the `Networks`.
      params: the parameters (`init_params`).
      obs: raw observations (B, D).
      noise: ξ (B, A) ~ N(0, I).

    Returns:
      (action (B, A), log_prob (B,)).

    Raises:
      ConfigError: networks built for another algorithm.
      ShapeError: `obs` or `noise` of another shape.
    """
    _require(nets, "sac", "sac_sample")
    check_last("noise", noise, nets.cfg.action_size, "action_size")
    loc, std = sac_distribution(nets, params, obs)
    _check_batch_dims("noise", noise, loc.shape, "the policy output")
    u = loc + std * noise
    log_normal = jnp.sum(-0.5 * noise**2 - jnp.log(std) - 0.5 * math.log(2.0 * math.pi), axis=-1)
    log_det_jacobian = jnp.sum(2.0 * (math.log(2.0) - u - jax.nn.softplus(-2.0 * u)), axis=-1)
    return jnp.tanh(u), log_normal - log_det_jacobian


def sac_mode(nets: Networks, params: Params, obs):
    """The SAC policy's deterministic action tanh(loc).

    Args:
      nets: the `Networks`.
      params: the parameters (`init_params`).
      obs: raw observations (B, D).

    Returns:
      (B, A).

    Raises:
      ConfigError: networks built for another algorithm.
      ShapeError: `obs` of another last dimension.
    """
    loc, _ = sac_distribution(nets, params, obs)
    return jnp.tanh(loc)
