"""Load one canonical parameter file into both cores and print every SF² loss term side by side.

    python scripts/parity_demo.py [--obs-size 5 --action-size 1 --batch 256 --steps 1 --dtype float64]

Builds paper-default networks (F = 512, hidden 512) for the given sizes, writes their canonical parameters
to a temporary .npz with sf2_jax, loads that file into sf2_torch, feeds both the same batch and the same
explicit noise, and prints each loss (and the largest gradient difference) with the relative difference.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--obs-size", type=int, default=5)
    ap.add_argument("--action-size", type=int, default=1)
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--steps", type=int, default=1, help="denoising steps T")
    ap.add_argument("--integrator", default="midpoint", choices=["midpoint", "euler"])
    ap.add_argument("--dtype", default="float64", choices=["float64", "float32"])
    args = ap.parse_args(argv)

    import jax

    jax.config.update("jax_enable_x64", args.dtype == "float64")
    jax.config.update("jax_default_matmul_precision", "highest")
    import jax.numpy as jnp
    import numpy as np
    import sf2_jax
    import sf2_torch
    import torch

    kw = dict(obs_size=args.obs_size, action_size=args.action_size, denoising_steps=args.steps,
              integrator=args.integrator)
    jcfg = sf2_jax.SF2Config(**kw)
    t0 = time.perf_counter()
    rows = []
    for algo in ("td3", "sac"):
        jn = sf2_jax.networks.make_networks(jcfg, algo)
        flat = sf2_jax.params.to_canonical(sf2_jax.networks.init_params(jn, jax.random.key(0)))
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / f"{algo}.npz"
            sf2_jax.params.save(path, flat)
            jp = sf2_jax.params.from_canonical(sf2_jax.params.load(path), jn, dtype=getattr(jnp, args.dtype))
            tn = sf2_torch.networks.make_networks(sf2_torch.SF2Config(**kw), algo)
            tn = tn.to(getattr(torch, args.dtype))
            sf2_torch.params.from_canonical(sf2_torch.params.load(path), tn)
        rng = np.random.default_rng(0)
        B, D, A = args.batch, args.obs_size, args.action_size
        raw = dict(obs=rng.normal(size=(B, D)), action=rng.uniform(-1, 1, (B, A)), reward=rng.normal(size=B),
                   discount=np.ones(B), next_obs=rng.normal(size=(B, D)), truncation=np.zeros(B))
        noise = dict(next_action=rng.uniform(-1, 1, (B, A)), eps=rng.normal(size=(B, D)),
                     flow_time=rng.uniform(size=B), a_noise=rng.normal(size=(B, A)))
        J = lambda x: jnp.asarray(x, dtype=getattr(jnp, args.dtype))  # noqa: E731
        T = lambda x: torch.as_tensor(x, dtype=getattr(torch, args.dtype))  # noqa: E731
        jb = sf2_jax.losses.Batch(**{k: J(v) for k, v in raw.items()})
        tb = sf2_torch.losses.Batch(**{k: T(v) for k, v in raw.items()})
        cases = [("flow_loss", ("next_action", "eps", "flow_time"))]
        if algo == "td3":
            cases += [("td3_critic_loss", ("a_noise",)), ("td3_actor_loss", ())]
        else:
            cases += [(f"sac_{n}_loss", ("a_noise",)) for n in ("critic", "actor", "alpha")]
        for name, keys in cases:
            extra = [J(noise[k]) for k in keys]
            jl, jaux = jax.jit(getattr(sf2_jax.losses, name), static_argnums=0)(jn, jp, jb, *extra)
            tl, taux = getattr(sf2_torch.losses, name)(tn, tb, *[T(noise[k]) for k in keys])
            rows.append((algo, name, float(jl), float(tl.detach())))
            for key in jaux:
                rows.append((algo, f"  {name}.{key}", float(jaux[key]), float(taux[key])))
    print(f"\nSF² losses, one canonical file in both cores ({args.dtype}; D={args.obs_size}, "
          f"A={args.action_size}, B={args.batch}, T={args.steps} {args.integrator}, paper network sizes)\n")
    print("| algo | term | JAX | torch | relative difference |\n|---|---|---|---|---|")
    for algo, name, a, b in rows:
        print(f"| {algo} | {name} | {a:.12g} | {b:.12g} | {abs(a - b) / max(abs(b), 1e-30):.2e} |")
    print(f"\n({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
