"""Helpers shared by the cross-framework tests: build both cores from one canonical file, compare.

The relative difference of two arrays is ‖a − b‖∞ / max(‖b‖∞, 1e-30): the worst entry relative to the
array's scale (an entrywise ratio would blow up on entries that are zero up to round-off).
"""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import numpy as np
import sf2_jax
import sf2_torch
import torch
from sf2_jax import networks as jnet
from sf2_jax import params as jparams
from sf2_torch import networks as tnet
from sf2_torch import params as tparams

# Tolerances (relative, see the module docstring). float64: anything above ~1e-10 is a bug.
# float32: the two frameworks round differently (summation order, fused multiply-adds, XLA's reciprocal
# rewrites), and the flow-time embedding multiplies k by 10⁴ (docs/parity.md): one float32 ulp of k (6e-8)
# becomes 6e-4 rad of phase in the highest frequency. Outputs that pass through ζ at an ODE-integrated k
# therefore differ by up to ~3e-5 relative (observed), gradients by up to ~1e-4; the bounds leave 3x room.
# A bare ODE solution compared at several intermediate flow times (kind "ode") is the worst-conditioned
# output: compilers may fuse k_i + h/2 into one rounding or two, and that ulp is amplified 10⁴-fold;
# observed up to 1.8e-4 relative, bound 1e-3.
TOL = {"float64": 1e-10, "float32": {"value": 1e-4, "grad": 5e-4, "ode": 1e-3}}

RECORD: dict[tuple[str, str], list] = {}


def tolerance(dtype: str, kind: str) -> float:
    t = TOL[dtype]
    return t if isinstance(t, float) else t[kind]


def rel(a, b) -> float:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    assert a.shape == b.shape, f"shape mismatch {a.shape} vs {b.shape}"
    scale = max(float(np.max(np.abs(b))) if b.size else 0.0, 1e-30)
    return float(np.max(np.abs(a - b))) / scale if a.size else 0.0


def check(term: str, a, b, dtype: str, kind: str = "value") -> float:
    """Assert JAX value `a` equals torch value `b` within the dtype's tolerance; record the difference."""
    tol = tolerance(dtype, kind)
    r = rel(a, b)
    worst, _, n = RECORD.get((dtype, term), (0.0, tol, 0))
    RECORD[(dtype, term)] = [max(worst, r), tol, n + 1]
    assert r <= tol, f"{term} ({dtype}): JAX and torch differ by {r:.3e} relative (tolerance {tol:.0e})"
    return r


def canonical_values(shapes: dict, seed: int = 0) -> dict[str, np.ndarray]:
    """{name: array} for canonical `shapes` with every entry non-trivial: values drawn with numpy so that
    LayerNorm scales and biases, the normalizer statistics and the targets all differ from their
    defaults (a test that leaves them at 1/0/copies cannot catch a mix-up between them)."""
    rng = np.random.default_rng(seed)
    out = {}
    for name, shape in shapes.items():
        if name.endswith(".kernel"):  # LeCun-uniform scale, like the initializers
            v = rng.uniform(-1.0, 1.0, shape) * np.sqrt(3.0 / shape[0])
        elif name.endswith("obs_norm.std"):
            v = rng.uniform(0.5, 2.0, shape)
        elif name.endswith("obs_norm.count"):
            v = np.asarray(100.0)
        elif name.endswith("obs_norm.summed_var"):
            v = rng.uniform(50.0, 400.0, shape)
        elif name.endswith(".scale"):
            v = rng.uniform(0.5, 1.5, shape)
        elif name == "log_alpha":
            v = np.asarray(rng.normal(-1.0, 0.3))
        elif name == "task.w":  # Sim's task vector, N(0, 1) at init
            v = rng.normal(0.0, 1.0, shape)
        else:
            v = rng.normal(0.0, 0.1, shape)
        out[name] = v
    return out


def canonical_file(tmp_path: Path, cfg_kwargs: dict, algo: str, seed: int = 0) -> Path:
    """One canonical parameter file of the core networks (names and shapes from sf2_jax's
    `expected_shapes`), every entry non-trivial (`canonical_values`)."""
    shapes = jparams.expected_shapes(sf2_jax.SF2Config(**cfg_kwargs), algo)
    path = tmp_path / f"{algo}-{seed}.npz"
    jparams.save(path, canonical_values(shapes, seed))
    return path


def build_pair(path: Path, cfg_kwargs: dict, algo: str, dtype: str):
    """Load the canonical file into both cores at `dtype`; returns (jax nets, jax params, torch nets)."""
    flat = jparams.load(path)
    jcfg = sf2_jax.SF2Config(**cfg_kwargs)
    tcfg = sf2_torch.SF2Config(**cfg_kwargs)
    jn = jnet.make_networks(jcfg, algo)
    jp = jparams.from_canonical(flat, jn, dtype=getattr(jnp, dtype))
    tn = tnet.make_networks(tcfg, algo).to(getattr(torch, dtype))
    tparams.from_canonical(tparams.load(path), tn)
    return jn, jp, tn


def make_batch(cfg_kwargs: dict, batch_size: int, seed: int, truncation: bool):
    """Identical raw batch and noise for both frameworks, as float64 numpy arrays."""
    D, A = cfg_kwargs["obs_size"], cfg_kwargs["action_size"]
    rng = np.random.default_rng(1000 + seed)
    trunc = (rng.uniform(size=batch_size) < 0.3).astype(np.float64) if truncation else np.zeros(batch_size)
    batch = dict(
        obs=rng.normal(0.5, 2.0, (batch_size, D)),
        action=rng.uniform(-1, 1, (batch_size, A)),
        reward=rng.normal(size=batch_size),
        discount=(rng.uniform(size=batch_size) > 0.1).astype(np.float64),
        next_obs=rng.normal(0.5, 2.0, (batch_size, D)),
        truncation=trunc,
    )
    noise = dict(
        eps=rng.normal(size=(batch_size, D)),
        flow_time=rng.uniform(size=batch_size),
        next_action=rng.uniform(-1, 1, (batch_size, A)),
        smoothing=rng.normal(size=(batch_size, A)),
        noise=rng.normal(size=(batch_size, A)),
    )
    return batch, noise


def jx(x, dtype):
    return jnp.asarray(np.asarray(x), dtype=getattr(jnp, dtype))


def th(x, dtype):
    return torch.as_tensor(np.array(x), dtype=getattr(torch, dtype))   # a copy: torch wants writable memory


def jbatch(batch, dtype):
    return sf2_jax.losses.Batch(**{k: jx(v, dtype) for k, v in batch.items()})


def tbatch(batch, dtype):
    return sf2_torch.losses.Batch(**{k: th(v, dtype) for k, v in batch.items()})


def np_(x):
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().numpy()
    return np.asarray(x)
