"""Bench-only variants of the SF² update (issue #6 target 5), timed next to the cores' code.

Nothing here changes `sf2_jax` or copies a loss. Kept, because the tables of bench/results/h200 use them:
- `psi-only` (representation): TD3/SAC on ψ features with no flow loss at all; SF² update − psi-only =
  cost of the flow step inside the update (the `psi-only` column and the fp32 floor argument of
  bench/results/h200/README.md);
- reduced-precision dots (runs 1 and 4 there): `sf2_jax.losses.flow_loss` itself, with some of its
  matmuls traced under an error-compensated XLA dot algorithm (3 TF32 / 6 bf16 tensor-core passes, fp32
  accumulation, `jax.lax.DotAlgorithmPreset`; GPU only: on a CPU they fail with XLA's "not supported by
  dot_general on CPU"):
  - `x3tf32` / `x6bf16`: the two contractions M = Wψ, M̄ = W̄ψ̄′ (`networks.contract`; autodiff's
    transposes dW, dψ inherit the algorithm), ~half the update's FLOPs;
  - `wt-ode3xtf32` / `wt-ode6xbf16`: the target field's evaluations (`networks.velocity_contracted` with
    `target=True`: the ODE and the bootstrap target, which carry no gradient).
  `python -m bench flow-step --variants x3tf32` times one in the bare flow-loss step; the representations
  `sf2-<variant>` registered below put it in the agents' full `sgd_step` (`--reps none,sf2,sf2-x3tf32`).

Retired (`RETIRED`, refused with the reason): the M layouts before the cores stored M as (B, D, H)
(`pre-wt`, `bhd`, `bdh`, `bdhb`, `merged-bhd`, `wt`; results/h200 runs 1–4 and 8 recorded them) and
`merged`, the online evaluations as one 2B batch, which is now the cores' `flow_loss`.
"""

from __future__ import annotations

import functools
from unittest import mock

import jax
import jax.numpy as jnp
from sf2_jax import losses
from sf2_jax import networks as nw
from sf2_jax.agents import representations

# variant: (the networks function traced under the algorithm, only its target=True calls, the algorithm)
PRECISION = {
    "x3tf32": ("contract", False, "TF32_TF32_F32_X3"),
    "x6bf16": ("contract", False, "BF16_BF16_F32_X6"),
    "wt-ode3xtf32": ("velocity_contracted", True, "TF32_TF32_F32_X3"),
    "wt-ode6xbf16": ("velocity_contracted", True, "BF16_BF16_F32_X6"),
}
_LAYOUT = "a layout of M before the cores stored it (B, D, H) (issue #6); the cores' layout is `sf2`"
RETIRED = {**dict.fromkeys(("pre-wt", "bhd", "bdh", "bdhb", "merged-bhd"), _LAYOUT),
           "wt": "now the cores' layout: time `sf2` (representation) or `fast` (flow step)",
           "merged": "now the cores' flow_loss: time `sf2` (representation) or `fast` (flow step)"}


def with_precision(function: str, target_only: bool, algorithm: str):
    """`sf2_jax.losses.flow_loss` (same signature) with `sf2_jax.networks.<function>` (its target=True
    calls only, if `target_only`) traced under `jax.default_matmul_precision(algorithm)`."""
    original = getattr(nw, function)

    def traced(*args, target=False, **kwargs):
        if target_only and not target:
            return original(*args, target=target, **kwargs)
        with jax.default_matmul_precision(algorithm):
            return original(*args, target=target, **kwargs)

    @functools.wraps(losses.flow_loss)
    def flow_loss(*args, **kwargs):
        with mock.patch.object(nw, function, traced):
            return losses.flow_loss(*args, **kwargs)

    return flow_loss


VARIANTS = {name: with_precision(*spec) for name, spec in PRECISION.items()}


def variant(name: str):
    """The flow-loss function of prototype `name`, or a ValueError naming the valid ones."""
    if name in VARIANTS:
        return VARIANTS[name]
    why = f" ({RETIRED[name]})" if name in RETIRED else ""
    raise ValueError(f"unknown prototype {name!r}{why}: valid are {', '.join(VARIANTS)}")


# ------------------------------------------------------------------------- representations (full update)
def _sf2_variant(name: str, label: str, fn):
    class Variant(representations.SF2Representation):
        def aux_loss(self, params, batch, next_action, noise):
            return fn(self.nets, params, batch, next_action, noise["flow_noise"], noise["flow_time"])

    Variant.name, Variant.label = name, label
    Variant.__name__ = Variant.__qualname__ = f"SF2_{name.replace('-', '_')}"
    return representations.register(Variant)


@representations.register
class PsiOnly(representations.SF2Representation):
    """TD3/SAC on ψ features with no flow loss (ζ untouched): the SF² update minus its flow step."""

    name = "psi-only"
    label = "ψ critic, no flow loss"
    aux_groups = ()

    def targets(self):
        return {"target_psi": ("psi", self.cfg.tau)}


for _name, _fn in VARIANTS.items():
    _sf2_variant(f"sf2-{_name}", f"SF² ({_name})", _fn)

REPRESENTATIONS = ("psi-only", *(f"sf2-{n}" for n in VARIANTS))


# ------------------------------------------------------------------------------------------ accuracy
def grad_errors(obs_size: int, action_size: int, size: str, steps: int, variants,
                seed: int = 0) -> list[dict]:
    """Relative error of the flow-loss gradient of the fast path and of each variant in float32, against
    the fast path in float64, at one batch, per parameter group: worst leaf of ‖g − g64‖∞ / ‖g64‖∞
    (`{group}_rel_err`, the leaf's name in `{group}_worst_leaf`) and the whole group's 2-norm ratio
    (`{group}_rel_err_2`). Shows whether a variant is as accurate as the fp32 'highest' fast path."""
    import numpy as np
    from sf2_common.config import SF2Config
    from sf2_jax.losses import Batch

    from .data import FIELDS, make_batches
    from .sizes import SIZES

    kw = {k: v for k, v in SIZES[size].items() if k != "batch_size"}
    B = SIZES[size]["batch_size"]
    cfg = SF2Config(obs_size=obs_size, action_size=action_size, denoising_steps=steps, **kw)
    nets = nw.make_networks(cfg, "td3")
    raw = make_batches(obs_size, action_size, B, 1, seed)[0]
    rng = np.random.default_rng(seed + 1)
    na = rng.uniform(-1, 1, (B, action_size)).astype(np.float32)
    eps = rng.standard_normal((B, obs_size), np.float32)
    k = rng.uniform(size=B).astype(np.float32)
    params32 = nw.init_params(nets, jax.random.key(seed), dtype=jnp.float32)
    host = jax.tree_util.tree_map(np.asarray, params32)

    def grads(fn, dtype):
        p = jax.tree_util.tree_map(lambda v: jnp.asarray(v, dtype), host)
        batch = Batch(*(jnp.asarray(raw[f], dtype) for f in FIELDS))
        inputs = (jnp.asarray(na, dtype), jnp.asarray(eps, dtype), jnp.asarray(k, dtype))

        def f(sub, p, batch, inputs):   # everything an argument: no constants for XLA to fold
            return fn(nets, {**p, **sub}, batch, *inputs)[0]

        g = jax.jit(jax.grad(f))({"psi": p["psi"], "zeta": p["zeta"]}, p, batch, inputs)
        return jax.tree_util.tree_map(lambda v: np.asarray(v, np.float64), g)

    with jax.enable_x64(True):
        ref = grads(losses.flow_loss, jnp.float64)
    out = []
    for name, fn in [("fast", losses.flow_loss), *((v, variant(v)) for v in variants)]:
        try:
            g = grads(fn, jnp.float32)
        except Exception as e:  # noqa: BLE001
            out.append(dict(variant=name, steps=steps, error=f"{type(e).__name__}: {str(e)[:120]}"))
            continue
        row = dict(variant=name, steps=steps)
        for group in ("psi", "zeta"):
            worst, leaf, sq_err, sq_ref = 0.0, "", 0.0, 0.0
            flat = jax.tree_util.tree_flatten_with_path(ref[group])[0]
            for (path, b), a in zip(flat, jax.tree_util.tree_leaves(g[group])):
                r = float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-30))
                if r >= worst:
                    worst, leaf = r, ".".join(str(getattr(q, "key", q)) for q in path)
                sq_err, sq_ref = sq_err + float(np.sum((a - b) ** 2)), sq_ref + float(np.sum(b**2))
            row[f"{group}_rel_err"] = worst
            row[f"{group}_worst_leaf"] = leaf
            row[f"{group}_rel_err_2"] = (sq_err / max(sq_ref, 1e-300)) ** 0.5
        out.append(row)
    return out
