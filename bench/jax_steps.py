"""JAX updates to time: the agents' `step_noise` + `sgd_step` (jit, donated buffers) and the bare flow-loss
step (`sf2_jax.losses.flow_loss` + Adam).

Measured with `jax.jit(...).lower(...).compile()` (compile time recorded, FLOPs and bytes from XLA's
`cost_analysis()` of the very executable that is timed), then called with donated params/opt_state;
`sync` is `jax.block_until_ready` on the newest params (each update depends on the previous one).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from .data import FIELDS, make_batches
from .sizes import VARIANT_REPS, Case
from .timing import Runner

# Flow-loss functions with `sf2_jax.losses.flow_loss`'s signature that `flow-step --variants` times beside
# `fast` and `oracle`, by name. Empty here: a module that defines variants of the loss adds them.
FLOW_VARIANTS: dict[str, Callable] = {}


def configure(precision: str = "highest") -> None:
    """Set JAX's default matmul precision for every program built afterwards.

    Args:
        precision: `jax_default_matmul_precision`; "highest" (full fp32) for published numbers
            (docs/core-contract.md "Precision").
    """
    import jax

    jax.config.update("jax_default_matmul_precision", precision)


def _analysis(obj) -> dict:
    try:
        cost = obj.cost_analysis()
    except Exception:  # noqa: BLE001 — some backends do not implement it
        return {}
    if isinstance(cost, (list, tuple)):
        cost = cost[0] if cost else {}
    return dict(cost or {})


def _cpu_lowered(raw, args):
    """The program lowered for the CPU backend (arguments copied to the host CPU device)."""
    import jax

    cpu = jax.devices("cpu")[0]
    return jax.jit(raw).lower(*jax.device_put(args, cpu))


def _cost(lowered, compiled, raw=None, args=None) -> dict:
    """FLOPs from XLA's HLO cost analysis of the program lowered *for the CPU backend* (a property of
    the program: every dot counts 2·m·n·k, elementwise ops one per element; the GPU backend's analysis
    leaves out the GEMMs it hands to cuBLAS), bytes accessed from the compiled executable (after fusion)."""
    import jax

    low, comp = _analysis(lowered), _analysis(compiled)
    cpu = {}
    if raw is not None and jax.default_backend() != "cpu":
        try:
            cpu = _analysis(_cpu_lowered(raw, args))
        except Exception:  # noqa: BLE001
            cpu = {}
    flops = cpu.get("flops", low.get("flops", comp.get("flops", float("nan"))))
    return {"flops": float(flops), "bytes": float(comp.get("bytes accessed", float("nan"))),
            "flops_backend": float(low.get("flops", float("nan")))}


def _device_batches(case: Case, count: int, seed: int):
    import jax.numpy as jnp
    from sf2_jax.losses import Batch

    raw = make_batches(case.obs_size, case.action_size, case.batch_size, count, seed)
    return [Batch(*(jnp.asarray(b[f]) for f in FIELDS)) for b in raw]


def baselines_available(framework: str = "jax") -> tuple[str, ...]:
    """Register the baselines of `sf2_baselines` with one framework's agents.

    Args:
        framework: "jax" or "torch": imports `sf2_baselines.<framework>`, which registers Sim, SimLap and
            SPR with that framework's agents.

    Returns:
        The baseline representations' names, or () when `sf2_baselines` is not installed.
    """
    import importlib

    try:
        mod = importlib.import_module(f"sf2_baselines.{framework}")
    except Exception:  # noqa: BLE001
        return ()
    reps = getattr(mod, "representations", None)
    return tuple(getattr(reps, "NAMES", ()) or getattr(mod, "REGISTERED", ()) or ())


def _algorithm(case: Case):
    from sf2_common.config import SF2Config
    from sf2_jax.agents import algorithms, representations

    if case.rep not in representations.names():
        baselines_available("jax")
    cfg = SF2Config(obs_size=case.obs_size, action_size=case.action_size, **case.sf2_overrides())
    return algorithms.make_algorithm(case.algo, cfg, representations.get(case.rep))


def _update(alg):
    """One agents' update as the trainer runs it: `step_noise(key, batch)`, then `sgd_step`."""
    def update(params, opt_state, batch, key, step):
        return alg.sgd_step(params, opt_state, batch, alg.step_noise(key, batch), step)

    return update


def update_runner(case: Case, seed: int = 0, scan: int = 1) -> tuple[Runner, dict]:
    """Build a timed JAX update: `step_noise` then `sgd_step` of the agents, as the trainer calls them.

    Args:
        case: what to time (a `jax` or `jax-scan` case).
        seed: seed of the parameters, batches and noise keys.
        scan: updates per jitted call; above 1 they run through `lax.scan`, as the trainer runs its
            `grad_updates_per_step`.

    Returns:
        The `Runner` and a dict with `flops`, `bytes` (XLA's cost analysis), `finite` (a callable: are
        the parameters finite) and `hlo` (a callable: the compiled program's text).
    """
    import jax
    import jax.numpy as jnp

    alg = _algorithm(case)
    params, opt_state = alg.init(jax.random.key(seed))
    batches = _device_batches(case, 4, seed)
    keys = list(jax.random.split(jax.random.key(seed + 1), len(batches)))
    steps = [jnp.asarray(i, jnp.int32) for i in range(len(batches))]

    update = _update(alg)
    if scan == 1:
        raw = update
    else:
        def many(params, opt_state, batch, key, step):
            def body(carry, k):
                p, o = carry
                p, o, m = update(p, o, batch, k, step)
                return (p, o), m["critic_loss"]

            keys = jax.random.split(key, scan)
            (params, opt_state), losses_ = jax.lax.scan(body, (params, opt_state), keys)
            return params, opt_state, losses_

        raw = many
    fn = jax.jit(raw, donate_argnums=(0, 1))
    args = (params, opt_state, batches[0], keys[0], steps[0])
    t0 = time.perf_counter()
    lowered = fn.lower(*args)
    compiled = lowered.compile()
    compile_s = time.perf_counter() - t0
    cost = _cost(lowered, compiled, raw, args)
    # with lax.scan, XLA's cost analysis counts the loop body (one update) once: already per update
    state = {"p": params, "o": opt_state, "i": 0}
    # Baselines update some groups every k-th step (`aux_every`): give them a growing step counter so a
    # timed block averages over their schedule. SF² and vanilla ignore the step (policy_delay = 1).
    counting = case.rep not in ("none", "sf2") and case.rep not in VARIANT_REPS

    def step():
        i = state["i"] % len(batches)
        s = jnp.asarray(state["i"] * scan, jnp.int32) if counting else steps[i]
        state["p"], state["o"], _ = compiled(state["p"], state["o"], batches[i], keys[i], s)
        state["i"] += 1

    def sync():
        jax.block_until_ready(state["p"])

    def finite() -> bool:
        leaves = jax.tree_util.tree_leaves(state["p"])
        return bool(all(jnp.all(jnp.isfinite(x)) for x in leaves if jnp.issubdtype(x.dtype, jnp.floating)))

    runner = Runner(case.key, step, sync, compile_s=compile_s, per_call=scan)
    return runner, {**cost, "finite": finite, "hlo": compiled.as_text}


def count_flops(case: Case, seed: int = 0) -> float:
    """Count the FLOPs of one update from XLA's cost analysis of the program lowered for the CPU.

    Args:
        case: the update (a JAX case); nothing is compiled or run on a device.
        seed: seed of the parameters and batch.

    Returns:
        FLOPs per update, the figure `update_runner` reports, recomputable on any machine.
    """
    import jax

    alg = _algorithm(case)
    cpu = jax.devices("cpu")[0]
    with jax.default_device(cpu):
        params, opt_state = alg.init(jax.random.key(seed))
        batch = _device_batches(case, 1, seed)[0]
        args = (params, opt_state, batch, jax.random.key(seed + 1), jax.numpy.asarray(0, "int32"))
    return float(_analysis(_cpu_lowered(_update(alg), args)).get("flops", float("nan")))


# ------------------------------------------------------------------------------------------ flow step
def flow_step_runner(obs_size: int, action_size: int, size: str, steps: int, integrator: str,
                     contract: bool, seed: int = 0, loss_fn=None, label: str = "") -> tuple[Runner, dict]:
    """Build a timed flow-loss step: value_and_grad of `sf2_jax.losses.flow_loss` and Adam on (ψ, ζ).

    Args:
        obs_size: observation size D.
        action_size: action size A.
        size: network/batch preset (`bench.sizes.SIZES`).
        steps: denoising steps T.
        integrator: "midpoint" or "euler".
        contract: the fast path (`contract_zeta=True`) or the oracle that builds ζ (False).
        seed: seed of the parameters, batches and noise.
        loss_fn: a function with `flow_loss`'s signature to time instead (a `FLOW_VARIANTS` entry).
        label: the runner's name.

    Returns:
        The `Runner` (jitted, donated buffers) and a dict with `flops`, `bytes`, `loss` and `first_loss`
        (callables: the latest and the first step's loss).
    """
    import jax
    import jax.numpy as jnp
    import numpy as np
    import optax
    from sf2_common.config import SF2Config
    from sf2_jax import losses, networks

    case = Case("jax", "td3", "sf2", _task_for(obs_size, action_size), size, steps, integrator)
    cfg = SF2Config(obs_size=obs_size, action_size=action_size, contract_zeta=contract,
                    **case.sf2_overrides())
    nets = networks.make_networks(cfg, "td3")
    params = networks.init_params(nets, jax.random.key(seed), dtype=jnp.float32)
    loss_fn = loss_fn or losses.flow_loss
    groups = ("psi", "zeta")
    opt = optax.adam(cfg.learning_rate, eps=cfg.adam_eps)
    opt_state = opt.init({g: params[g] for g in groups})
    batches = _device_batches(case, 4, seed)
    rng = np.random.default_rng(seed + 7)
    B = case.batch_size
    noises = [(jnp.asarray(rng.uniform(-1, 1, (B, action_size)).astype(np.float32)),
               jnp.asarray(rng.standard_normal((B, obs_size), np.float32)),
               jnp.asarray(rng.uniform(size=B).astype(np.float32))) for _ in batches]

    def flow_step(params, opt_state, batch, next_action, eps, flow_time):
        def f(sub):
            return loss_fn(nets, {**params, **sub}, batch, next_action, eps, flow_time)

        sub = {g: params[g] for g in groups}
        (loss, _), grads = jax.value_and_grad(f, has_aux=True)(sub)
        updates, opt_state = opt.update(grads, opt_state, sub)
        return {**params, **optax.apply_updates(sub, updates)}, opt_state, loss

    fn = jax.jit(flow_step, donate_argnums=(0, 1))
    t0 = time.perf_counter()
    args = (params, opt_state, batches[0], *noises[0])
    lowered = fn.lower(*args)
    compiled = lowered.compile()
    compile_s = time.perf_counter() - t0
    cost = _cost(lowered, compiled, flow_step, args)
    state = {"p": params, "o": opt_state, "i": 0, "loss": None, "first": None}

    def step():
        i = state["i"] % len(batches)
        state["p"], state["o"], state["loss"] = compiled(state["p"], state["o"], batches[i], *noises[i])
        if state["first"] is None:
            state["first"] = state["loss"]
        state["i"] += 1

    def sync():
        jax.block_until_ready(state["p"])

    name = label or f"flow/{'fast' if contract else 'oracle'}/T{steps}/{integrator}"
    runner = Runner(name, step, sync, compile_s=compile_s)
    return runner, {**cost, "loss": lambda: float(state["loss"]), "first_loss": lambda: float(state["first"])}


def grad_errors(obs_size: int, action_size: int, size: str, steps: int, variants: dict[str, Callable],
                seed: int = 0) -> list[dict]:
    """Measure the float32 flow-loss gradient of the fast path and of each variant against float64.

    Args:
        obs_size: observation size D.
        action_size: action size A.
        size: network/batch preset (`bench.sizes.SIZES`).
        steps: denoising steps T.
        variants: name → a function with `flow_loss`'s signature, measured beside the fast path.
        seed: seed of the parameters, batch and noise (one batch, the initial parameters).

    Returns:
        One row per function (`variant`, `steps`), with per group (ψ, ζ) the worst leaf's
        ‖g − g₆₄‖∞ / ‖g₆₄‖∞ (`{group}_rel_err`, the leaf in `{group}_worst_leaf`) and the whole group's
        2-norm ratio (`{group}_rel_err_2`); a function that fails gives a row with `error` instead.
    """
    import jax
    import jax.numpy as jnp
    import numpy as np
    from sf2_common.config import SF2Config
    from sf2_jax import losses
    from sf2_jax import networks as nw
    from sf2_jax.losses import Batch

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
    host = jax.tree_util.tree_map(np.asarray, nw.init_params(nets, jax.random.key(seed), dtype=jnp.float32))

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
    for name, fn in [("fast", losses.flow_loss), *variants.items()]:
        try:
            g = grads(fn, jnp.float32)
        except Exception as e:  # noqa: BLE001 — e.g. a dot algorithm this backend lacks
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


def _task_for(obs_size: int, action_size: int) -> str:
    from .sizes import TASKS

    for task, sizes in TASKS.items():
        if sizes == (obs_size, action_size):
            return task
    raise ValueError(f"no task has sizes ({obs_size}, {action_size}); valid: {TASKS}")
