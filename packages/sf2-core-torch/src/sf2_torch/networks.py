"""Networks of SF²: ψ, ζ, twin Q heads, TD3 and SAC policies, observation normalizer, flow-time embedding.

Paper: Definition 3.1 (u = ζ(x, k)ᵀψ(s, a)), Appendix E (architectures); docs/core-contract.md "Networks"
and "Notation" (B batch, D = obs_size, A = action_size, F = feature_size, H = width of ζ's last hidden
layer, E = embedding_size; `flow_time` k ∈ [0, 1] is the flow time, never the MDP step).

Every network is an `MLP` whose children are named `dense_{i}` (`nn.Linear`) and `layer_norm_{i}`
(`nn.LayerNorm`, ε = 1e-6), so `params.to_canonical` maps module paths to the canonical names. A hidden
layer is Dense → ReLU → LayerNorm, the last layer Dense only; LeCun-uniform kernels, zero biases.
`make_networks(cfg, algo)` builds a `Networks` module of the online networks, their frozen target copies
and, for SAC, `log_alpha`. The functional helpers (`psi`, `zeta`, `velocity`, `contract`, ...) have the
JAX core's signatures without its `params` argument, and every input is shape-checked (`check_last`): a
wrong size raises `ShapeError` naming the expected and the found sizes before any torch op runs.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence

import torch
import torch.nn.functional as F
from sf2_common.config import SF2Config
from sf2_common.embedding import EMBEDDING_K_GRID, embedding_turns
from sf2_common.errors import ConfigError, ShapeError
from torch import nn

__all__ = [
    # the JAX core's names, in its order (`init_params` aside: torch modules hold their parameters)
    "ALGOS", "LAYER_NORM_EPS", "MLP", "TwinQ", "Networks", "make_networks", "init_normalizer",
    "normalize", "update_normalizer", "flow_time_embedding", "psi", "zeta", "zeta_hidden",
    "zeta_last_layer", "velocity", "contract", "velocity_contracted", "q_values", "td3_action",
    "sac_distribution", "sac_sample", "sac_mode", "check_last",
    # torch's modules and helpers
    "Psi", "Zeta", "QHead", "twin_heads", "TD3Policy", "SACPolicy", "ObsNormalizer", "lecun_uniform_",
]

ALGOS = ("td3", "sac")
LAYER_NORM_EPS = 1e-6
_LOG_2PI = math.log(2.0 * math.pi)
_LOG_2 = math.log(2.0)


# ----------------------------------------------------------------------------------------------- checks
def check_last(name: str, tensor: torch.Tensor, size: int, what: str) -> None:
    """Check the last dimension of an input on its shape (no host synchronization).

    Args:
      name: the argument's name, for the message.
      tensor: the tensor.
      size: its last dimension.
      what: the config field `size` is, for the message ("obs_size", "action_size", ...).

    Raises:
      ShapeError: `tensor` is a scalar or its last dimension differs, naming both sizes.
    """
    if tensor.ndim < 1 or tensor.shape[-1] != size:
        found = tuple(tensor.shape)
        last = found[-1] if found else "none (a scalar)"
        raise ShapeError(f"{name} must have last dimension {what} = {size}, found {last} (shape {found})")


def _check_batch(name: str, tensor: torch.Tensor, other_name: str, other: torch.Tensor) -> None:
    if tuple(tensor.shape[:-1]) != tuple(other.shape[:-1]):
        raise ShapeError(
            f"{name} has batch shape {tuple(tensor.shape[:-1])} but {other_name} has batch shape "
            f"{tuple(other.shape[:-1])}; they must match"
        )


def _flow_time_column(k: torch.Tensor | float, x: torch.Tensor) -> torch.Tensor:
    """k as a (B,) tensor matching x (B, D): accepts (B,), (B, 1) or a scalar."""
    k = torch.as_tensor(k, dtype=x.dtype, device=x.device)
    if k.ndim == 0:
        return k.expand(x.shape[:-1])
    if k.ndim == x.ndim and k.shape[-1] == 1:
        k = k.squeeze(-1)
    if tuple(k.shape) != tuple(x.shape[:-1]):
        raise ShapeError(
            f"flow_time must have shape {tuple(x.shape[:-1])} (one k per sample of x), found {tuple(k.shape)}"
        )
    return k


# -------------------------------------------------------------------------------------------- building
@torch.no_grad()
def lecun_uniform_(layer: nn.Linear) -> nn.Linear:
    """LeCun-uniform kernel U(±√(3/fan_in)) and zero bias, in place."""
    bound = math.sqrt(3.0 / layer.in_features)
    layer.weight.uniform_(-bound, bound)
    if layer.bias is not None:
        layer.bias.zero_()
    return layer


class MLP(nn.Module):
    """Dense → ReLU → [LayerNorm] per hidden width, then a last Dense.

    Children: `dense_0 .. dense_{n}` (`nn.Linear`) and, when `layer_norm`, `layer_norm_0 .. layer_norm_{n-1}`
    (`nn.LayerNorm(eps=1e-6)`), n = len(hidden_sizes).
    """

    def __init__(
        self,
        in_size: int,
        hidden_sizes: Sequence[int],
        out_size: int,
        layer_norm: bool = True,
        *,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        self.in_size = int(in_size)
        self.out_size = int(out_size)
        self.hidden_sizes = tuple(int(h) for h in hidden_sizes)
        self.layer_norm = bool(layer_norm)
        self.num_hidden = len(self.hidden_sizes)
        fan_in = self.in_size
        for i, width in enumerate(self.hidden_sizes):
            self.add_module(
                f"dense_{i}", lecun_uniform_(nn.Linear(fan_in, width, dtype=dtype, device=device))
            )
            if self.layer_norm:
                self.add_module(
                    f"layer_norm_{i}", nn.LayerNorm(width, eps=LAYER_NORM_EPS, dtype=dtype, device=device)
                )
            fan_in = width
        self.add_module(
            f"dense_{self.num_hidden}",
            lecun_uniform_(nn.Linear(fan_in, self.out_size, dtype=dtype, device=device)),
        )

    @property
    def last(self) -> nn.Linear:
        """The last Dense layer."""
        return getattr(self, f"dense_{self.num_hidden}")

    @property
    def hidden_size(self) -> int:
        """Width of the input of the last layer (H for ζ)."""
        return self.last.in_features

    def trunk(self, x: torch.Tensor) -> torch.Tensor:
        """Everything before the last Dense."""
        for i in range(self.num_hidden):
            x = F.relu(getattr(self, f"dense_{i}")(x))
            if self.layer_norm:
                x = getattr(self, f"layer_norm_{i}")(x)
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.last(self.trunk(x))


class Psi(MLP):
    """ψ(s, a): MLP(hidden_sizes → F) on concat[normalized s, a] (input D + A). Returns (B, F)."""

    def __init__(self, cfg: SF2Config, **kw) -> None:
        super().__init__(
            cfg.obs_size + cfg.action_size, cfg.hidden_sizes, cfg.feature_size, cfg.layer_norm, **kw
        )
        self.obs_size, self.action_size = cfg.obs_size, cfg.action_size

    def forward(self, obs_normalized: torch.Tensor, action: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        check_last("obs", obs_normalized, self.obs_size, "obs_size")
        check_last("action", action, self.action_size, "action_size")
        _check_batch("action", action, "obs", obs_normalized)
        return super().forward(torch.cat([obs_normalized, action], dim=-1))


class Zeta(MLP):
    """ζ(x, k): MLP(zeta_hidden_sizes → F·D) on concat[x, embedding(k)] (input D + E), reshaped (B, D, F).

    Entry (d, f) of the (D, F) matrix is output index d·F + f (row-major). `hidden(x, k)` → (B, H) is
    everything before the last Dense (`last`, weight (F·D, H) in torch layout), used by the fast path.
    """

    def __init__(self, cfg: SF2Config, **kw) -> None:
        super().__init__(
            cfg.obs_size + cfg.embedding_size,
            cfg.zeta_hidden_sizes,
            cfg.feature_size * cfg.obs_size,
            cfg.layer_norm,
            **kw,
        )
        self.obs_size, self.feature_size, self.embedding_size = (
            cfg.obs_size,
            cfg.feature_size,
            cfg.embedding_size,
        )

    def hidden(self, x: torch.Tensor, k: torch.Tensor | float) -> torch.Tensor:
        check_last("x", x, self.obs_size, "obs_size")
        k = _flow_time_column(k, x)
        return self.trunk(torch.cat([x, flow_time_embedding(k, self.embedding_size)], dim=-1))

    def forward(self, x: torch.Tensor, k: torch.Tensor | float) -> torch.Tensor:  # type: ignore[override]
        out = self.last(self.hidden(x, k))
        return out.reshape(*out.shape[:-1], self.obs_size, self.feature_size)

    def last_dense(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(W viewed as (D, F, H), b viewed as (D, F)): the torch-layout last layer, split by (d, f)."""
        w, b = self.last.weight, self.last.bias
        return w.view(self.obs_size, self.feature_size, w.shape[-1]), b.view(self.obs_size, self.feature_size)


class QHead(MLP):
    """One Q head: Dense(F → q_hidden_size) → ReLU → Dense(→ 1), no LayerNorm (authors' code)."""

    def __init__(self, cfg: SF2Config, **kw) -> None:
        super().__init__(cfg.feature_size, (cfg.q_hidden_size,), 1, False, **kw)


def twin_heads(head_0: MLP, head_1: MLP, x: torch.Tensor) -> torch.Tensor:
    """Two MLP heads of one shape on one input as one program: `torch.cat([head_0(x), head_1(x)], -1)`.

    The first layer's two weights stacked make one GEMM on the shared input (forward, and one each for the
    weight and the input gradient); each later hidden layer is one batched product over the two heads
    (`torch.baddbmm`); the LayerNorms normalize both heads at once and scale by each head's own weight and
    bias; the output layers are one elementwise product and row sum. Each head keeps its own parameters (the
    canonical names), and the values equal the plain `cat` up to float rounding. torch.compile does not merge
    two modules' products by itself (docs/decisions/torch-trainer-step.md).

    Args:
      head_0, head_1: MLPs of one shape with one output each.
      x: their input (..., in).

    Returns:
      (..., 2).
    """
    if head_0.num_hidden == 0:
        return torch.cat([head_0(x), head_1(x)], dim=-1)

    def pair(layer: str, name: str) -> torch.Tensor:
        return torch.stack([getattr(getattr(head_0, layer), name), getattr(getattr(head_1, layer), name)])

    lead, x = x.shape[:-1], x.reshape(-1, x.shape[-1])
    h = x
    for i in range(head_0.num_hidden):
        weight, bias = pair(f"dense_{i}", "weight"), pair(f"dense_{i}", "bias")   # (2, out, in), (2, out)
        if i == 0:   # one GEMM on the shared input, viewed (2, N, out)
            h = F.linear(x, weight.flatten(0, 1), bias.flatten()).unflatten(-1, (2, -1)).transpose(0, 1)
        else:
            h = torch.baddbmm(bias.unsqueeze(1), h, weight.transpose(1, 2))
        h = F.relu(h)
        if head_0.layer_norm:
            norm = getattr(head_0, f"layer_norm_{i}")
            h = (F.layer_norm(h, h.shape[-1:], eps=norm.eps) * pair(f"layer_norm_{i}", "weight").unsqueeze(1)
                 + pair(f"layer_norm_{i}", "bias").unsqueeze(1))
    last = f"dense_{head_0.num_hidden}"
    out = (h * pair(last, "weight")).sum(-1) + pair(last, "bias")               # (2, N)
    return out.transpose(0, 1).reshape(*lead, 2)


class TwinQ(nn.Module):
    """Two independent heads `head_0`, `head_1` on ψ features; `forward(features)` → (B, 2), both heads
    as one product (`twin_heads`)."""

    def __init__(self, cfg: SF2Config, **kw) -> None:
        super().__init__()
        self.feature_size = cfg.feature_size
        self.head_0 = QHead(cfg, **kw)
        self.head_1 = QHead(cfg, **kw)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        check_last("features", features, self.feature_size, "feature_size")
        return twin_heads(self.head_0, self.head_1, features)


class TD3Policy(MLP):
    """Deterministic policy: tanh(MLP(hidden_sizes → A)(normalized s)) ∈ [-1, 1]^A."""

    def __init__(self, cfg: SF2Config, **kw) -> None:
        super().__init__(cfg.obs_size, cfg.hidden_sizes, cfg.action_size, cfg.layer_norm, **kw)
        self.obs_size = cfg.obs_size

    def forward(self, obs_normalized: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        check_last("obs", obs_normalized, self.obs_size, "obs_size")
        return torch.tanh(super().forward(obs_normalized))


class SACPolicy(MLP):
    """Tanh-Gaussian policy: MLP(hidden_sizes → 2A)(normalized s) = [loc, pre-std].

    σ = softplus(pre-std) + min_std. With standard-normal ξ: u = loc + σξ, a = tanh(u),
    log π(a|s) = Σ_i [−½ξ_i² − log σ_i − ½ log 2π] − Σ_i 2(log 2 − u_i − softplus(−2u_i)).
    """

    def __init__(self, cfg: SF2Config, **kw) -> None:
        super().__init__(cfg.obs_size, cfg.hidden_sizes, 2 * cfg.action_size, cfg.layer_norm, **kw)
        self.obs_size, self.action_size, self.min_std = cfg.obs_size, cfg.action_size, cfg.min_std

    def forward(self, obs_normalized: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # type: ignore[override]
        """(loc, σ), each (B, A)."""
        check_last("obs", obs_normalized, self.obs_size, "obs_size")
        out = super().forward(obs_normalized)
        loc, pre_std = out[..., : self.action_size], out[..., self.action_size :]
        return loc, F.softplus(pre_std) + self.min_std

    def sample(self, obs_normalized: torch.Tensor, noise: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(action (B, A), log π(action|s) (B,)) for explicit standard-normal `noise` ξ (B, A)."""
        check_last("noise", noise, self.action_size, "action_size")
        _check_batch("noise", noise, "obs", obs_normalized)
        loc, std = self(obs_normalized)
        u = loc + std * noise
        gauss = (-0.5 * noise.square() - torch.log(std) - 0.5 * _LOG_2PI).sum(-1)
        log_det = (2.0 * (_LOG_2 - u - F.softplus(-2.0 * u))).sum(-1)
        return torch.tanh(u), gauss - log_det

    def deterministic(self, obs_normalized: torch.Tensor) -> torch.Tensor:
        """tanh(loc)."""
        return torch.tanh(self(obs_normalized)[0])


class ObsNormalizer(nn.Module):
    """Running observation statistics (Brax `running_statistics`).

    Buffers: count (), mean (D,), summed_var (D,), std (D,); initial state count 0, mean 0,
    summed_var 0, std 1. `forward(obs)` = (obs − mean) / std.
    """

    count: torch.Tensor
    mean: torch.Tensor
    summed_var: torch.Tensor
    std: torch.Tensor

    def __init__(
        self,
        obs_size: int,
        std_min: float = 1e-6,
        std_max: float = 1e6,
        *,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        self.obs_size, self.std_min, self.std_max = int(obs_size), float(std_min), float(std_max)
        kw = dict(dtype=dtype or torch.get_default_dtype(), device=device)
        self.register_buffer("count", torch.zeros((), **kw))
        self.register_buffer("mean", torch.zeros(self.obs_size, **kw))
        self.register_buffer("summed_var", torch.zeros(self.obs_size, **kw))
        self.register_buffer("std", torch.ones(self.obs_size, **kw))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return normalize(obs, self)

    @torch.no_grad()
    def update(self, obs_batch: torch.Tensor) -> ObsNormalizer:
        """Welford update over every leading dimension of `obs_batch` (..., D), in place."""
        new = _running_update(self._stats(), obs_batch, self.obs_size, self.std_min, self.std_max)
        for name, value in new.items():
            getattr(self, name).copy_(value)
        return self

    def _stats(self) -> dict[str, torch.Tensor]:
        return {"count": self.count, "mean": self.mean, "summed_var": self.summed_var, "std": self.std}


class Networks(nn.Module):
    """All networks of one SF² agent (canonical groups of docs/core-contract.md as attributes).

    `obs_norm`, `psi`, `zeta`, `q`, `policy`, `target_psi`, `target_zeta`, `target_q`, and
    `target_policy` (TD3) or the `log_alpha` parameter (SAC, shape ()). Targets are deep copies of the
    online networks with `requires_grad=False`. `cfg` and `algo` are kept as plain attributes.
    """

    def __init__(
        self,
        cfg: SF2Config,
        algo: str = "td3",
        *,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        if not isinstance(cfg, SF2Config):
            raise ConfigError(f"cfg must be an SF2Config, found {type(cfg).__name__}")
        if algo not in ALGOS:
            raise ConfigError(f"algo={algo!r} is invalid: must be one of {', '.join(repr(a) for a in ALGOS)}")
        self.cfg, self.algo = cfg, algo
        kw = dict(dtype=dtype, device=device)
        self.obs_norm = ObsNormalizer(cfg.obs_size, cfg.normalizer_std_min, cfg.normalizer_std_max, **kw)
        self.psi = Psi(cfg, **kw)
        self.zeta = Zeta(cfg, **kw)
        self.q = TwinQ(cfg, **kw)
        self.policy = TD3Policy(cfg, **kw) if algo == "td3" else SACPolicy(cfg, **kw)
        self.target_psi = _frozen_copy(self.psi)
        self.target_zeta = _frozen_copy(self.zeta)
        self.target_q = _frozen_copy(self.q)
        if algo == "td3":
            self.target_policy = _frozen_copy(self.policy)
        else:
            self.log_alpha = nn.Parameter(
                torch.full((), cfg.init_log_alpha, dtype=dtype or torch.get_default_dtype(), device=device)
            )

    def online_modules(self) -> dict[str, nn.Module]:
        """The trained networks by canonical group name (without `log_alpha`)."""
        return {"psi": self.psi, "zeta": self.zeta, "q": self.q, "policy": self.policy}

    def target_modules(self) -> dict[str, nn.Module]:
        """The target networks by canonical group name."""
        out = {"target_psi": self.target_psi, "target_zeta": self.target_zeta, "target_q": self.target_q}
        if self.algo == "td3":
            out["target_policy"] = self.target_policy
        return out

    def extra_repr(self) -> str:
        return f"algo={self.algo!r}"


def _frozen_copy(module: nn.Module) -> nn.Module:
    return copy.deepcopy(module).requires_grad_(False)


def make_networks(
    cfg: SF2Config,
    algo: str = "td3",
    *,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> Networks:
    """Build the networks of one SF² agent and initialise them (seed with `torch.manual_seed` first).

    ψ: MLP(hidden_sizes → F) on [normalize(s), a]; ζ: MLP(zeta_hidden_sizes → F·D) on [x, embedding(k)];
    Q: twin heads on ψ; policy: MLP(hidden_sizes → A (TD3) or 2A (SAC)) on normalize(s) (Appendix E).
    Draw order: ψ, ζ, Q head 0, Q head 1, policy; targets copy the online networks.

    Args:
      cfg: the `SF2Config`.
      algo: "td3" or "sac".
      dtype: of every parameter (default: torch's default dtype).
      device: where they live.

    Returns:
      The `Networks`: online networks, their frozen target copies and, for SAC, `log_alpha`.

    Raises:
      ConfigError: `cfg` is not an `SF2Config`, or `algo` is neither "td3" nor "sac".
    """
    return Networks(cfg, algo, dtype=dtype, device=device)


# ------------------------------------------------------------------------------------ functional helpers
# Exact phase reduction of the flow-time embedding: the tables come from sf2_common.embedding.


_TABLES: dict[tuple, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}


def _embedding_tables(size: int, dtype: torch.dtype, device: torch.device):
    """`embedding_turns(size)` as tensors of `dtype` on `device`, made once per (size, dtype, device):
    a host-to-device copy on every call would be illegal inside a CUDA graph capture (the capture's
    warm-up calls fill the cache first)."""
    key = (size, dtype, device)
    if key not in _TABLES:
        _TABLES[key] = tuple(torch.as_tensor(v, dtype=dtype, device=device) for v in embedding_turns(size))
    return _TABLES[key]


def flow_time_embedding(k: torch.Tensor, size: int) -> torch.Tensor:
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
    k = torch.as_tensor(k)
    if not k.is_floating_point():
        k = k.to(torch.get_default_dtype())
    turns, hi, lo = _embedding_tables(size, k.dtype, k.device)
    k_hi = torch.round(k * EMBEDDING_K_GRID) / EMBEDDING_K_GRID
    k_lo, k_hi = (k - k_hi)[..., None], k_hi[..., None]
    t_hi = k_hi * hi
    t = (t_hi - torch.round(t_hi)) + (k_hi * lo + k_lo * turns)
    arg = t * (2.0 * math.pi)
    return torch.stack([torch.sin(arg), torch.cos(arg)], dim=-1).reshape(*k.shape, size)


def init_normalizer(size: int, dtype: torch.dtype | None = None) -> dict[str, torch.Tensor]:
    """The initial running observation statistics.

    Args:
      size: D.
      dtype: of the statistics (default: torch's default dtype).

    Returns:
      {"count": 0, "mean": zeros (D,), "summed_var": zeros (D,), "std": ones (D,)}.
    """
    kw = dict(dtype=dtype or torch.get_default_dtype())
    return {
        "count": torch.zeros((), **kw),
        "mean": torch.zeros(size, **kw),
        "summed_var": torch.zeros(size, **kw),
        "std": torch.ones(size, **kw),
    }


def _stats_of(stats) -> Mapping[str, torch.Tensor]:
    if isinstance(stats, Networks):
        stats = stats.obs_norm
    if isinstance(stats, ObsNormalizer):
        return stats._stats()
    if isinstance(stats, Mapping):
        return stats
    raise TypeError(f"stats must be an ObsNormalizer or a mapping of tensors, found {type(stats).__name__}")


def normalize(obs: torch.Tensor, stats) -> torch.Tensor:
    """Normalize observations with running statistics (Brax `running_statistics`): (obs − mean) / std.

    Args:
      obs: (..., D).
      stats: an `ObsNormalizer` (or `Networks`, or a mapping with `mean` and `std`).

    Returns:
      (..., D).

    Raises:
      ShapeError: `obs` of another last dimension.
    """
    s = _stats_of(stats)
    check_last("obs", obs, s["mean"].shape[-1], "obs_size")
    return (obs - s["mean"]) / s["std"]


def _running_update(stats, obs_batch, obs_size, std_min, std_max) -> dict[str, torch.Tensor]:
    check_last("obs_batch", obs_batch, obs_size, "obs_size")
    x = obs_batch.reshape(-1, obs_size).to(stats["mean"].dtype)
    if x.shape[0] == 0:
        return dict(stats)
    count = stats["count"] + x.shape[0]
    diff_old = x - stats["mean"]
    mean = stats["mean"] + diff_old.sum(0) / count
    summed_var = stats["summed_var"] + (diff_old * (x - mean)).sum(0)
    std = torch.clamp(torch.sqrt(torch.clamp(summed_var, min=0.0) / count), std_min, std_max)
    return {"count": count, "mean": mean, "summed_var": summed_var, "std": std}


def update_normalizer(stats, obs_batch: torch.Tensor, cfg: SF2Config):
    """Brax's running-statistics update with a batch of observations (Welford).

    std = clip(√(summed_var / count), normalizer_std_min, normalizer_std_max); every leading dimension of
    `obs_batch` is a sample.

    Args:
      stats: an `ObsNormalizer` or `Networks` (updated in place), or a mapping {count, mean, summed_var, std}.
      obs_batch: (..., D).
      cfg: the `SF2Config` (D and the std clip).

    Returns:
      The updated `ObsNormalizer`, or a new mapping when given a mapping.

    Raises:
      ShapeError: `obs_batch` of another last dimension.
    """
    with torch.no_grad():
        if isinstance(stats, Networks):
            stats = stats.obs_norm
        s = _stats_of(stats)
        new = _running_update(s, obs_batch, cfg.obs_size, cfg.normalizer_std_min, cfg.normalizer_std_max)
        if isinstance(stats, ObsNormalizer):
            for name, value in new.items():
                getattr(stats, name).copy_(value)
            return stats
        return new


def psi(nets: Networks, obs: torch.Tensor, action: torch.Tensor, target: bool = False) -> torch.Tensor:
    """ψ(s, a), the time-invariant state-action feature (Definition 3.1), on [normalize(s), a].

    Args:
      nets: the `Networks`.
      obs: raw observations (B, D) (normalized here with the `obs_norm` statistics).
      action: (B, A).
      target: the target network instead of the online one.

    Returns:
      (B, F).

    Raises:
      ShapeError: `obs` or `action` of another last dimension.
    """
    check_last("obs", obs, nets.cfg.obs_size, "obs_size")
    check_last("action", action, nets.cfg.action_size, "action_size")
    net = nets.target_psi if target else nets.psi
    return net(normalize(obs, nets.obs_norm), action)


def zeta(nets: Networks, x: torch.Tensor, k: torch.Tensor, target: bool = False) -> torch.Tensor:
    """ζ(x, k), the time-conditioned matrix field, on [x, embedding(k)].

    Entry (d, f) of the (D, F) matrix is ζ's output d·F + f (row-major).

    Args:
      nets: the `Networks`.
      x: (B, D), in normalized-observation space.
      k: the flow time (B,) (or a scalar).
      target: the target network instead of the online one.

    Returns:
      (B, D, F).

    Raises:
      ShapeError: `x` of another last dimension, or `k` of another batch shape.
    """
    return (nets.target_zeta if target else nets.zeta)(x, k)


def zeta_hidden(nets: Networks, x: torch.Tensor, k: torch.Tensor, target: bool = False) -> torch.Tensor:
    """h(x, k): ζ's MLP up to, not including, its last Dense (the fast path's h).

    Args:
      nets: the `Networks`.
      x: (B, D).
      k: the flow time (B,) (or a scalar).
      target: the target network instead of the online one.

    Returns:
      (B, H).

    Raises:
      ShapeError: `x` of another last dimension, or `k` of another batch shape.
    """
    return (nets.target_zeta if target else nets.zeta).hidden(x, k)


def zeta_last_layer(nets: Networks, target: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """ζ's last Dense layer in canonical layout.

    Args:
      nets: the `Networks`.
      target: the target network instead of the online one.

    Returns:
      (kernel W (H, F·D), a transposed view, bias b (F·D,)).
    """
    last = (nets.target_zeta if target else nets.zeta).last
    return last.weight.T, last.bias


def velocity(
    nets: Networks, x: torch.Tensor, k: torch.Tensor, features: torch.Tensor, target: bool = False
) -> torch.Tensor:
    """The plain velocity u = ζ(x, k)ᵀψ: u_d = Σ_f ζ(x, k)_{d f} ψ_f (Definition 3.1); materializes ζ.

    Args:
      nets: the `Networks`.
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
    return torch.einsum("bdf,bf->bd", zeta(nets, x, k, target), features)


def contract(
    nets: Networks, features: torch.Tensor, target: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """Contract ζ's last layer with ψ once, for the fast path (docs/core-contract.md "Networks").

    M[b, d, h] = Σ_f W[h, d·F + f] ψ[b, f] and c[b, d] = Σ_f b[d·F + f] ψ[b, f]; compute once per (ζ, ψ) and
    reuse for every evaluation at new (x, k). The kernel is re-laid (D, H, F) once per contraction (the stored
    parameter keeps its canonical layout), so one GEMM emits M as (B, D·H) and every `velocity_contracted`
    reduces over M's minor axis (docs/decisions/flow-loss-layout.md).

    Args:
      nets: the `Networks`.
      features: ψ (B, F).
      target: the target network instead of the online one.

    Returns:
      (M (B, D, H), c (B, D)).

    Raises:
      ShapeError: `features` of another last dimension.
    """
    check_last("features", features, nets.cfg.feature_size, "feature_size")
    w, b = (nets.target_zeta if target else nets.zeta).last_dense()  # (D, F, H), (D, F)
    d, h = w.shape[0], w.shape[-1]
    w_t = w.transpose(1, 2).reshape(d * h, w.shape[1])  # (D·H, F), a copy
    m = (features @ w_t.T).view(*features.shape[:-1], d, h)
    c = features @ b.T
    return m, c


def velocity_contracted(
    nets: Networks,
    x: torch.Tensor,
    k: torch.Tensor,
    M: torch.Tensor,
    c: torch.Tensor,
    target: bool = False,
) -> torch.Tensor:
    """The fast velocity u = einsum('bh,bdh->bd', h(x, k), M) + c, equal to `velocity`.

    u is linear in ζ's last layer, so (M, c) from `contract` give it without building ζ (B, D, F).

    Args:
      nets: the `Networks`.
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
    h = zeta_hidden(nets, x, k, target)
    if tuple(M.shape) != (*x.shape, h.shape[-1]) or tuple(c.shape) != tuple(x.shape):
        raise ShapeError(
            f"contracted (M, c) must have shapes {(*x.shape, h.shape[-1])} (B, D, H) and {tuple(x.shape)}, "
            f"found {tuple(M.shape)} and {tuple(c.shape)}"
        )
    return torch.einsum("bh,bdh->bd", h, M) + c


def q_values(nets: Networks, features: torch.Tensor, target: bool = False) -> torch.Tensor:
    """The twin Q heads on features (Appendix D): column j is head j.

    Args:
      nets: the `Networks`.
      features: ψ (B, F).
      target: the target network instead of the online one.

    Returns:
      (B, 2).

    Raises:
      ShapeError: `features` of another last dimension.
    """
    return (nets.target_q if target else nets.q)(features)


def _require(nets: Networks, algo: str, fn: str) -> None:
    if nets.algo != algo:
        raise ConfigError(f"{fn} needs networks built with algo={algo!r}, found algo={nets.algo!r}")


def td3_action(nets: Networks, obs: torch.Tensor, target: bool = False) -> torch.Tensor:
    """The TD3 policy's action tanh(MLP(normalize(s))).

    Args:
      nets: the `Networks`.
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
    return (nets.target_policy if target else nets.policy)(normalize(obs, nets.obs_norm))


def sac_sample(
    nets: Networks, obs: torch.Tensor, noise: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """A tanh-Gaussian sample of the SAC policy with explicit standard-normal noise, and its log-density.

    u = loc + σξ, a = tanh(u),
    log π(a|s) = Σ_i[−½ξ_i² − log σ_i − ½ log 2π] − Σ_i 2(log 2 − u_i − softplus(−2u_i)).

    Args:
      nets: the `Networks`.
      obs: raw observations (B, D).
      noise: ξ (B, A) ~ N(0, I).

    Returns:
      (action (B, A), log_prob (B,)).

    Raises:
      ConfigError: networks built for another algorithm.
      ShapeError: `obs` or `noise` of another shape.
    """
    _require(nets, "sac", "sac_sample")
    check_last("obs", obs, nets.cfg.obs_size, "obs_size")
    return nets.policy.sample(normalize(obs, nets.obs_norm), noise)


def sac_distribution(nets: Networks, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The SAC policy's pre-tanh Gaussian: loc = out[:, :A], σ = softplus(out[:, A:]) + min_std.

    Args:
      nets: the `Networks`.
      obs: raw observations (B, D).

    Returns:
      (loc (B, A), σ (B, A)).

    Raises:
      ConfigError: networks built for another algorithm.
      ShapeError: `obs` of another last dimension.
    """
    _require(nets, "sac", "sac_distribution")
    check_last("obs", obs, nets.cfg.obs_size, "obs_size")
    return nets.policy(normalize(obs, nets.obs_norm))


def sac_mode(nets: Networks, obs: torch.Tensor) -> torch.Tensor:
    """The SAC policy's deterministic action tanh(loc).

    Args:
      nets: the `Networks`.
      obs: raw observations (B, D).

    Returns:
      (B, A).

    Raises:
      ConfigError: networks built for another algorithm.
      ShapeError: `obs` of another last dimension.
    """
    return torch.tanh(sac_distribution(nets, obs)[0])

