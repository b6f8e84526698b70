"""Networks for image observations and discrete actions: the MinAtar system (docs/minatar.md).

pgx's PPO example's conv torso, the actor, the PPO critics (V, or Q(s, ·) for PPO-Q), ψ(s, ·) with one
feature row per action and its Q head, the image ζ as a ψ-conditioned 1×1 convolution over a conv net's
per-pixel features, and the autoencoder; docs/core-contract.md "Image networks". Observations are NHWC
grids (B, H, W, C) of floats; actions are integer indices (B,). `make_image_networks(cfg, obs_shape,
method)` returns an `ImageNetworks` of flax modules, `init_image_params` its parameter dict of canonical
groups (`sf2_jax.params` reads and writes them); the helpers below apply a group to inputs, with the
same names as `sf2_jax.networks`' where they compute the same thing (`psi`, `zeta`, `velocity`, ...).
The torch core's `sf2_torch.networks_image` has the same functions, names, messages and canonical names.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from sf2_common.config import SF2Config
from sf2_common.errors import ConfigError, ShapeError

from sf2_jax import networks as nw

__all__ = [
    "METHODS", "TORSO_CHANNELS", "TORSO_KERNEL", "TORSO_WIDTH", "HEAD_SIZES", "ZETA_KERNEL", "LATENT_SIZE",
    "Torso", "Head", "TorsoNet", "ImagePsi", "PixelLast", "ImageZeta", "ImageNetworks", "make_image_networks",
    "init_image_params", "latent_networks", "policy_logits", "categorical_log_prob", "categorical_entropy",
    "state_value", "action_values", "expected_value", "psi_all", "psi", "q_head", "zeta_hidden", "zeta",
    "velocity", "contract", "velocity_contracted", "encode", "decode_logits", "check_obs", "check_actions",
    "check_flow_time",
]

METHODS = ("ppo", "ppo_q", "sf2", "sf2_ae")
TORSO_CHANNELS, TORSO_KERNEL, TORSO_WIDTH = 32, 2, 64   # pgx's example: Conv(32, 2×2) → pool → Dense 64
HEAD_SIZES = (64, 64)                                   # the actor's and critics' tanh hidden widths
ZETA_KERNEL = 3                                         # ζ's convolutions: 3×3, 'SAME'
LATENT_SIZE = 64                                        # the autoencoder's z ∈ [−1, 1]^64

Params = dict[str, Any]

# Initialization (not part of parity). The torso and the actor's and critics' heads: pgx's example (haiku's
# defaults): conv kernels LeCun-normal (truncated at ±2σ, variance-corrected), dense kernels N(0, 1/fan_in)
# truncated at ±2σ. ψ's MLP, the Q head, ζ and the autoencoder after its torso: the cores' LeCun-uniform.
CONV_INIT = nn.initializers.variance_scaling(1.0, "fan_in", "truncated_normal")


def _dense_init(key, shape, dtype=jnp.float32):
    return jax.random.truncated_normal(key, -2.0, 2.0, shape, dtype) / math.sqrt(shape[0])


def _taps_inside(n: int, kernel: int) -> np.ndarray:
    """V (n, kernel): V_{i,t} = 1 where tap t of a stride-1 'SAME' convolution at row i reads a row inside
    [0, n) (XLA's padding: (kernel − 1) // 2 rows before), else 0."""
    rows = np.arange(n)[:, None] + np.arange(kernel)[None, :] - (kernel - 1) // 2
    return ((rows >= 0) & (rows < n)).astype(np.float64)


def _pixel_last_init(key, shape, dtype=jnp.float32):
    """LeCun-uniform of the 1×1 layer W (H, C, F): fan-in H."""
    bound = math.sqrt(3.0 / shape[0])
    return jax.random.uniform(key, shape, dtype, -bound, bound)


# --------------------------------------------------------------------------------------------- modules
def _avg_pool_2x2(x):
    """2×2 average pooling, stride 2, 'VALID' (an odd last row or column is dropped), on NHWC."""
    b, h, w, c = x.shape
    x = x[:, : 2 * (h // 2), : 2 * (w // 2)].reshape(b, h // 2, 2, w // 2, 2, c)
    return jnp.mean(x, axis=(2, 4))


class Torso(nn.Module):
    """pgx's torso: `conv_0` Conv(32, 2×2, 'SAME') → ReLU → avg-pool 2×2 → flatten (NHWC order) →
    `dense_0` Dense 64 → ReLU. (B, H, W, C) → (B, 64)."""

    def setup(self):
        self.conv = [nn.Conv(TORSO_CHANNELS, (TORSO_KERNEL, TORSO_KERNEL), padding="SAME",
                             kernel_init=CONV_INIT)]
        self.dense = [nn.Dense(TORSO_WIDTH, kernel_init=_dense_init)]

    def __call__(self, obs):
        x = _avg_pool_2x2(nn.relu(self.conv[0](obs)))
        return nn.relu(self.dense[0](x.reshape(x.shape[0], -1)))


class Head(nn.Module):
    """Dense → tanh per hidden width, then a last Dense: `dense_0 .. dense_n`."""

    hidden_sizes: tuple[int, ...]
    out_size: int
    kernel_init: Any = _dense_init

    def setup(self):
        self.dense = [nn.Dense(n, kernel_init=self.kernel_init) for n in (*self.hidden_sizes, self.out_size)]

    def __call__(self, x):
        for layer in self.dense[:-1]:
            x = jnp.tanh(layer(x))
        return self.dense[-1](x)


class TorsoNet(nn.Module):
    """`torso` then `head`: the actor (head → A logits), the critics (→ 1 or A), the encoder (→ 64)."""

    hidden_sizes: tuple[int, ...]
    out_size: int
    kernel_init: Any = _dense_init

    def setup(self):
        self.torso = Torso()
        self.head = Head(self.hidden_sizes, self.out_size, self.kernel_init)

    def __call__(self, obs):
        return self.head(self.torso(obs))


class ImagePsi(nn.Module):
    """ψ(s, ·): `torso` then `head`, the cores' MLP (Dense → ReLU → LayerNorm per hidden width) → A·F."""

    hidden_sizes: tuple[int, ...]
    out_size: int
    use_layer_norm: bool = True

    def setup(self):
        self.torso = Torso()
        self.head = nw.MLP(self.hidden_sizes, self.out_size, self.use_layer_norm)

    def __call__(self, obs):
        return self.head(self.torso(obs))


class PixelLast(nn.Module):
    """The ψ-conditioned 1×1 layer of the image ζ: `kernel` W (H, C, F), `bias` b (C, F)."""

    hidden: int
    channels: int
    features: int

    def setup(self):
        self.kernel = self.param("kernel", _pixel_last_init, (self.hidden, self.channels, self.features))
        self.bias = self.param("bias", nn.initializers.zeros, (self.channels, self.features))

    def __call__(self):
        return self.kernel, self.bias


class ImageZeta(nn.Module):
    """The image ζ: `conv_{i}` Conv(channels_i, 3×3, 'SAME') → ReLU on [grid, embedding(k) at every pixel]
    gives h (B, H, W, H_ζ); `last` is the 1×1 layer (`PixelLast`)."""

    channels: tuple[int, ...]
    grid_channels: int
    features: int

    def setup(self):
        self.conv = [nn.Conv(n, (ZETA_KERNEL, ZETA_KERNEL), padding="SAME", kernel_init=nw.LECUN_UNIFORM)
                     for n in self.channels]
        self.last = PixelLast(self.channels[-1], self.grid_channels, self.features)

    def hidden(self, inp):
        for conv in self.conv:
            inp = nn.relu(conv(inp))
        return inp

    def hidden_split(self, grid, emb):
        """`hidden` of [grid, emb at every pixel] without that broadcast input: the first convolution's
        embedding rows K^e see one e per sample, so their part at pixel (i, j) is Σ_{y,x} V_{i,y} V_{j,x}
        (eᵀK^e_{y,x}) (`_taps_inside`: the taps that read inside the grid); its grid rows convolve as
        before. The same sums as `hidden`, grouped per tap. grid (B, H, W, C), emb (B, E)."""
        kernel, bias = (self.conv[0].variables["params"][name] for name in ("kernel", "bias"))
        dtype = jnp.result_type(grid, emb, kernel)
        kernel, c = kernel.astype(dtype), grid.shape[-1]
        out = jax.lax.conv_general_dilated(grid.astype(dtype), kernel[:, :, :c], (1, 1), "SAME",
                                           dimension_numbers=("NHWC", "HWIO", "NHWC"))
        taps = jnp.einsum("be,yxeh->byxh", emb.astype(dtype), kernel[:, :, c:])
        rows, cols = (jnp.asarray(_taps_inside(n, k), dtype) for n, k in zip(grid.shape[1:3], kernel.shape))
        inp = nn.relu(out + jnp.einsum("iy,jx,byxh->bijh", rows, cols, taps) + bias.astype(dtype))
        for conv in self.conv[1:]:
            inp = nn.relu(conv(inp))
        return inp

    def __call__(self, inp):
        return self.hidden(inp), self.last()


@struct.dataclass
class ImageNetworks:
    """The config, grid shape, method and (parameter-free) flax modules of one MinAtar agent.

    Groups by method: every method `actor`; "ppo" `critic` (V, 1 output); "ppo_q" `critic` (Q(s, ·), A
    outputs); "sf2" `psi`, `q`, `zeta` (image ζ), `target_psi`, `target_zeta`; "sf2_ae" those with `zeta`
    the cores' vector ζ over latents (`latent`: the vector `Networks` of the latent flow, of which only ζ
    is used) and `encoder`, `decoder`. Unused modules are None.
    """

    cfg: SF2Config = struct.field(pytree_node=False)
    obs_shape: tuple = struct.field(pytree_node=False)
    method: str = struct.field(pytree_node=False)
    actor: TorsoNet = struct.field(pytree_node=False)
    critic: Any = struct.field(pytree_node=False, default=None)
    psi: Any = struct.field(pytree_node=False, default=None)
    q: Any = struct.field(pytree_node=False, default=None)
    zeta: Any = struct.field(pytree_node=False, default=None)
    encoder: Any = struct.field(pytree_node=False, default=None)
    decoder: Any = struct.field(pytree_node=False, default=None)
    latent: Any = struct.field(pytree_node=False, default=None)


def _check_obs_shape(obs_shape) -> tuple[int, int, int]:
    shape = tuple(obs_shape) if isinstance(obs_shape, (tuple, list)) else None
    if (shape is None or len(shape) != 3 or not all(isinstance(n, (int, np.integer)) for n in shape)
            or shape[0] < 2 or shape[1] < 2 or shape[2] < 1):
        raise ConfigError(f"obs_shape={obs_shape!r} is invalid: must be (height, width, channels), "
                          f"integers with height and width >= 2 and channels >= 1")
    return tuple(int(n) for n in shape)


def make_image_networks(cfg: SF2Config, obs_shape, method: str) -> ImageNetworks:
    """Build the networks of one MinAtar agent (docs/minatar.md).

    The actor: torso → Dense 64 tanh → Dense 64 tanh → A logits; "ppo"'s critic → 1 (V), "ppo_q"'s → A
    (Q(s, ·)); ψ(s, ·): torso → MLP(cfg.hidden_sizes, LayerNorm per cfg.layer_norm) → A·F, ψ(s, a) = row
    a; Q head: Dense(F → cfg.q_hidden_size) → ReLU → Dense(→ 1) on ψ; "sf2"'s ζ: convolutions of widths
    cfg.zeta_hidden_sizes, then the ψ-conditioned 1×1 layer; "sf2_ae"'s ζ: the cores' vector ζ (MLP of
    widths cfg.zeta_hidden_sizes on [z, embedding(k)] → F·64); encoder: torso → Dense 64 → tanh; decoder:
    Dense(64 → H·W·C) logits.

    Args:
      cfg: the `SF2Config`: obs_size = H·W·C, action_size = A (the number of actions), the sizes above and
        the flow loss's hyperparameters.
      obs_shape: (H, W, C) of the grid.
      method: one of `METHODS`: "ppo", "ppo_q", "sf2" (SF² w/o AE), "sf2_ae" (SF² w AE).

    Returns:
      The `ImageNetworks` (`init_image_params` makes the parameters).

    Raises:
      ConfigError: `cfg` not an `SF2Config`, an unknown `method`, an invalid `obs_shape` or one whose size
        is not cfg.obs_size.
    """
    if not isinstance(cfg, SF2Config):
        raise ConfigError(f"cfg must be an SF2Config, found {type(cfg).__name__}")
    if method not in METHODS:
        raise ConfigError(f"method={method!r} is invalid: must be one of "
                          f"{', '.join(repr(m) for m in METHODS)}")
    shape = _check_obs_shape(obs_shape)
    if shape[0] * shape[1] * shape[2] != cfg.obs_size:
        raise ConfigError(f"obs_shape={shape} has {shape[0] * shape[1] * shape[2]} cells, but "
                          f"cfg.obs_size = {cfg.obs_size}: they must be equal")
    A, F = cfg.action_size, cfg.feature_size
    kw: dict[str, Any] = dict(actor=TorsoNet(HEAD_SIZES, A))
    if method in ("ppo", "ppo_q"):
        kw["critic"] = TorsoNet(HEAD_SIZES, 1 if method == "ppo" else A)
    else:
        kw["psi"] = ImagePsi(cfg.hidden_sizes, A * F, cfg.layer_norm)
        kw["q"] = nw.MLP((cfg.q_hidden_size,), 1, use_layer_norm=False)
        if method == "sf2":
            kw["zeta"] = ImageZeta(cfg.zeta_hidden_sizes, shape[2], F)
        else:
            latent = nw.make_networks(dataclasses.replace(cfg, obs_size=LATENT_SIZE), "td3")
            kw.update(latent=latent, zeta=latent.zeta, encoder=TorsoNet((), LATENT_SIZE, nw.LECUN_UNIFORM),
                      decoder=Head((), cfg.obs_size, nw.LECUN_UNIFORM))
    return ImageNetworks(cfg=cfg, obs_shape=shape, method=method, **kw)


def init_image_params(nets: ImageNetworks, key: jax.Array, dtype=None) -> Params:
    """Initialise the parameters of every canonical group of `nets` (targets are copies of the online ones).

    Args:
      nets: the `ImageNetworks`.
      key: a PRNG key.
      dtype: of every parameter (default: JAX's default float type, float64 under `jax_enable_x64`).

    Returns:
      {group: nested params} (`sf2_jax.params` flattens it to canonical names).
    """
    cfg = nets.cfg
    dtype = jnp.dtype(jnp.result_type(float) if dtype is None else dtype)
    f32 = jnp.float32
    obs = jnp.zeros((1, *nets.obs_shape), f32)
    keys = dict(zip(("actor", "critic", "psi", "q", "zeta", "encoder", "decoder"), jax.random.split(key, 7)))
    inputs = {
        "actor": obs, "critic": obs, "psi": obs, "q": jnp.zeros((1, cfg.feature_size), f32),
        "encoder": obs, "decoder": jnp.zeros((1, LATENT_SIZE), f32),
        "zeta": (jnp.zeros((1, *nets.obs_shape[:2], nets.obs_shape[2] + cfg.embedding_size), f32)
                 if nets.method == "sf2" else jnp.zeros((1, LATENT_SIZE + cfg.embedding_size), f32)),
    }
    params = {}
    for name, x in inputs.items():
        module = getattr(nets, name)
        if module is not None:
            tree = module.init(keys[name], x)["params"]
            params[name] = jax.tree_util.tree_map(lambda v: jnp.asarray(v, dtype), tree)
    for name in ("psi", "zeta"):
        if name in params:
            params[f"target_{name}"] = jax.tree_util.tree_map(jnp.copy, params[name])
    return params


def latent_networks(nets: ImageNetworks) -> nw.Networks:
    """The vector core's view of the latent flow of "sf2_ae": `sf2_jax.networks` functions (`contract`,
    `velocity`, ...) called with it and the image params read the groups `zeta` and `target_zeta`.

    Args:
      nets: "sf2_ae" `ImageNetworks`.

    Returns:
      The vector `Networks` whose cfg is `nets.cfg` with obs_size = `LATENT_SIZE`.

    Raises:
      ConfigError: networks of another method.
    """
    _require(nets, ("sf2_ae",), "latent_networks")
    return nets.latent


# ------------------------------------------------------------------------------------------ checks
def _require(nets: ImageNetworks, methods: tuple[str, ...], fn: str) -> None:
    if not isinstance(nets, ImageNetworks):
        raise ConfigError(f"{fn} needs ImageNetworks, found {type(nets).__name__}")
    if nets.method not in methods:
        raise ConfigError(f"{fn} needs image networks built with method "
                          f"{' or '.join(repr(m) for m in methods)}, found method={nets.method!r}")


def _dtype_name(x) -> str:
    return str(jnp.asarray(x).dtype) if not hasattr(x, "dtype") else str(np.dtype(x.dtype))


def _host_values(x):
    """x as a numpy array when its values are readable without a device synchronization (not traced, on
    the CPU); else None (the value checks are then skipped)."""
    if isinstance(x, jax.core.Tracer):
        return None
    if isinstance(x, jax.Array) and any(d.platform != "cpu" for d in x.devices()):
        return None
    return np.asarray(x)


def check_obs(nets: ImageNetworks, name: str, obs, batch_shape: tuple | None = None) -> tuple[int]:
    """Check a batch of grids: shape (B, H, W, C), a floating-point dtype (never bool).

    Args:
      nets: the `ImageNetworks` (its obs_shape).
      name: the argument's name, for the message.
      obs: the array.
      batch_shape: (B,) it must have; None: any single batch dimension.

    Returns:
      The batch shape (B,).

    Raises:
      ShapeError: another shape or a non-floating dtype.
    """
    shape = tuple(jnp.shape(obs))
    if len(shape) != 4 or shape[1:] != nets.obs_shape or (batch_shape is not None
                                                         and shape[:1] != tuple(batch_shape)):
        lead = "B" if batch_shape is None else batch_shape[0]
        raise ShapeError(f"{name} must have shape ({lead}, {', '.join(map(str, nets.obs_shape))}) (a batch "
                         f"of grids, NHWC), found {shape}")
    if not jnp.issubdtype(obs.dtype if hasattr(obs, "dtype") else jnp.asarray(obs).dtype, jnp.floating):
        raise ShapeError(f"{name} must be a floating-point array (the grid's cells as 0.0 and 1.0), found "
                         f"dtype {_dtype_name(obs)}")
    return shape[:1]


def check_actions(nets: ImageNetworks, name: str, action, batch_shape: tuple) -> None:
    """Check action indices: shape (B,), an integer dtype, and (where readable, `_host_values`) in [0, A).

    Args:
      nets: the `ImageNetworks` (A = cfg.action_size).
      name: the argument's name, for the message.
      action: the array.
      batch_shape: (B,).

    Raises:
      ShapeError: another shape, a non-integer dtype, or an index outside [0, A).
    """
    shape = tuple(jnp.shape(action))
    if shape != tuple(batch_shape):
        raise ShapeError(f"{name} must have shape {tuple(batch_shape)} (one action index per sample), "
                         f"found {shape}")
    dtype = action.dtype if hasattr(action, "dtype") else jnp.asarray(action).dtype
    if not jnp.issubdtype(dtype, jnp.integer):
        raise ShapeError(f"{name} must be an integer array of action indices, found dtype "
                         f"{_dtype_name(action)}")
    values = _host_values(action)
    A = nets.cfg.action_size
    if values is not None and values.size and (values.min() < 0 or values.max() >= A):
        raise ShapeError(f"{name} must hold action indices in [0, {A}), found values from "
                         f"{int(values.min())} to {int(values.max())}")


def check_flow_time(flow_time, batch_shape: tuple) -> None:
    """Check flow times: shape (B,) and (where readable, `_host_values`) in [0, 1].

    Args:
      flow_time: k, the array.
      batch_shape: (B,).

    Raises:
      ShapeError: another shape, or a value outside [0, 1].
    """
    shape = tuple(jnp.shape(flow_time))
    if shape != tuple(batch_shape):
        raise ShapeError(f"flow_time must have shape {tuple(batch_shape)} (one flow time per sample), "
                         f"found {shape}")
    values = _host_values(flow_time)
    if values is not None and values.size and not (values.min() >= 0 and values.max() <= 1):
        raise ShapeError(f"flow_time must lie in [0, 1], found values from {float(values.min())!r} to "
                         f"{float(values.max())!r}")


def _group(params: Params, name: str, target: bool = False) -> Params:
    key = f"target_{name}" if target else name
    if key not in params:
        raise ConfigError(f"params has no group {key!r}; groups: {sorted(params)}")
    return params[key]


# ------------------------------------------------------------------------------------------ actor, critics
def policy_logits(nets: ImageNetworks, params: Params, obs):
    """The actor's logits: torso → Dense 64 tanh → Dense 64 tanh → Dense A.

    Args:
      nets: the `ImageNetworks`.
      params: the parameters (`init_image_params`).
      obs: grids (B, H, W, C).

    Returns:
      (B, A).

    Raises:
      ShapeError: `obs` of another shape or dtype.
    """
    check_obs(nets, "obs", obs)
    return nets.actor.apply({"params": _group(params, "actor")}, obs)


def categorical_log_prob(logits, action):
    """log π(a|s) = log_softmax(logits)[a].

    Args:
      logits: (B, A).
      action: integer indices (B,).

    Returns:
      (B,).
    """
    log_p = jax.nn.log_softmax(logits, axis=-1)
    return jnp.take_along_axis(log_p, jnp.asarray(action)[..., None], axis=-1)[..., 0]


def categorical_entropy(logits):
    """The entropy of the categorical policy: −Σ_a π(a|s) log π(a|s).

    Args:
      logits: (B, A).

    Returns:
      (B,).
    """
    log_p = jax.nn.log_softmax(logits, axis=-1)
    return -jnp.sum(jnp.exp(log_p) * log_p, axis=-1)


def state_value(nets: ImageNetworks, params: Params, obs):
    """V(s), "ppo"'s critic: torso → Dense 64 tanh → Dense 64 tanh → Dense 1.

    Args:
      nets: "ppo" `ImageNetworks`.
      params: the parameters (`init_image_params`).
      obs: grids (B, H, W, C).

    Returns:
      (B,).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `obs` of another shape or dtype.
    """
    _require(nets, ("ppo",), "state_value")
    check_obs(nets, "obs", obs)
    return nets.critic.apply({"params": _group(params, "critic")}, obs)[..., 0]


def action_values(nets: ImageNetworks, params: Params, obs):
    """Q(s, ·): "ppo_q"'s critic (torso → Dense 64 tanh ×2 → Dense A), or SF²'s Q head on ψ(s, ·).

    Args:
      nets: "ppo_q", "sf2" or "sf2_ae" `ImageNetworks`.
      params: the parameters (`init_image_params`).
      obs: grids (B, H, W, C).

    Returns:
      (B, A).

    Raises:
      ConfigError: "ppo" networks.
      ShapeError: `obs` of another shape or dtype.
    """
    _require(nets, ("ppo_q", "sf2", "sf2_ae"), "action_values")
    if nets.method == "ppo_q":
        check_obs(nets, "obs", obs)
        return nets.critic.apply({"params": _group(params, "critic")}, obs)
    return q_head(nets, params, psi_all(nets, params, obs))


def expected_value(logits, q):
    """V_Q(s) = Σ_a π(a|s) Q(s, a), exact for discrete actions.

    Args:
      logits: the actor's logits (B, A).
      q: Q(s, ·) (B, A).

    Returns:
      (B,).
    """
    return jnp.sum(jax.nn.softmax(logits, axis=-1) * q, axis=-1)


# ------------------------------------------------------------------------------------------ ψ and Q
def psi_all(nets: ImageNetworks, params: Params, obs, target: bool = False):
    """ψ(s, ·): every action's feature, row a of the (A, F) reshape of the A·F outputs (entry a·F + f).

    Args:
      nets: "sf2" or "sf2_ae" `ImageNetworks`.
      params: the parameters (`init_image_params`).
      obs: grids (B, H, W, C).
      target: the target ψ̄ instead of the online ψ.

    Returns:
      (B, A, F).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `obs` of another shape or dtype.
    """
    _require(nets, ("sf2", "sf2_ae"), "psi_all")
    check_obs(nets, "obs", obs)
    out = nets.psi.apply({"params": _group(params, "psi", target)}, obs)
    return out.reshape(*out.shape[:-1], nets.cfg.action_size, nets.cfg.feature_size)


def psi(nets: ImageNetworks, params: Params, obs, action, target: bool = False):
    """ψ(s, a): row a of `psi_all`.

    Args:
      nets: "sf2" or "sf2_ae" `ImageNetworks`.
      params: the parameters (`init_image_params`).
      obs: grids (B, H, W, C).
      action: integer indices (B,).
      target: the target ψ̄ instead of the online ψ.

    Returns:
      (B, F).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `obs` or `action` of another shape or dtype, or an action outside [0, A).
    """
    _require(nets, ("sf2", "sf2_ae"), "psi")
    b = check_obs(nets, "obs", obs)
    check_actions(nets, "action", action, b)
    rows = psi_all(nets, params, obs, target)
    return jnp.take_along_axis(rows, jnp.asarray(action)[:, None, None], axis=1)[:, 0]


def q_head(nets: ImageNetworks, params: Params, features):
    """SF²'s Q on features: Dense(F → q_hidden_size) → ReLU → Dense(→ 1), applied to each feature row.

    Args:
      nets: "sf2" or "sf2_ae" `ImageNetworks`.
      params: the parameters (`init_image_params`).
      features: ψ (..., F).

    Returns:
      (...).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `features` of another last dimension.
    """
    _require(nets, ("sf2", "sf2_ae"), "q_head")
    nw.check_last("features", features, nets.cfg.feature_size, "feature_size")
    return nets.q.apply({"params": _group(params, "q")}, features)[..., 0]


# ------------------------------------------------------------------------------------------ the image ζ
def _zeta_parts(nets: ImageNetworks, x, k):
    """(grid of x (B, H, W, C), embedding(k) (B, E)), checked."""
    cfg = nets.cfg
    nw.check_last("x", x, cfg.obs_size, "obs_size")
    x, k = jnp.asarray(x), jnp.asarray(k)
    if k.ndim == 0:
        k = jnp.broadcast_to(k, x.shape[:-1])
    if tuple(k.shape) != tuple(x.shape[:-1]) or x.ndim != 2:
        raise ShapeError(f"x and flow_time must have shapes (B, {cfg.obs_size}) and (B,), found "
                         f"{tuple(x.shape)} and {tuple(k.shape)}")
    dtype = jnp.result_type(x.dtype, k.dtype, float)
    grid = x.astype(dtype).reshape(x.shape[0], *nets.obs_shape)
    return grid, nw.flow_time_embedding(k.astype(dtype), cfg.embedding_size)


def _zeta_input(nets: ImageNetworks, x, k):
    """[grid of x, embedding(k) at every pixel] (B, H, W, C + E)."""
    grid, emb = _zeta_parts(nets, x, k)
    emb = jnp.broadcast_to(emb[:, None, None, :], (*grid.shape[:3], emb.shape[-1]))
    return jnp.concatenate([grid, emb], axis=-1)


def zeta_hidden(nets: ImageNetworks, params: Params, x, k, target: bool = False):
    """h(x, k): the image ζ's per-pixel features, its convolutions on [grid of x, embedding(k)].

    With `cfg.contract_zeta` (the fast path) the embedding's part of the first convolution is formed once
    per sample and tap (`ImageZeta.hidden_split`); otherwise the convolution runs over the embedding
    broadcast to every pixel (the oracle).

    Args:
      nets: "sf2" `ImageNetworks`.
      params: the parameters (`init_image_params`).
      x: flattened grids (B, D), D = H·W·C in NHWC order.
      k: the flow time (B,) (or a scalar).
      target: the target ζ̄ instead of the online ζ.

    Returns:
      (B, H, W, H_ζ).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `x` or `k` of another shape.
    """
    _require(nets, ("sf2",), "zeta_hidden")
    variables = {"params": _group(params, "zeta", target)}
    if nets.cfg.contract_zeta:
        return nets.zeta.apply(variables, *_zeta_parts(nets, x, k), method=ImageZeta.hidden_split)
    return nets.zeta.apply(variables, _zeta_input(nets, x, k), method=ImageZeta.hidden)


def _last(params: Params, target: bool):
    last = _group(params, "zeta", target)["last"]
    return last["kernel"], last["bias"]


def zeta(nets: ImageNetworks, params: Params, x, k, target: bool = False):
    """The image ζ(x, k) materialized (the plain formulation, a test oracle): ζ_{(p,c),f} = Σ_h h_{p,h}
    W_{h,c,f} + b_{c,f}, p a pixel, c a channel, row (p, c) = the flattened grid's index p·C + c.

    Args:
      nets: "sf2" `ImageNetworks`.
      params: the parameters (`init_image_params`).
      x: flattened grids (B, D).
      k: the flow time (B,) (or a scalar).
      target: the target ζ̄ instead of the online ζ.

    Returns:
      (B, D, F).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `x` or `k` of another shape.
    """
    h = zeta_hidden(nets, params, x, k, target)
    W, b = _last(params, target)
    out = jnp.einsum("bpqh,hcf->bpqcf", h, W) + b
    return out.reshape(out.shape[0], nets.cfg.obs_size, nets.cfg.feature_size)


def velocity(nets: ImageNetworks, params: Params, x, k, features, target: bool = False):
    """The plain velocity u = ζ(x, k)ψ, u_d = Σ_f ζ_{d f} ψ_f, through the materialized ζ (test oracle).

    Args:
      nets: "sf2" `ImageNetworks`.
      params: the parameters (`init_image_params`).
      x: flattened grids (B, D).
      k: the flow time (B,).
      features: ψ (B, F).
      target: the target ζ̄ instead of the online ζ.

    Returns:
      (B, D).

    Raises:
      ConfigError: networks of another method.
      ShapeError: an input of another shape.
    """
    nw.check_last("features", features, nets.cfg.feature_size, "feature_size")
    return jnp.einsum("bdf,bf->bd", zeta(nets, params, x, k, target), features)


def contract(nets: ImageNetworks, params: Params, features, target: bool = False):
    """Contract the 1×1 layer with ψ once: M = Wψ, M_{h,c} = Σ_f W_{h,c,f} ψ_f, and c_c = Σ_f b_{c,f} ψ_f.

    Args:
      nets: "sf2" `ImageNetworks`.
      params: the parameters (`init_image_params`).
      features: ψ (B, F).
      target: the target ζ̄ instead of the online ζ.

    Returns:
      (M (B, H_ζ, C), c (B, C)).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `features` of another last dimension.
    """
    _require(nets, ("sf2",), "contract")
    nw.check_last("features", features, nets.cfg.feature_size, "feature_size")
    W, b = _last(params, target)
    return jnp.einsum("bf,hcf->bhc", features, W), jnp.einsum("bf,cf->bc", features, b)


def velocity_contracted(nets: ImageNetworks, params: Params, x, k, M, c, target: bool = False):
    """The fast velocity u_{p,c} = Σ_h h_{p,h} M_{h,c} + c_c, equal to `velocity` without forming ζ.

    Args:
      nets: "sf2" `ImageNetworks`.
      params: the parameters (`init_image_params`).
      x: flattened grids (B, D).
      k: the flow time (B,).
      M: (B, H_ζ, C) from `contract`.
      c: (B, C) from `contract`.
      target: the target ζ̄ instead of the online ζ.

    Returns:
      (B, D).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `x`, `k`, M or c of another shape.
    """
    h = zeta_hidden(nets, params, x, k, target)
    expected = ((h.shape[0], h.shape[-1], nets.obs_shape[2]), (h.shape[0], nets.obs_shape[2]))
    if (tuple(jnp.shape(M)), tuple(jnp.shape(c))) != expected:
        raise ShapeError(f"contracted (M, c) must have shapes {expected[0]} (B, H_zeta, C) and {expected[1]} "
                         f"(B, C), found {tuple(jnp.shape(M))} and {tuple(jnp.shape(c))}")
    u = jnp.einsum("bpqh,bhc->bpqc", h, M) + c[:, None, None, :]
    return u.reshape(u.shape[0], nets.cfg.obs_size)


# ------------------------------------------------------------------------------------------ autoencoder
def encode(nets: ImageNetworks, params: Params, obs):
    """The encoder: z = tanh(Dense 64(torso(s))) ∈ [−1, 1]^64.

    Args:
      nets: "sf2_ae" `ImageNetworks`.
      params: the parameters (`init_image_params`).
      obs: grids (B, H, W, C).

    Returns:
      (B, 64).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `obs` of another shape or dtype.
    """
    _require(nets, ("sf2_ae",), "encode")
    check_obs(nets, "obs", obs)
    return jnp.tanh(nets.encoder.apply({"params": _group(params, "encoder")}, obs))


def decode_logits(nets: ImageNetworks, params: Params, z):
    """The decoder: Dense(64 → H·W·C), the Bernoulli logits of every cell.

    Args:
      nets: "sf2_ae" `ImageNetworks`.
      params: the parameters (`init_image_params`).
      z: latents (B, 64).

    Returns:
      (B, H, W, C).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `z` of another last dimension.
    """
    _require(nets, ("sf2_ae",), "decode_logits")
    nw.check_last("z", z, LATENT_SIZE, "the latent size")
    out = nets.decoder.apply({"params": _group(params, "decoder")}, z)
    return out.reshape(*out.shape[:-1], *nets.obs_shape)
