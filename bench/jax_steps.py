"""JAX updates to time: the agents' `step_noise` + `sgd_step` (jit, donated buffers) and the bare flow-loss
step (`sf2_jax.losses.flow_loss` + Adam).

Measured with `jax.jit(...).lower(...).compile()` (compile time recorded, FLOPs and bytes from XLA's
`cost_analysis()` of the very executable that is timed), then called with donated params/opt_state;
`sync` is `jax.block_until_ready` on the newest params (each update depends on the previous one).
"""

from __future__ import annotations

import time

from .data import FIELDS, make_batches
from .sizes import Case
from .timing import Runner


def configure(precision: str = "highest") -> None:
    """Full fp32 matmuls for published numbers (docs/core-contract.md "Precision")."""
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
    reports far fewer, e.g. 12 instead of 35 GFLOP for the Cheetah SF² update, as it does not count
    the GEMMs it hands to cuBLAS), bytes accessed from the compiled executable (after fusion)."""
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
    """Import `sf2_baselines.<framework>` (it registers Sim, SimLap, SPR with that framework's agents)
    and return the baseline names, or () when the package is absent."""
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
    if case.rep not in representations.names():
        from . import prototypes  # noqa: F401 — registers the bench-only representations
    cfg = SF2Config(obs_size=case.obs_size, action_size=case.action_size, **case.sf2_overrides())
    return algorithms.make_algorithm(case.algo, cfg, representations.get(case.rep))


def _update(alg):
    """One agents' update as the trainer runs it: `step_noise(key, batch)`, then `sgd_step`."""
    def update(params, opt_state, batch, key, step):
        return alg.sgd_step(params, opt_state, batch, alg.step_noise(key, batch), step)

    return update


def update_runner(case: Case, seed: int = 0, scan: int = 1) -> tuple[Runner, dict]:
    """A Runner over one agents' update of `case`, `step_noise` then `sgd_step` as the trainer calls them
    (one jitted call per update, or `scan` updates per call through `lax.scan`, as the trainer does with
    `grad_updates_per_step`)."""
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
    counting = case.rep not in ("none", "sf2", "psi-only") and not case.rep.startswith("sf2-")

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
    """FLOPs of one update of `case` from XLA's HLO cost analysis of the program lowered for the CPU
    (no compilation, no device): what `update_runner` reports, recomputable anywhere."""
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
    """value_and_grad of `sf2_jax.losses.flow_loss` + Adam on (ψ, ζ), jitted with donated buffers.

    `loss_fn` replaces `losses.flow_loss` (same signature) to time a prototype."""
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


def _task_for(obs_size: int, action_size: int) -> str:
    from .sizes import TASKS

    for task, sizes in TASKS.items():
        if sizes == (obs_size, action_size):
            return task
    raise ValueError(f"no task has sizes ({obs_size}, {action_size}); valid: {TASKS}")
