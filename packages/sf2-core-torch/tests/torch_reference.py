"""Test helpers: non-trivial float64 networks and batches, and a numpy re-implementation of the contract.

The numpy reference reads only canonical parameters (docs/core-contract.md), so it checks the torch
modules, the canonical layout and the loss formulas at once.
"""

from __future__ import annotations

import numpy as np
import torch
from sf2_torch import SF2Config, losses, networks, params

D, A, B = 3, 2, 6


def make_cfg(**overrides) -> SF2Config:
    return SF2Config.small(D, A, **overrides)


def make_nets(algo: str = "td3", seed: int = 0, **overrides) -> networks.Networks:
    """float64 networks whose every entry is non-trivial (LN scales ≠ 1, targets ≠ online, stats ≠ 0/1)."""
    torch.manual_seed(seed)
    nets = networks.make_networks(make_cfg(**overrides), algo).double()
    rng = np.random.default_rng(seed)
    flat = params.to_canonical(nets)
    for name, v in flat.items():
        if name == "obs_norm.count":
            flat[name] = np.asarray(50.0)
        elif name.endswith("obs_norm.std"):
            flat[name] = rng.uniform(0.5, 2.0, v.shape)
        elif name.endswith("obs_norm.summed_var"):
            flat[name] = rng.uniform(10.0, 100.0, v.shape)
        elif name.endswith(".scale"):
            flat[name] = rng.uniform(0.5, 1.5, v.shape)
        elif name == "log_alpha":
            flat[name] = np.asarray(-0.7)
        elif name.endswith(".kernel"):
            flat[name] = v + rng.normal(0.0, 0.05, v.shape)
        else:
            flat[name] = rng.normal(0.0, 0.1, v.shape)
    params.from_canonical(flat, nets)
    return nets


def make_batch(seed: int = 1, truncation: bool = True):
    rng = np.random.default_rng(seed)
    t = lambda x: torch.as_tensor(x, dtype=torch.float64)  # noqa: E731
    trunc = np.zeros(B)
    if truncation:
        trunc[[1, 4]] = 1.0
    batch = losses.Batch(
        obs=t(rng.normal(0.5, 2.0, (B, D))),
        action=t(rng.uniform(-1, 1, (B, A))),
        reward=t(rng.normal(size=B)),
        discount=t(np.array([1.0, 1.0, 0.0, 1.0, 1.0, 1.0])),
        next_obs=t(rng.normal(0.5, 2.0, (B, D))),
        truncation=t(trunc),
    )
    noise = dict(
        eps=t(rng.normal(size=(B, D))),
        flow_time=t(rng.uniform(size=B)),
        next_action=t(rng.uniform(-1, 1, (B, A))),
        smoothing=t(rng.normal(size=(B, A))),
        noise=t(rng.normal(size=(B, A))),
    )
    return batch, noise


# ------------------------------------------------------------------------------------------ numpy model
def np_layer_norm(x, scale, bias, eps=1e-6):
    mu = x.mean(-1, keepdims=True)
    var = ((x - mu) ** 2).mean(-1, keepdims=True)
    return (x - mu) / np.sqrt(var + eps) * scale + bias


def np_mlp(flat, prefix, x, n_hidden, layer_norm=True):
    for i in range(n_hidden):
        x = np.maximum(x @ flat[f"{prefix}.dense_{i}.kernel"] + flat[f"{prefix}.dense_{i}.bias"], 0.0)
        if layer_norm:
            x = np_layer_norm(
                x, flat[f"{prefix}.layer_norm_{i}.scale"], flat[f"{prefix}.layer_norm_{i}.bias"]
            )
    return x @ flat[f"{prefix}.dense_{n_hidden}.kernel"] + flat[f"{prefix}.dense_{n_hidden}.bias"]


def np_embedding(k, size):
    out = np.zeros((k.shape[0], size))
    for i in range(size // 2):
        omega = np.exp(-2.0 * i * np.log(1e4) / size)
        out[:, 2 * i] = np.sin(1e4 * k * omega)
        out[:, 2 * i + 1] = np.cos(1e4 * k * omega)
    return out


def np_normalize(flat, obs):
    return (obs - flat["obs_norm.mean"]) / flat["obs_norm.std"]


def np_psi(flat, cfg, obs, action, prefix="psi"):
    x = np.concatenate([np_normalize(flat, obs), action], -1)
    return np_mlp(flat, prefix, x, len(cfg.hidden_sizes), cfg.layer_norm)


def np_zeta(flat, cfg, x, k, prefix="zeta"):
    out = np_mlp(
        flat,
        prefix,
        np.concatenate([x, np_embedding(k, cfg.embedding_size)], -1),
        len(cfg.zeta_hidden_sizes),
        cfg.layer_norm,
    )
    z = np.zeros((x.shape[0], cfg.obs_size, cfg.feature_size))
    for d in range(cfg.obs_size):
        for f in range(cfg.feature_size):
            z[:, d, f] = out[:, d * cfg.feature_size + f]
    return z


def np_q(flat, feats, prefix="q"):
    return np.concatenate([np_mlp(flat, f"{prefix}.head_{j}", feats, 1, False) for j in (0, 1)], -1)


def np_flow_loss(flat, cfg, batch, next_action, eps, k):
    """(loss, loss_p, loss_boot) of the contract, in numpy, looping the ODE literally."""
    b = {n: np.asarray(v) for n, v in batch._asdict().items()}
    mask = 1.0 - b["truncation"]
    next_n = np_normalize(flat, b["next_obs"])
    feats = np_psi(flat, cfg, b["obs"], b["action"])
    kc = k[:, None]
    x_k = kc * next_n + (1 - kc) * eps
    u_p = np.einsum("bdf,bf->bd", np_zeta(flat, cfg, x_k, k), feats)
    l_p = ((u_p - (next_n - eps)) ** 2).sum(-1)
    feats_bar = np_psi(flat, cfg, b["next_obs"], next_action, prefix="target_psi")

    def field(x, kk):
        return np.einsum("bdf,bf->bd", np_zeta(flat, cfg, x, kk, prefix="target_zeta"), feats_bar)

    x = eps.copy()
    h = k / cfg.denoising_steps
    for i in range(cfg.denoising_steps):
        ki = i * h
        if cfg.integrator == "midpoint":
            x_mid = x + (h / 2)[:, None] * field(x, ki)
            x = x + h[:, None] * field(x_mid, ki + h / 2)
        else:
            x = x + h[:, None] * field(x, ki)
    u_b = np.einsum("bdf,bf->bd", np_zeta(flat, cfg, x, k), feats)
    l_b = ((u_b - field(x, k)) ** 2).sum(-1)
    g = cfg.gamma_su
    return (mask * ((1 - g) * l_p + g * l_b)).mean(), (mask * l_p).mean(), (mask * l_b).mean()
