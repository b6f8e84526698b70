"""Networks for image observations and discrete actions: the MinAtar system (docs/minatar.md).

pgx's PPO example's conv torso, the actor, the PPO critics (V, or Q(s, ·) for PPO-Q), ψ(s, ·) with one
feature row per action and its Q head, the image ζ as a ψ-conditioned 1×1 convolution over a conv net's
per-pixel features, and the autoencoder; docs/core-contract.md "Image networks". The public API takes NHWC
grids (B, H, W, C) of floats (the convolutions run NCHW inside) and integer actions (B,).
`make_image_networks(cfg, obs_shape, method)` builds an `ImageNetworks` module whose children carry the
canonical names (`sf2_torch.params`: conv kernels stored HWIO); the functions below have the JAX core's
`sf2_jax.networks_image` names, signatures (without its `params`) and messages.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from sf2_common.config import SF2Config
from sf2_common.errors import ConfigError, ShapeError
from torch import nn

from .networks import MLP, Zeta, check_last, flow_time_embedding

__all__ = [
    # the JAX core's names, in its order (`init_image_params` aside: torch modules hold their parameters)
    "METHODS", "TORSO_CHANNELS", "TORSO_KERNEL", "TORSO_WIDTH", "HEAD_SIZES", "ZETA_KERNEL", "LATENT_SIZE",
    "Torso", "Head", "TorsoNet", "ImagePsi", "PixelLast", "ImageZeta", "ImageNetworks", "make_image_networks",
    "latent_networks", "policy_logits", "categorical_log_prob", "categorical_entropy", "state_value",
    "action_values", "expected_value", "psi_all", "psi", "q_head", "zeta_hidden", "zeta", "velocity",
    "contract", "velocity_contracted", "encode", "decode_logits", "check_obs", "check_actions",
    "check_flow_time",
    # torch's
    "LatentView",
]

METHODS = ("ppo", "ppo_q", "sf2", "sf2_ae")
TORSO_CHANNELS, TORSO_KERNEL, TORSO_WIDTH = 32, 2, 64   # pgx's example: Conv(32, 2×2) → pool → Dense 64
HEAD_SIZES = (64, 64)                                   # the actor's and critics' tanh hidden widths
ZETA_KERNEL = 3                                         # ζ's convolutions: 3×3, 'SAME'
LATENT_SIZE = 64                                        # the autoencoder's z ∈ [−1, 1]^64
_TRUNCATED_STD = 0.87962566103423978                    # std of N(0, 1) truncated at ±2


# Initialization (not part of parity), as the JAX core's: the torso and the actor's and critics' heads
# follow pgx's example (haiku's defaults), ψ's MLP, the Q head, ζ and the autoencoder after its torso the
# cores' LeCun-uniform.
@torch.no_grad()
def _init(module: nn.Module, kind: str) -> nn.Module:
    """kind "conv": LeCun-normal truncated at ±2σ, variance-corrected; "dense": N(0, 1/fan_in) truncated at
    ±2σ; "lecun": U(±√(3/fan_in)). Fan-in: in_features, or in_channels·kh·kw. Biases zero."""
    w = module.weight
    fan_in = w[0].numel()
    if kind == "lecun":
        bound = math.sqrt(3.0 / fan_in)
        w.uniform_(-bound, bound)
    else:
        std = math.sqrt(1.0 / fan_in) / (_TRUNCATED_STD if kind == "conv" else 1.0)
        nn.init.trunc_normal_(w, 0.0, std, -2.0 * std, 2.0 * std)
    module.bias.zero_()
    return module


def _conv_same(conv: nn.Conv2d, x: torch.Tensor) -> torch.Tensor:
    """A stride-1 convolution with XLA's 'SAME' padding (an even kernel pads one more after than before)."""
    pads = []
    for k in reversed(conv.kernel_size):   # F.pad: last dimension first
        pads += [(k - 1) // 2, k - 1 - (k - 1) // 2]
    return conv(F.pad(x, pads))


def _taps_inside(n: int, kernel: int) -> np.ndarray:
    """V (n, kernel): V_{i,t} = 1 where tap t of a stride-1 'SAME' convolution at row i reads a row inside
    [0, n) (XLA's padding: (kernel − 1) // 2 rows before), else 0."""
    rows = np.arange(n)[:, None] + np.arange(kernel)[None, :] - (kernel - 1) // 2
    return ((rows >= 0) & (rows < n)).astype(np.float64)


def _avg_pool_2x2(x: torch.Tensor) -> torch.Tensor:
    """2×2 average pooling, stride 2, 'VALID' (an odd last row or column is dropped), on NHWC."""
    b, h, w, c = x.shape
    x = x[:, : 2 * (h // 2), : 2 * (w // 2)].reshape(b, h // 2, 2, w // 2, 2, c)
    return x.mean(dim=(2, 4))


class Torso(nn.Module):
    """pgx's torso: `conv_0` Conv(32, 2×2, 'SAME') → ReLU → avg-pool 2×2 → flatten (NHWC order) →
    `dense_0` Dense 64 → ReLU. (B, H, W, C) → (B, 64)."""

    def __init__(self, obs_shape: Sequence[int], *, dtype=None, device=None) -> None:
        super().__init__()
        h, w, c = obs_shape
        kw = dict(dtype=dtype, device=device)
        self.conv_0 = _init(nn.Conv2d(c, TORSO_CHANNELS, TORSO_KERNEL, **kw), "conv")
        self.dense_0 = _init(nn.Linear((h // 2) * (w // 2) * TORSO_CHANNELS, TORSO_WIDTH, **kw), "dense")

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        x = F.relu(_conv_same(self.conv_0, obs.permute(0, 3, 1, 2))).permute(0, 2, 3, 1)
        x = _avg_pool_2x2(x)
        return F.relu(self.dense_0(x.reshape(x.shape[0], -1)))


class Head(nn.Module):
    """Dense → tanh per hidden width, then a last Dense: `dense_0 .. dense_n`."""

    def __init__(self, in_size: int, hidden_sizes: Sequence[int], out_size: int, init: str = "dense", *,
                 dtype=None, device=None) -> None:
        super().__init__()
        sizes = (int(in_size), *hidden_sizes, int(out_size))
        self.num_layers = len(sizes) - 1
        for i in range(self.num_layers):
            self.add_module(f"dense_{i}", _init(nn.Linear(sizes[i], sizes[i + 1], dtype=dtype, device=device),
                                                init))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for i in range(self.num_layers):
            x = getattr(self, f"dense_{i}")(x)
            if i < self.num_layers - 1:
                x = torch.tanh(x)
        return x


class TorsoNet(nn.Module):
    """`torso` then `head`: the actor (head → A logits), the critics (→ 1 or A), the encoder (→ 64)."""

    def __init__(self, obs_shape, hidden_sizes, out_size: int, init: str = "dense", **kw) -> None:
        super().__init__()
        self.torso = Torso(obs_shape, **kw)
        self.head = Head(TORSO_WIDTH, hidden_sizes, out_size, init, **kw)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.head(self.torso(obs))


class ImagePsi(nn.Module):
    """ψ(s, ·): `torso` then `head`, the core's MLP (Dense → ReLU → LayerNorm per hidden width) → A·F."""

    def __init__(self, cfg: SF2Config, obs_shape, **kw) -> None:
        super().__init__()
        self.torso = Torso(obs_shape, **kw)
        out = cfg.action_size * cfg.feature_size
        self.head = MLP(TORSO_WIDTH, cfg.hidden_sizes, out, cfg.layer_norm, **kw)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.head(self.torso(obs))


class PixelLast(nn.Module):
    """The ψ-conditioned 1×1 layer of the image ζ: `kernel` W (H, C, F), `bias` b (C, F)."""

    def __init__(self, hidden: int, channels: int, features: int, *, dtype=None, device=None) -> None:
        super().__init__()
        kw = dict(dtype=dtype or torch.get_default_dtype(), device=device)
        bound = math.sqrt(3.0 / hidden)
        self.kernel = nn.Parameter(torch.empty(hidden, channels, features, **kw).uniform_(-bound, bound))
        self.bias = nn.Parameter(torch.zeros(channels, features, **kw))


class ImageZeta(nn.Module):
    """The image ζ: `conv_{i}` Conv(channels_i, 3×3, 'SAME') → ReLU on [grid, embedding(k) at every pixel]
    gives h (B, H, W, H_ζ); `last` is the 1×1 layer (`PixelLast`)."""

    def __init__(self, cfg: SF2Config, obs_shape, **kw) -> None:
        super().__init__()
        self.obs_shape, self.obs_size = tuple(obs_shape), cfg.obs_size
        self.embedding_size = cfg.embedding_size
        fan_in = obs_shape[2] + cfg.embedding_size
        self.num_conv = len(cfg.zeta_hidden_sizes)
        for i, width in enumerate(cfg.zeta_hidden_sizes):
            self.add_module(f"conv_{i}", _init(nn.Conv2d(fan_in, width, ZETA_KERNEL, **kw), "lecun"))
            fan_in = width
        self.last = PixelLast(fan_in, obs_shape[2], cfg.feature_size, **kw)

    def _parts(self, x: torch.Tensor, k) -> tuple[torch.Tensor, torch.Tensor]:
        """(grid of x (B, H, W, C), embedding(k) (B, E)), checked."""
        check_last("x", x, self.obs_size, "obs_size")
        k = torch.as_tensor(k, dtype=x.dtype, device=x.device)
        if k.ndim == 0:
            k = k.expand(x.shape[:-1])
        if tuple(k.shape) != tuple(x.shape[:-1]) or x.ndim != 2:
            raise ShapeError(f"x and flow_time must have shapes (B, {self.obs_size}) and (B,), found "
                             f"{tuple(x.shape)} and {tuple(k.shape)}")
        return x.reshape(x.shape[0], *self.obs_shape), flow_time_embedding(k, self.embedding_size)

    def hidden(self, x: torch.Tensor, k) -> torch.Tensor:
        grid, emb = self._parts(x, k)
        emb = emb[:, None, None, :].expand(*grid.shape[:3], self.embedding_size)
        inp = torch.cat([grid, emb], dim=-1).permute(0, 3, 1, 2)
        for i in range(self.num_conv):
            inp = F.relu(_conv_same(getattr(self, f"conv_{i}"), inp))
        return inp.permute(0, 2, 3, 1)

    def hidden_split(self, x: torch.Tensor, k) -> torch.Tensor:
        """`hidden` without the embedding broadcast to every pixel: the first convolution's embedding rows
        K^e see one e per sample, so their part at pixel (i, j) is Σ_{y,x} V_{i,y} V_{j,x} (eᵀK^e_{y,x})
        (`_taps_inside`); its grid rows convolve as before. The same sums as `hidden`, grouped per tap."""
        grid, emb = self._parts(x, k)
        conv, c = self.conv_0, grid.shape[-1]
        kh, kw = conv.kernel_size
        pads = [(kw - 1) // 2, kw - 1 - (kw - 1) // 2, (kh - 1) // 2, kh - 1 - (kh - 1) // 2]
        out = F.conv2d(F.pad(grid.permute(0, 3, 1, 2), pads), conv.weight[:, :c], conv.bias)
        taps = torch.einsum("be,heyx->bhyx", emb, conv.weight[:, c:])
        rows, cols = (torch.as_tensor(_taps_inside(n, kk), dtype=taps.dtype, device=taps.device)
                      for n, kk in zip(grid.shape[1:3], (kh, kw)))
        inp = F.relu(out + torch.einsum("iy,jx,bhyx->bhij", rows, cols, taps))
        for i in range(1, self.num_conv):
            inp = F.relu(_conv_same(getattr(self, f"conv_{i}"), inp))
        return inp.permute(0, 2, 3, 1)


def _frozen_copy(module: nn.Module) -> nn.Module:
    return copy.deepcopy(module).requires_grad_(False)


def _check_obs_shape(obs_shape) -> tuple[int, int, int]:
    shape = tuple(obs_shape) if isinstance(obs_shape, (tuple, list)) else None
    if (shape is None or len(shape) != 3 or not all(isinstance(n, (int, np.integer)) for n in shape)
            or shape[0] < 2 or shape[1] < 2 or shape[2] < 1):
        raise ConfigError(f"obs_shape={obs_shape!r} is invalid: must be (height, width, channels), "
                          f"integers with height and width >= 2 and channels >= 1")
    return tuple(int(n) for n in shape)


class ImageNetworks(nn.Module):
    """The networks of one MinAtar agent (`make_image_networks`); `cfg`, `obs_shape` and `method` are plain
    attributes.

    Groups by method: every method `actor`; "ppo" `critic` (V, 1 output); "ppo_q" `critic` (Q(s, ·), A
    outputs); "sf2" `psi`, `q`, `zeta` (image ζ), `target_psi`, `target_zeta` (frozen copies); "sf2_ae"
    those with `zeta` the core's vector ζ over latents (`Zeta` of `latent_cfg`, obs_size 64) and `encoder`,
    `decoder`.
    """

    def __init__(self, cfg: SF2Config, obs_shape, method: str, *, dtype=None, device=None) -> None:
        super().__init__()
        if not isinstance(cfg, SF2Config):
            raise ConfigError(f"cfg must be an SF2Config, found {type(cfg).__name__}")
        if method not in METHODS:
            raise ConfigError(f"method={method!r} is invalid: must be one of "
                              f"{', '.join(repr(m) for m in METHODS)}")
        shape = _check_obs_shape(obs_shape)
        if shape[0] * shape[1] * shape[2] != cfg.obs_size:
            raise ConfigError(f"obs_shape={shape} has {shape[0] * shape[1] * shape[2]} cells, but "
                              f"cfg.obs_size = {cfg.obs_size}: they must be equal")
        self.cfg, self.obs_shape, self.method = cfg, shape, method
        A, kw = cfg.action_size, dict(dtype=dtype, device=device)
        self.actor = TorsoNet(shape, HEAD_SIZES, A, **kw)
        if method in ("ppo", "ppo_q"):
            self.critic = TorsoNet(shape, HEAD_SIZES, 1 if method == "ppo" else A, **kw)
            return
        self.psi = ImagePsi(cfg, shape, **kw)
        self.q = MLP(cfg.feature_size, (cfg.q_hidden_size,), 1, False, **kw)
        if method == "sf2":
            self.zeta = ImageZeta(cfg, shape, **kw)
        else:
            self.latent_cfg = dataclasses.replace(cfg, obs_size=LATENT_SIZE)
            self.zeta = Zeta(self.latent_cfg, **kw)
            self.encoder = TorsoNet(shape, (), LATENT_SIZE, "lecun", **kw)
            self.decoder = Head(LATENT_SIZE, (), cfg.obs_size, "lecun", **kw)
        self.target_psi = _frozen_copy(self.psi)
        self.target_zeta = _frozen_copy(self.zeta)

    def extra_repr(self) -> str:
        return f"method={self.method!r}, obs_shape={self.obs_shape}"


def make_image_networks(cfg: SF2Config, obs_shape, method: str, *, dtype=None, device=None) -> ImageNetworks:
    """Build and initialise the networks of one MinAtar agent (docs/minatar.md; seed with
    `torch.manual_seed` first).

    The actor: torso → Dense 64 tanh → Dense 64 tanh → A logits; "ppo"'s critic → 1 (V), "ppo_q"'s → A
    (Q(s, ·)); ψ(s, ·): torso → MLP(cfg.hidden_sizes, LayerNorm per cfg.layer_norm) → A·F, ψ(s, a) = row
    a; Q head: Dense(F → cfg.q_hidden_size) → ReLU → Dense(→ 1) on ψ; "sf2"'s ζ: convolutions of widths
    cfg.zeta_hidden_sizes, then the ψ-conditioned 1×1 layer; "sf2_ae"'s ζ: the core's vector ζ (MLP of
    widths cfg.zeta_hidden_sizes on [z, embedding(k)] → F·64); encoder: torso → Dense 64 → tanh; decoder:
    Dense(64 → H·W·C) logits.

    Args:
      cfg: the `SF2Config`: obs_size = H·W·C, action_size = A (the number of actions), the sizes above and
        the flow loss's hyperparameters.
      obs_shape: (H, W, C) of the grid.
      method: one of `METHODS`: "ppo", "ppo_q", "sf2" (SF² w/o AE), "sf2_ae" (SF² w AE).
      dtype: of every parameter (default: torch's default dtype).
      device: where they live.

    Returns:
      The `ImageNetworks`.

    Raises:
      ConfigError: `cfg` not an `SF2Config`, an unknown `method`, an invalid `obs_shape` or one whose size
        is not cfg.obs_size.
    """
    return ImageNetworks(cfg, obs_shape, method, dtype=dtype, device=device)


@dataclasses.dataclass(frozen=True)
class LatentView:
    """The core's view of the latent flow of "sf2_ae": `cfg` (obs_size 64) and ζ, ζ̄ (vector `Zeta`), what
    `sf2_torch.networks`' ζ functions (`contract`, `velocity`, ...) read of their `nets`."""

    cfg: SF2Config
    zeta: nn.Module
    target_zeta: nn.Module


def latent_networks(nets: ImageNetworks) -> LatentView:
    """The vector core's view of the latent flow of "sf2_ae": `sf2_torch.networks` functions (`contract`,
    `velocity`, ...) called with it use the groups `zeta` and `target_zeta`.

    Args:
      nets: "sf2_ae" `ImageNetworks`.

    Returns:
      A `LatentView` whose cfg is `nets.cfg` with obs_size = `LATENT_SIZE`.

    Raises:
      ConfigError: networks of another method.
    """
    _require(nets, ("sf2_ae",), "latent_networks")
    return LatentView(nets.latent_cfg, nets.zeta, nets.target_zeta)


# ------------------------------------------------------------------------------------------ checks
def _require(nets: ImageNetworks, methods: tuple[str, ...], fn: str) -> None:
    if not isinstance(nets, ImageNetworks):
        raise ConfigError(f"{fn} needs ImageNetworks, found {type(nets).__name__}")
    if nets.method not in methods:
        raise ConfigError(f"{fn} needs image networks built with method "
                          f"{' or '.join(repr(m) for m in methods)}, found method={nets.method!r}")


def _dtype_name(x: torch.Tensor) -> str:
    return str(x.dtype).removeprefix("torch.")


def _host_values(x: torch.Tensor):
    """x when its values are readable without a device synchronization (on the CPU, not under
    torch.compile); else None (the value checks are then skipped)."""
    if x.device.type != "cpu" or torch.compiler.is_compiling():
        return None
    return x.detach()


def check_obs(nets: ImageNetworks, name: str, obs: torch.Tensor,
              batch_shape: tuple | None = None) -> tuple[int]:
    """Check a batch of grids: shape (B, H, W, C), a floating-point dtype (never bool).

    Args:
      nets: the `ImageNetworks` (its obs_shape).
      name: the argument's name, for the message.
      obs: the tensor.
      batch_shape: (B,) it must have; None: any single batch dimension.

    Returns:
      The batch shape (B,).

    Raises:
      ShapeError: another shape or a non-floating dtype.
    """
    shape = tuple(obs.shape)
    if len(shape) != 4 or shape[1:] != nets.obs_shape or (batch_shape is not None
                                                         and shape[:1] != tuple(batch_shape)):
        lead = "B" if batch_shape is None else batch_shape[0]
        raise ShapeError(f"{name} must have shape ({lead}, {', '.join(map(str, nets.obs_shape))}) (a batch "
                         f"of grids, NHWC), found {shape}")
    if not obs.is_floating_point():
        raise ShapeError(f"{name} must be a floating-point array (the grid's cells as 0.0 and 1.0), found "
                         f"dtype {_dtype_name(obs)}")
    return shape[:1]


def check_actions(nets: ImageNetworks, name: str, action: torch.Tensor, batch_shape: tuple) -> None:
    """Check action indices: shape (B,), an integer dtype, and (where readable, `_host_values`) in [0, A).

    Args:
      nets: the `ImageNetworks` (A = cfg.action_size).
      name: the argument's name, for the message.
      action: the tensor.
      batch_shape: (B,).

    Raises:
      ShapeError: another shape, a non-integer dtype, or an index outside [0, A).
    """
    shape = tuple(action.shape)
    if shape != tuple(batch_shape):
        raise ShapeError(f"{name} must have shape {tuple(batch_shape)} (one action index per sample), "
                         f"found {shape}")
    if action.is_floating_point() or action.is_complex() or action.dtype == torch.bool:
        raise ShapeError(f"{name} must be an integer array of action indices, found dtype "
                         f"{_dtype_name(action)}")
    values = _host_values(action)
    A = nets.cfg.action_size
    if values is not None and values.numel() and (values.min() < 0 or values.max() >= A):
        raise ShapeError(f"{name} must hold action indices in [0, {A}), found values from "
                         f"{int(values.min())} to {int(values.max())}")


def check_flow_time(flow_time: torch.Tensor, batch_shape: tuple) -> None:
    """Check flow times: shape (B,) and (where readable, `_host_values`) in [0, 1].

    Args:
      flow_time: k, the tensor.
      batch_shape: (B,).

    Raises:
      ShapeError: another shape, or a value outside [0, 1].
    """
    shape = tuple(flow_time.shape)
    if shape != tuple(batch_shape):
        raise ShapeError(f"flow_time must have shape {tuple(batch_shape)} (one flow time per sample), "
                         f"found {shape}")
    values = _host_values(flow_time)
    if values is not None and values.numel() and not (values.min() >= 0 and values.max() <= 1):
        raise ShapeError(f"flow_time must lie in [0, 1], found values from {float(values.min())!r} to "
                         f"{float(values.max())!r}")


# ------------------------------------------------------------------------------------------ actor, critics
def policy_logits(nets: ImageNetworks, obs: torch.Tensor) -> torch.Tensor:
    """The actor's logits: torso → Dense 64 tanh → Dense 64 tanh → Dense A.

    Args:
      nets: the `ImageNetworks`.
      obs: grids (B, H, W, C).

    Returns:
      (B, A).

    Raises:
      ShapeError: `obs` of another shape or dtype.
    """
    check_obs(nets, "obs", obs)
    return nets.actor(obs)


def categorical_log_prob(logits: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
    """log π(a|s) = log_softmax(logits)[a].

    Args:
      logits: (B, A).
      action: integer indices (B,).

    Returns:
      (B,).
    """
    return torch.log_softmax(logits, dim=-1).gather(-1, action.long()[..., None])[..., 0]


def categorical_entropy(logits: torch.Tensor) -> torch.Tensor:
    """The entropy of the categorical policy: −Σ_a π(a|s) log π(a|s).

    Args:
      logits: (B, A).

    Returns:
      (B,).
    """
    log_p = torch.log_softmax(logits, dim=-1)
    return -(log_p.exp() * log_p).sum(-1)


def state_value(nets: ImageNetworks, obs: torch.Tensor) -> torch.Tensor:
    """V(s), "ppo"'s critic: torso → Dense 64 tanh → Dense 64 tanh → Dense 1.

    Args:
      nets: "ppo" `ImageNetworks`.
      obs: grids (B, H, W, C).

    Returns:
      (B,).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `obs` of another shape or dtype.
    """
    _require(nets, ("ppo",), "state_value")
    check_obs(nets, "obs", obs)
    return nets.critic(obs)[..., 0]


def action_values(nets: ImageNetworks, obs: torch.Tensor) -> torch.Tensor:
    """Q(s, ·): "ppo_q"'s critic (torso → Dense 64 tanh ×2 → Dense A), or SF²'s Q head on ψ(s, ·).

    Args:
      nets: "ppo_q", "sf2" or "sf2_ae" `ImageNetworks`.
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
        return nets.critic(obs)
    return q_head(nets, psi_all(nets, obs))


def expected_value(logits: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """V_Q(s) = Σ_a π(a|s) Q(s, a), exact for discrete actions.

    Args:
      logits: the actor's logits (B, A).
      q: Q(s, ·) (B, A).

    Returns:
      (B,).
    """
    return (torch.softmax(logits, dim=-1) * q).sum(-1)


# ------------------------------------------------------------------------------------------ ψ and Q
def psi_all(nets: ImageNetworks, obs: torch.Tensor, target: bool = False) -> torch.Tensor:
    """ψ(s, ·): every action's feature, row a of the (A, F) reshape of the A·F outputs (entry a·F + f).

    Args:
      nets: "sf2" or "sf2_ae" `ImageNetworks`.
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
    out = (nets.target_psi if target else nets.psi)(obs)
    return out.reshape(*out.shape[:-1], nets.cfg.action_size, nets.cfg.feature_size)


def psi(nets: ImageNetworks, obs: torch.Tensor, action: torch.Tensor, target: bool = False) -> torch.Tensor:
    """ψ(s, a): row a of `psi_all`.

    Args:
      nets: "sf2" or "sf2_ae" `ImageNetworks`.
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
    rows = psi_all(nets, obs, target)
    return rows.gather(1, action.long()[:, None, None].expand(-1, 1, rows.shape[-1]))[:, 0]


def q_head(nets: ImageNetworks, features: torch.Tensor) -> torch.Tensor:
    """SF²'s Q on features: Dense(F → q_hidden_size) → ReLU → Dense(→ 1), applied to each feature row.

    Args:
      nets: "sf2" or "sf2_ae" `ImageNetworks`.
      features: ψ (..., F).

    Returns:
      (...).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `features` of another last dimension.
    """
    _require(nets, ("sf2", "sf2_ae"), "q_head")
    check_last("features", features, nets.cfg.feature_size, "feature_size")
    return nets.q(features)[..., 0]


# ------------------------------------------------------------------------------------------ the image ζ
def zeta_hidden(nets: ImageNetworks, x: torch.Tensor, k, target: bool = False) -> torch.Tensor:
    """h(x, k): the image ζ's per-pixel features, its convolutions on [grid of x, embedding(k)].

    With `cfg.contract_zeta` (the fast path) the embedding's part of the first convolution is formed once
    per sample and tap (`ImageZeta.hidden_split`); otherwise the convolution runs over the embedding
    broadcast to every pixel (the oracle).

    Args:
      nets: "sf2" `ImageNetworks`.
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
    module = nets.target_zeta if target else nets.zeta
    return module.hidden_split(x, k) if nets.cfg.contract_zeta else module.hidden(x, k)


def _last(nets: ImageNetworks, target: bool) -> tuple[torch.Tensor, torch.Tensor]:
    last = (nets.target_zeta if target else nets.zeta).last
    return last.kernel, last.bias


def zeta(nets: ImageNetworks, x: torch.Tensor, k, target: bool = False) -> torch.Tensor:
    """The image ζ(x, k) materialized (the plain formulation, a test oracle): ζ_{(p,c),f} = Σ_h h_{p,h}
    W_{h,c,f} + b_{c,f}, p a pixel, c a channel, row (p, c) = the flattened grid's index p·C + c.

    Args:
      nets: "sf2" `ImageNetworks`.
      x: flattened grids (B, D).
      k: the flow time (B,) (or a scalar).
      target: the target ζ̄ instead of the online ζ.

    Returns:
      (B, D, F).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `x` or `k` of another shape.
    """
    h = zeta_hidden(nets, x, k, target)
    W, b = _last(nets, target)
    out = torch.einsum("bpqh,hcf->bpqcf", h, W) + b
    return out.reshape(out.shape[0], nets.cfg.obs_size, nets.cfg.feature_size)


def velocity(nets: ImageNetworks, x: torch.Tensor, k, features: torch.Tensor,
             target: bool = False) -> torch.Tensor:
    """The plain velocity u = ζ(x, k)ψ, u_d = Σ_f ζ_{d f} ψ_f, through the materialized ζ (test oracle).

    Args:
      nets: "sf2" `ImageNetworks`.
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
    check_last("features", features, nets.cfg.feature_size, "feature_size")
    return torch.einsum("bdf,bf->bd", zeta(nets, x, k, target), features)


def contract(nets: ImageNetworks, features: torch.Tensor,
             target: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Contract the 1×1 layer with ψ once: M = Wψ, M_{h,c} = Σ_f W_{h,c,f} ψ_f, and c_c = Σ_f b_{c,f} ψ_f.

    Args:
      nets: "sf2" `ImageNetworks`.
      features: ψ (B, F).
      target: the target ζ̄ instead of the online ζ.

    Returns:
      (M (B, H_ζ, C), c (B, C)).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `features` of another last dimension.
    """
    _require(nets, ("sf2",), "contract")
    check_last("features", features, nets.cfg.feature_size, "feature_size")
    W, b = _last(nets, target)
    return torch.einsum("bf,hcf->bhc", features, W), torch.einsum("bf,cf->bc", features, b)


def velocity_contracted(nets: ImageNetworks, x: torch.Tensor, k, M: torch.Tensor, c: torch.Tensor,
                        target: bool = False) -> torch.Tensor:
    """The fast velocity u_{p,c} = Σ_h h_{p,h} M_{h,c} + c_c, equal to `velocity` without forming ζ.

    Args:
      nets: "sf2" `ImageNetworks`.
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
    h = zeta_hidden(nets, x, k, target)
    expected = ((h.shape[0], h.shape[-1], nets.obs_shape[2]), (h.shape[0], nets.obs_shape[2]))
    if (tuple(M.shape), tuple(c.shape)) != expected:
        raise ShapeError(f"contracted (M, c) must have shapes {expected[0]} (B, H_zeta, C) and {expected[1]} "
                         f"(B, C), found {tuple(M.shape)} and {tuple(c.shape)}")
    u = torch.einsum("bpqh,bhc->bpqc", h, M) + c[:, None, None, :]
    return u.reshape(u.shape[0], nets.cfg.obs_size)


# ------------------------------------------------------------------------------------------ autoencoder
def encode(nets: ImageNetworks, obs: torch.Tensor) -> torch.Tensor:
    """The encoder: z = tanh(Dense 64(torso(s))) ∈ [−1, 1]^64.

    Args:
      nets: "sf2_ae" `ImageNetworks`.
      obs: grids (B, H, W, C).

    Returns:
      (B, 64).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `obs` of another shape or dtype.
    """
    _require(nets, ("sf2_ae",), "encode")
    check_obs(nets, "obs", obs)
    return torch.tanh(nets.encoder(obs))


def decode_logits(nets: ImageNetworks, z: torch.Tensor) -> torch.Tensor:
    """The decoder: Dense(64 → H·W·C), the Bernoulli logits of every cell.

    Args:
      nets: "sf2_ae" `ImageNetworks`.
      z: latents (B, 64).

    Returns:
      (B, H, W, C).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `z` of another last dimension.
    """
    _require(nets, ("sf2_ae",), "decode_logits")
    check_last("z", z, LATENT_SIZE, "the latent size")
    out = nets.decoder(z)
    return out.reshape(*out.shape[:-1], *nets.obs_shape)
