"""Wall-clock time of one SGD step (the whole update: critic, flow, actor, targets) of the torch agents,
eager and `torch.compile`d (and as CUDA graphs on a GPU), against the JAX agents' jitted `sgd_step`, at
the paper's sizes, in one process so that every number comes from the same machine state.

    python -m sf2_torch.agents.timing --algo td3 --repr sf2 --obs-size 17 --action-size 6 --json out.json

Defaults are the `paper` preset's sizes (F = 512, ψ/policy (512, 512, 512), ζ (512, 512), Q hidden 512,
embedding 64, batch 512, T = 1 midpoint step) for CheetahRun's sizes (D = 17, A = 6). Each variant runs
`--warmup` steps (the first of which compiles) and then `--steps` timed steps on fixed batches; the
median and the interquartile range of the per-step times are reported (GPU steps are timed with a device
synchronization after each step). fp32 throughout: TF32 off in torch, JAX matmul precision "highest".
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

__all__ = ["main", "time_torch", "time_jax"]


def _sizes(args) -> dict:
    return dict(obs_size=args.obs_size, action_size=args.action_size, feature_size=args.feature_size,
                hidden_sizes=(args.width,) * args.hidden_layers, q_hidden_size=args.width,
                zeta_hidden_sizes=(args.width,) * args.zeta_hidden_layers,
                embedding_size=args.embedding_size, denoising_steps=args.denoising_steps)


def _stats(times: list[float]) -> dict:
    ms = sorted(t * 1e3 for t in times)
    q = statistics.quantiles(ms, n=4) if len(ms) >= 4 else [ms[0], statistics.median(ms), ms[-1]]
    return {"median_ms": statistics.median(ms), "p25_ms": q[0], "p75_ms": q[2], "steps": len(ms)}


def time_torch(args, compile_mode: str | None, cudagraphs: bool) -> dict:
    import torch
    from tensordict import TensorDict

    from sf2_torch.config import SF2Config

    from . import algorithms, representations

    device = torch.device(args.device)
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    torch.manual_seed(0)
    cfg = SF2Config(**_sizes(args))
    algo = algorithms.make_algorithm(args.algo, cfg, representations.get(args.repr), device=device,
                                     compile_mode=compile_mode, cudagraphs=cudagraphs)
    algo.observe(torch.randn(1024, cfg.obs_size, device=device))
    g = torch.Generator(device=device).manual_seed(0)
    b, d, a = args.batch_size, cfg.obs_size, cfg.action_size
    tds = []
    for _ in range(4):
        trunc = torch.rand(b, 1, generator=g, device=device) < 0.01
        td = TensorDict({
            "observation": torch.randn(b, d, generator=g, device=device),
            "action": torch.rand(b, a, generator=g, device=device) * 2 - 1,
            "next": {"observation": torch.randn(b, d, generator=g, device=device),
                     "reward": torch.rand(b, 1, generator=g, device=device),
                     "done": trunc.clone(), "terminated": torch.zeros_like(trunc), "truncated": trunc},
        }, [b], device=device)
        td.update(algo.draw_noise((b,), g))
        tds.append(td)

    def sync():
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    t0 = time.perf_counter()
    algo.sgd_step(tds[0], step=0)
    sync()
    first = time.perf_counter() - t0
    for i in range(1, args.warmup):
        algo.sgd_step(tds[i % 4], step=i)
    sync()
    times = []
    for i in range(args.steps):  # step indices as the trainer's (policy delay, `aux_every` schedules)
        t = time.perf_counter()
        algo.sgd_step(tds[i % 4], step=args.warmup + i)
        sync()
        times.append(time.perf_counter() - t)
    return {"first_step_s": first, **_stats(times)}


def time_jax(args) -> dict:
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_default_matmul_precision", "highest")
    import sf2_jax
    from sf2_jax.agents import representations
    from sf2_jax.agents.algorithms import make_algorithm

    cfg = sf2_jax.SF2Config(**_sizes(args))
    algo = make_algorithm(args.algo, cfg, representations.get(args.repr))
    params, opt = algo.init(jax.random.PRNGKey(0))
    b, d, a = args.batch_size, cfg.obs_size, cfg.action_size
    keys = jax.random.split(jax.random.PRNGKey(1), 6)
    batch = sf2_jax.losses.Batch(
        obs=jax.random.normal(keys[0], (b, d)),
        action=jax.random.uniform(keys[1], (b, a), minval=-1, maxval=1),
        reward=jax.random.uniform(keys[2], (b,)), discount=jnp.ones((b,)),
        next_obs=jax.random.normal(keys[3], (b, d)), truncation=jnp.zeros((b,)))
    step = jax.jit(algo.sgd_step, donate_argnums=(0, 1))
    t0 = time.perf_counter()
    params, opt, m = step(params, opt, batch, keys[4], 0)
    jax.block_until_ready(m)
    first = time.perf_counter() - t0
    key = keys[5]
    for i in range(1, args.warmup):
        params, opt, m = step(params, opt, batch, jax.random.fold_in(key, i), i)
    jax.block_until_ready(m)
    times = []
    for i in range(args.steps):
        t = time.perf_counter()
        params, opt, m = step(params, opt, batch, jax.random.fold_in(key, 1000 + i), i)
        jax.block_until_ready((params, m))
        times.append(time.perf_counter() - t)
    return {"first_step_s": first, **_stats(times)}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m sf2_torch.agents.timing",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--algo", default="td3", choices=("td3", "sac"))
    p.add_argument("--repr", default="sf2", choices=("sf2", "none"))
    p.add_argument("--obs-size", type=int, default=17)
    p.add_argument("--action-size", type=int, default=6)
    p.add_argument("--feature-size", type=int, default=512)
    p.add_argument("--width", type=int, default=512)
    p.add_argument("--hidden-layers", type=int, default=3, help="ψ and policy hidden layers")
    p.add_argument("--zeta-hidden-layers", type=int, default=2)
    p.add_argument("--embedding-size", type=int, default=64)
    p.add_argument("--denoising-steps", type=int, default=1)
    p.add_argument("--batch-size", type=int, default=512)
    p.add_argument("--device", default="cpu")
    p.add_argument("--compile-mode", default="default", help="torch.compile mode of the compiled variant")
    p.add_argument("--variants", default="torch-eager,torch-compiled,jax",
                   help="comma list of torch-eager, torch-compiled, torch-cudagraphs, "
                        "torch-compiled-cudagraphs, jax")
    p.add_argument("--warmup", type=int, default=3)
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--threads", type=int, default=0, help="torch.set_num_threads (0: leave torch's default)")
    p.add_argument("--json", default="", help="also write the results to this file")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    results = {"config": vars(args), "machine": {
        "platform": platform.platform(), "cpu_count": os.cpu_count(), "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "gpu": torch.cuda.get_device_name() if args.device.startswith("cuda") else None}, "results": {}}
    for variant in [v.strip() for v in args.variants.split(",") if v.strip()]:
        print(f"timing {variant} ...", file=sys.stderr, flush=True)
        if variant == "jax":
            import jax

            results["machine"]["jax"] = jax.__version__
            results["machine"]["jax_devices"] = [str(dv) for dv in jax.devices()]
            res = time_jax(args)
        else:
            compiled = "compiled" in variant
            res = time_torch(args, args.compile_mode if compiled else None, "cudagraphs" in variant)
        results["results"][variant] = res
        print(f"  {variant:28} {res['median_ms']:9.2f} ms/step (IQR {res['p25_ms']:.2f}-{res['p75_ms']:.2f}; "
              f"first step {res['first_step_s']:.1f} s)", file=sys.stderr, flush=True)
    print(json.dumps(results, indent=2))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
