"""Prototypes for issue #6 target 5 (make the SF² update fast), timed next to the cores' code.

Nothing here changes `sf2_jax`; each variant is a drop-in replacement of `sf2_jax.losses.flow_loss`
(same signature, same value up to rounding), usable two ways:
- `python -m bench flow-step --variants merged,x3tf32` times it in the bare flow-loss step;
- the representations registered below (`sf2-merged`, `sf2-x3tf32`, `sf2-x6bf16`) plug it into the
  agents' full `sgd_step`, so `python -m bench run --reps none,sf2,sf2-merged` times whole updates.
`psi-only` is TD3/SAC on ψ features with no flow loss at all: SF² update − psi-only = cost of the flow
step inside the update.

Variants (all on the fast path of DESIGN.md §6). The cores store M as (B, D, H) since the `wt` port
(issue #6; before it, `pre-wt` below); the layout variants are kept as references for the recorded runs
of bench/results/h200 (their README lists the commands):
- `pre-wt`: the cores' fast path before the port: M = einsum("hdf,bf->bhd", W, ψ) stored (B, H, D) and
  read with einsum("bh,bhd->bd"). Time it next to `sf2` to see the port's gain in one run.
- `bhd`: `pre-wt` with the contraction written `einsum("bf,hdf->bhd", ψ, W)` (ψ first), so M comes out of
  its GEMM in the layout the per-evaluation product reads.
- `bdh`: M and M̄ stored (B, D, H) by one transpose per contraction, `einsum("bf,hdf->bdh")`.
  (H200, jax 0.11.2: XLA sank that transpose back into every evaluation in the one-call-per-update
  program, but not inside `lax.scan`.)
- `bdhb`: `bdh` with the (B, D, H) value behind `lax.optimization_barrier`, so it is materialized once.
- `wt` — now the cores' layout (`sf2`), no longer a variant: ζ's last kernel re-laid (D, H, F) once per
  contraction, so the GEMM itself emits M as (B, D·H) (bench/results/h200/4-layout-fix).
- `wt-ode3xtf32` / `wt-ode6xbf16`: the cores' fast path, and the target field's evaluations (the ODE and
  the target velocity: no gradient flows through them) run their matmuls with an error-compensated
  algorithm (3 TF32 / 6 bf16 tensor-core passes, fp32 accumulation); everything else stays fp32 'highest'.
- `merged`: the cores' fast path with the two online velocity evaluations (at x_k and at x̂) run as one
  batch of 2B through ζ's hidden MLP and one batched product with M ('nbh,bdh->nbd'), instead of two
  separate chains (the torch core already does this). Fewer, larger kernels; same FLOPs. (Runs 1–2 of
  bench/results/h200 timed it on the `pre-wt` layout.)
- `merged-bhd`: `merged` on the `bhd` layout.
- `x3tf32` / `x6bf16`: `merged`, and the two contractions M = Wψ, M̄ = W̄ψ̄′ (and, through autodiff,
  their transposes dW, dψ), which hold ~half the update's FLOPs, use XLA's error-compensated dot
  algorithms (3 TF32 or 6 bf16 tensor-core passes with fp32 accumulation, accuracy close to fp32,
  `jax.lax.DotAlgorithmPreset`). TF32_TF32_F32_X3 is GPU-only. Accuracy is measured by `grad_errors`.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from sf2_jax import networks as nw
from sf2_jax.agents import representations
from sf2_jax.losses import _check_batch, _check_noise, _trainable
from sf2_jax.ode import integrate

sg = jax.lax.stop_gradient

ORDERS_BHD = ("pre-wt", "bhd")            # M stored (B, H, D)
ORDERS_BDH = ("bdh", "bdhb", "wt")        # M stored (B, D, H), the cores' layout


def _contract(nets, p, features, target, precision, order="wt"):
    """(M, c), M laid out as `order` says (ORDERS_BHD: (B, H, D); ORDERS_BDH: (B, D, H)).
    `order="wt"` is `sf2_jax.networks.contract` (with an optional dot `precision`); `"pre-wt"` is the
    cores' contraction before the port, `einsum("hdf,bf->bhd", W, ψ)`, whose GEMM emits (h, d, b), so
    XLA re-transposed M̄ inside every ODE evaluation (`input_transpose_fusion` in the H200 profile,
    ~9 µs each)."""
    cfg = nets.cfg
    W, b = nw.zeta_last_layer(nets, p, target)
    W = W.reshape(W.shape[0], cfg.obs_size, cfg.feature_size)
    c = jnp.einsum("bf,df->bd", features, b.reshape(cfg.obs_size, cfg.feature_size))
    if order == "pre-wt":
        return jnp.einsum("hdf,bf->bhd", W, features, precision=precision), c
    if order == "bhd":
        return jnp.einsum("bf,hdf->bhd", features, W, precision=precision), c
    if order == "bdh":
        return jnp.einsum("bf,hdf->bdh", features, W, precision=precision), c
    if order == "bdhb":   # bdh, and the (B, D, H) value materialized once (XLA may not sink the transpose)
        return jax.lax.optimization_barrier(jnp.einsum("bf,hdf->bdh", features, W, precision=precision)), c
    if order == "wt":     # the GEMM itself emits (B, D·H): W re-laid (D, H, F) once per contraction
        return jnp.einsum("bf,dhf->bdh", features, jnp.transpose(W, (1, 0, 2)), precision=precision), c
    raise ValueError(f"order = {order!r} is invalid: must be one of {ORDERS_BHD + ORDERS_BDH}")


def _velocity(order):
    """The per-evaluation product for M laid out as `order` says."""
    if order in ORDERS_BDH:
        return nw.velocity_contracted

    def velocity_bhd(nets, p, x, k, M_bhd, c, target=False):
        """u = Σ_h h(x, k)_h M[b, h, d] + c with M stored (B, H, D) (the pre-port layout)."""
        return jnp.einsum("bh,bhd->bd", nw.zeta_hidden(nets, p, x, k, target), M_bhd) + c

    return velocity_bhd


def flow_loss_bhd(nets, params, batch, next_action, eps, flow_time, order="bhd", ode_precision=None):
    """`sf2_jax.losses.flow_loss` (fast path) with M laid out by `_contract(order=...)`.
    `ode_precision`: a matmul precision (e.g. "TF32_TF32_F32_X3") for the target field's evaluations
    only (the ODE and the target velocity, which carry no gradient)."""
    vel = _velocity(order)
    cfg = nets.cfg
    b = _check_batch(nets, batch)
    _check_noise(nets, "next_action", next_action, b, cfg.action_size, "action_size")
    _check_noise(nets, "eps", eps, b, cfg.obs_size, "obs_size")
    p = _trainable(params, ("psi", "zeta"))
    next_action = sg(next_action)
    next_obs_n = nw.normalize(batch.next_obs, p["obs_norm"])
    features = nw.psi(nets, p, batch.obs, batch.action)
    k = flow_time
    x_k = k[..., None] * next_obs_n + (1 - k[..., None]) * eps
    M, c = _contract(nets, p, features, False, None, order)

    def online(x):
        return vel(nets, p, x, k, M, c)

    loss_p = jnp.sum((online(x_k) - (next_obs_n - eps)) ** 2, axis=-1)
    mask = 1 - batch.truncation
    if cfg.gamma_su == 0:
        return jnp.mean(mask * loss_p), {"loss_p": jnp.mean(mask * loss_p), "loss_boot": jnp.zeros(())}
    next_features = sg(nw.psi(nets, p, batch.next_obs, next_action, target=True))
    M_bar, c_bar = _contract(nets, p, next_features, True, None, order)

    def target_velocity(x, kk):
        if ode_precision is None:
            return vel(nets, p, x, kk, M_bar, c_bar, target=True)
        with jax.default_matmul_precision(ode_precision):
            return vel(nets, p, x, kk, M_bar, c_bar, target=True)

    x_hat = sg(integrate(target_velocity, eps, k, cfg.denoising_steps, cfg.integrator))
    loss_b = jnp.sum((online(x_hat) - sg(target_velocity(x_hat, k))) ** 2, axis=-1)
    loss = jnp.mean(mask * ((1 - cfg.gamma_su) * loss_p + cfg.gamma_su * loss_b))
    return loss, {"loss_p": jnp.mean(mask * loss_p), "loss_boot": jnp.mean(mask * loss_b)}


def flow_loss_merged(nets, params, batch, next_action, eps, flow_time, precision=None, order="wt"):
    """`sf2_jax.losses.flow_loss` (fast path), online evaluations merged; `precision` for M and M̄;
    M laid out by `_contract(order=...)`."""
    vel = _velocity(order)
    product = "nbh,bdh->nbd" if order in ORDERS_BDH else "nbh,bhd->nbd"
    cfg = nets.cfg
    b = _check_batch(nets, batch)
    _check_noise(nets, "next_action", next_action, b, cfg.action_size, "action_size")
    _check_noise(nets, "eps", eps, b, cfg.obs_size, "obs_size")
    p = _trainable(params, ("psi", "zeta"))
    next_action = sg(next_action)
    next_obs_n = nw.normalize(batch.next_obs, p["obs_norm"])
    features = nw.psi(nets, p, batch.obs, batch.action)
    k = flow_time
    x_k = k[..., None] * next_obs_n + (1 - k[..., None]) * eps
    M, c = _contract(nets, p, features, False, precision, order)
    mask = 1 - batch.truncation
    if cfg.gamma_su == 0:
        u_p = vel(nets, p, x_k, k, M, c)
        loss_p = jnp.sum((u_p - (next_obs_n - eps)) ** 2, axis=-1)
        return jnp.mean(mask * loss_p), {"loss_p": jnp.mean(mask * loss_p), "loss_boot": jnp.zeros(())}
    next_features = sg(nw.psi(nets, p, batch.next_obs, next_action, target=True))
    M_bar, c_bar = _contract(nets, p, next_features, True, precision, order)

    def target_velocity(x, kk):
        return vel(nets, p, x, kk, M_bar, c_bar, target=True)

    x_hat = sg(integrate(target_velocity, eps, k, cfg.denoising_steps, cfg.integrator))
    u_bar = sg(target_velocity(x_hat, k))
    h = nw.zeta_hidden(nets, p, jnp.concatenate([x_k, x_hat]), jnp.concatenate([k, k]))
    h = h.reshape(2, *x_k.shape[:-1], h.shape[-1])
    u = jnp.einsum(product, h, M) + c
    loss_p = jnp.sum((u[0] - (next_obs_n - eps)) ** 2, axis=-1)
    loss_b = jnp.sum((u[1] - u_bar) ** 2, axis=-1)
    loss = jnp.mean(mask * ((1 - cfg.gamma_su) * loss_p + cfg.gamma_su * loss_b))
    return loss, {"loss_p": jnp.mean(mask * loss_p), "loss_boot": jnp.mean(mask * loss_b)}


_P = jax.lax.DotAlgorithmPreset
VARIANTS = {
    "pre-wt": functools.partial(flow_loss_bhd, order="pre-wt"),
    "bhd": flow_loss_bhd,
    "bdh": functools.partial(flow_loss_bhd, order="bdh"),
    "bdhb": functools.partial(flow_loss_bhd, order="bdhb"),
    "wt-ode3xtf32": functools.partial(flow_loss_bhd, order="wt", ode_precision="TF32_TF32_F32_X3"),
    "wt-ode6xbf16": functools.partial(flow_loss_bhd, order="wt", ode_precision="BF16_BF16_F32_X6"),
    "merged-bhd": functools.partial(flow_loss_merged, order="bhd"),
    "merged": flow_loss_merged,
    "x3tf32": functools.partial(flow_loss_merged, precision=_P.TF32_TF32_F32_X3),
    "x6bf16": functools.partial(flow_loss_merged, precision=_P.BF16_BF16_F32_X6),
}
RETIRED = {"wt": "now the cores' layout: time `sf2` (representation) or `fast` (flow step)"}


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
            # noise: SF2Representation.aux_noise's draw, {"flow_noise": ε, "flow_time": k} (the agents'
            # tensordict keys), or the pair (ε, k) of the agents before that naming.
            eps, flow_time = ((noise["flow_noise"], noise["flow_time"]) if isinstance(noise, dict)
                              else noise)
            return fn(self.nets, params, batch, next_action, eps, flow_time)

    Variant.name, Variant.label = name, label
    Variant.__name__ = Variant.__qualname__ = f"SF2_{name.replace('-', '_')}"
    return representations.register(Variant)


@representations.register
class PsiOnly(representations.SF2Representation):
    """TD3/SAC on ψ features with no flow loss (ζ untouched): the SF² update minus its flow step."""

    name = "psi-only"
    label = "ψ critic, no flow loss"
    aux_groups = ()

    def update_targets(self, params):
        from sf2_jax.losses import ema_update

        return {"target_psi": ema_update(params["target_psi"], params["psi"], self.cfg.tau)}


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
    from sf2_jax import losses, networks
    from sf2_jax.config import SF2Config
    from sf2_jax.losses import Batch

    from .data import FIELDS, make_batches
    from .sizes import SIZES

    kw = {k: v for k, v in SIZES[size].items() if k != "batch_size"}
    B = SIZES[size]["batch_size"]
    cfg = SF2Config(obs_size=obs_size, action_size=action_size, denoising_steps=steps, **kw)
    nets = networks.make_networks(cfg, "td3")
    raw = make_batches(obs_size, action_size, B, 1, seed)[0]
    rng = np.random.default_rng(seed + 1)
    na = rng.uniform(-1, 1, (B, action_size)).astype(np.float32)
    eps = rng.standard_normal((B, obs_size), np.float32)
    k = rng.uniform(size=B).astype(np.float32)
    params32 = networks.init_params(nets, jax.random.key(seed), dtype=jnp.float32)
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
