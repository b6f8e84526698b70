"""What a training checkpoint costs: the time a run waits for `Checkpointer.save`, with the write awaited
and in the background (`save(wait=False)`, what the trainers do), and for `restore`.

    python -m bench.lab.checkpoint_cost --task CheetahRun --algo sac --repr none --seeds 10 [--repeats 3]
        [--framework jax|torch]

The state is the `paper` preset's for that many seeds, built from the program's abstract state: random
normals, each replay buffer filled only in its first `--fill` rows (the end of a 1M-step run), so the files
compress as a real run's last checkpoint does. Per repeat: `save` awaited; `save(wait=False)` until it
returns, then `finish`; `restore`. Medians over the repeats after one warm-up.
docs/decisions/background-checkpoints.md records what it measured."""

from __future__ import annotations

import argparse
import math
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

from bench.report import print_rows

FIELDS = ("framework", "task", "algo", "repr", "seeds", "state_gb", "save_awaited_s", "save_returns_s",
          "finish_s", "restore_s", "device")


def _state(cfg, fill: float, abstract):
    import jax
    import jax.numpy as jnp
    import numpy as np

    rng = np.random.default_rng(0)
    used = max(1, round(fill * cfg.max_replay_size))

    def leaf(x):
        if not jnp.issubdtype(x.dtype, jnp.floating) or math.prod(x.shape) == 0:
            return jnp.zeros(x.shape, x.dtype)
        if len(x.shape) >= 2 and x.shape[1] == cfg.max_replay_size:
            a = np.zeros(x.shape, x.dtype)
            a[:, :used] = rng.standard_normal((x.shape[0], used, *x.shape[2:]), dtype=np.float32)
            return jnp.asarray(a)
        return jnp.asarray(rng.standard_normal(x.shape, dtype=np.float32).astype(x.dtype))

    return jax.tree_util.tree_map(leaf, abstract)


def _timings(save, restore, repeats: int) -> dict:
    """Medians over `repeats` (after one warm-up) of `save(epoch, wait=True)`, of `save(epoch,
    wait=False)` until it returns and then its `finish`, and of `restore(epoch)`; `save` returns the
    checkpointer's `finish`."""
    times = {k: [] for k in ("save_awaited_s", "save_returns_s", "finish_s", "restore_s")}
    for i in range(repeats + 1):   # the first is a warm-up
        t = time.perf_counter()
        save(2 * i, True)
        awaited = time.perf_counter() - t
        t = time.perf_counter()
        finish = save(2 * i + 1, False)
        returns = time.perf_counter() - t
        t = time.perf_counter()
        finish()
        done = time.perf_counter() - t
        t = time.perf_counter()
        restore(2 * i + 1)
        restored = time.perf_counter() - t
        if i:
            for k, v in zip(times, (awaited, returns, done, restored), strict=True):
                times[k].append(v)
    return {k: round(statistics.median(v), 3) for k, v in times.items()}


def measure(task: str, algo: str, rep: str, seeds: int, repeats: int, fill: float, folder: Path) -> dict:
    import jax
    from sf2_common.agents import configs
    from sf2_jax.agents.checkpoint import Checkpointer
    from sf2_jax.agents.trainer import get_program

    cfg = configs.make_config("paper", task, algo, rep, {"num_timesteps": 1_000_000})
    abstract = get_program(cfg).abstract_state(tuple(range(seeds)))
    state = _state(cfg, fill, abstract)
    jax.block_until_ready(state)
    gb = sum(math.prod(x.shape) * x.dtype.itemsize for x in jax.tree_util.tree_leaves(abstract)) / 1e9
    ckpt = Checkpointer(folder, keep=2)

    def save(epoch, wait):
        ckpt.save(epoch, state, {}, wait=wait)
        return ckpt.finish

    try:
        times = _timings(save, lambda e: jax.block_until_ready(ckpt.restore(e, abstract)[0]), repeats)
    finally:
        ckpt.close()
    return {"framework": "jax", "task": task, "algo": algo, "repr": rep, "seeds": seeds,
            "state_gb": round(gb, 2), **times, "device": jax.devices()[0].device_kind}


def measure_torch(task: str, algo: str, rep: str, seeds: int, repeats: int, fill: float,
                  folder: Path) -> dict:
    import numpy as np
    import torch
    from sf2_torch.agents import configs
    from sf2_torch.agents.checkpoint import Checkpointer
    from sf2_torch.agents.trainer import get_program

    cfg = configs.make_config("paper", task, algo, rep, {"num_timesteps": 1_000_000})
    program = get_program(cfg)
    state = program.init(tuple(range(seeds)))
    actions = torch.zeros(seeds, cfg.num_envs, program.spec.action_size, device=program.device)
    template = program._env_step(state, actions)[0][:1]     # one transition's keys, shapes and dtypes
    used, chunk = max(1, round(fill * cfg.max_replay_size)), 65_536
    gen = torch.Generator(device=program.device).manual_seed(0)
    for agent in state.agents:
        for start in range(0, used, chunk):
            batch = template.expand(min(chunk, used - start)).clone()
            for x in batch.values(include_nested=True, leaves_only=True):
                if x.is_floating_point():
                    x.copy_(torch.randn(x.shape, generator=gen, device=x.device))
            agent.replay.insert(batch)
    sd = program.state_dict(state)
    leaves = state.env.get_state_leaves()
    gb = (sum(t.numel() * t.element_size() for t in _tensors(sd))
          + sum(np.asarray(x).nbytes for x in leaves)) / 1e9
    ckpt = Checkpointer(folder, keep=2)

    def save(epoch, wait):
        ckpt.save(epoch, sd, leaves, {}, wait=wait)
        return ckpt.finish

    try:
        times = _timings(save, lambda e: ckpt.restore(e, map_location=program.device), repeats)
    finally:
        ckpt.close()
    device = torch.cuda.get_device_name() if program.device.type == "cuda" else "cpu"
    return {"framework": "torch", "task": task, "algo": algo, "repr": rep, "seeds": seeds,
            "state_gb": round(gb, 2), **times, "device": device}


def _tensors(tree):
    import torch

    if isinstance(tree, torch.Tensor):
        return [tree]
    values = tree.values() if isinstance(tree, dict) else tree if isinstance(tree, list | tuple) else ()
    return [t for v in values for t in _tensors(v)]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.lab.checkpoint_cost",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="CheetahRun")
    parser.add_argument("--algo", default="sac", choices=("td3", "sac"))
    parser.add_argument("--repr", default="none", dest="rep")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--fill", type=float, default=1_001_088 / 4_194_304,
                        help="the filled fraction of each replay buffer (default: the end of a 1M-step run)")
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: a temporary folder)")
    parser.add_argument("--framework", default="jax", choices=("jax", "torch"),
                        help="whose trainer state and checkpointer (default: jax)")
    parser.add_argument("--markdown", action="store_true", help="a Markdown table instead of JSON lines")
    args = parser.parse_args(argv)
    if args.seeds < 1 or args.repeats < 1 or not 0 < args.fill <= 1:
        parser.error("--seeds and --repeats are ints >= 1; --fill is in (0, 1]")
    from sf2_common.errors import ConfigError

    folder = Path(tempfile.mkdtemp(prefix="ckpt-", dir=args.dir))
    try:
        run = measure if args.framework == "jax" else measure_torch
        row = run(args.task, args.algo, args.rep, args.seeds, args.repeats, args.fill, folder / "c")
    except ConfigError as err:   # an unknown task, algorithm or representation: named with the choices
        parser.error(str(err))
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    print_rows([row], FIELDS, args.markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
