"""Where the torch trainer's evaluation env step spends its time on one device: TorchRL's `step` (as the
evaluation called it), `step_actions` (the trainer's loops' own), the env's `_step` without TorchRL's
wrapper, the jitted JAX step dispatched once a step, and the same steps compiled into one `lax.scan` (the
physics alone). Every way steps the same envs from the same reset with the same random actions.

    python -m bench.lab.torch_eval_env --task CheetahRun --envs 640 --steps 300
"""

from __future__ import annotations

import argparse
import json
import sys
import time


def stepper(name: str, env, actions, jax_actions):
    """One way of stepping `env`: `fn(i)` takes step i's action and returns the next observation.

    Args:
        name: one of `WAYS` (the compiled scan is timed apart, `scan_steps`).
        env: a reset `sf2_torch.agents.envs.PlaygroundEnv`.
        actions: the torch actions, one (envs, A) tensor per step.
        jax_actions: the same actions as JAX arrays.

    Returns:
        The callable.
    """
    from sf2_torch.agents import envs
    from tensordict import TensorDict

    n = env.batch_size.numel()
    if name == "torchrl_step":
        return lambda i: env.step(TensorDict({"action": actions[i]}, [n], device=env.device)).get(
            "next").get("observation")
    if name == "step_actions":
        return lambda i: env.step_actions(actions[i]).get("observation")
    if name == "own_step":
        return lambda i: env._step(TensorDict({"action": actions[i]}, [n], device=env.device)).get(
            "observation")
    if name == "jax_step":
        _, step = envs._packed_fns(env._spec, env._layout)

        def jax_step(i):
            env._packed, transition = step(env._packed, jax_actions[i])
            return transition[:, :env._spec.obs_size]
        return jax_step
    raise ValueError(f"unknown way {name!r}; valid: {', '.join(WAYS)}")


WAYS = ("torchrl_step", "step_actions", "own_step", "jax_step")


def scan_steps(env, keys, jax_actions):
    """The jitted `lax.scan` of the wrapped JAX step over `jax_actions` from the reset of `keys`.

    Args:
        env: the `PlaygroundEnv` whose task to step.
        keys: the reset keys (envs, 2).
        jax_actions: (steps, envs, A).

    Returns:
        (a function of no argument running the scan, blocking; the last observation it reached).
    """
    import jax

    spec = env._spec
    state0 = spec.reset(jax.device_put(keys, env._jax_device))
    acts = jax_actions.astype(jax.dtypes.canonicalize_dtype("float64"))

    @jax.jit
    def scan(state, acts):
        def body(s, a):
            with jax.default_matmul_precision("highest"):
                s = spec.jax_env.step(s, a)
            return s, None
        return jax.lax.scan(body, state, acts)[0].obs

    return lambda: jax.block_until_ready(scan(state0, acts))


def main(argv=None) -> int:
    """Run `python -m bench.lab.torch_eval_env`.

    Args:
        argv: the command line after the module name.

    Returns:
        The exit status (2 for an invalid argument or task).
    """
    p = argparse.ArgumentParser(prog="python -m bench.lab.torch_eval_env",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="CheetahRun")
    p.add_argument("--envs", type=int, default=640)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--device", default=None, help="cuda or cpu (default: cuda where there is one)")
    a = p.parse_args(argv)
    if a.envs < 1 or a.steps < 1:
        print(f"--envs {a.envs} --steps {a.steps}: both must be at least 1", file=sys.stderr)
        return 2

    import jax
    import jax.numpy as jnp
    import torch
    from sf2_common.errors import ConfigError
    from sf2_torch.agents import envs

    dev = torch.device(a.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    try:
        env = envs.make_env(a.task, 1000, 1, a.envs, dev)
    except ConfigError as err:
        print(err, file=sys.stderr)
        return 2
    keys = jax.random.split(jax.random.PRNGKey(0), a.envs)
    g = torch.Generator(device=dev).manual_seed(0)
    actions = [torch.rand(a.envs, env._spec.action_size, device=dev, generator=g) * 2 - 1
               for _ in range(a.steps)]
    jax_actions = jnp.stack([jnp.asarray(x.cpu().numpy()) for x in actions])

    def drain():
        if dev.type == "cuda":
            torch.cuda.synchronize()
        jax.block_until_ready(env._packed)

    for name in WAYS:
        for _ in range(2):   # the first compiles
            env.reset_from_keys(keys)
            fn = stepper(name, env, actions, jax_actions)
            drain()
            t = time.perf_counter()
            for i in range(a.steps):
                fn(i)
            host = time.perf_counter() - t
            drain()
            drained = time.perf_counter() - t
        ms = {"host_ms": host / a.steps * 1e3, "drained_ms": drained / a.steps * 1e3}
        print(json.dumps({"way": name, **ms}), flush=True)
    run = scan_steps(env, keys, jax_actions)
    run()
    t = time.perf_counter()
    run()
    ms = (time.perf_counter() - t) / a.steps * 1e3
    print(json.dumps({"way": "jax_scan", "drained_ms": ms}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
