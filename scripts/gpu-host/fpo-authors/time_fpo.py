"""Time FPO's authors' own training iteration (akanazawa/fpo, playground/src/flow_policy, unmodified).

Their `FpoConfig` defaults (2048 envs × 480 steps per iteration, 16 passes of 32 minibatches), one seed, on
Playground's MJX backend `impl = "jax"` (their pinned Playground's only one; the newer default, warp, is not
carried). Each iteration is their `rollout` then `training_step`, timed from dispatch to
`jax.block_until_ready`; the first holds the compilation. Prints one JSON line: env steps per iteration,
each iteration's seconds, the median after the first and the rate.

    python3 time_fpo.py --env CheetahRun --iters 6 [--out rate.json]
"""

import argparse
import json
import statistics
import time

import jax
from flow_policy import fpo, rollouts
from mujoco_playground import registry


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="CheetahRun")
    p.add_argument("--iters", type=int, default=6, help="timed iterations, the first with compilation")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="also write the JSON line to this file")
    args = p.parse_args()
    env = registry.load(args.env, config_overrides={"impl": "jax"})
    config = fpo.FpoConfig()
    agent = fpo.FpoState.init(prng=jax.random.key(args.seed), env=env, config=config)
    state = rollouts.BatchedRolloutState.init(env, prng=jax.random.key(args.seed), num_envs=config.num_envs)
    seconds = []
    for _ in range(args.iters):
        start = time.perf_counter()
        state, transitions = state.rollout(agent, episode_length=config.episode_length,
                                           iterations_per_env=config.iterations_per_env)
        agent, metrics = agent.training_step(transitions)
        jax.block_until_ready((agent, metrics, state))
        seconds.append(time.perf_counter() - start)
    steps = config.iterations_per_env * config.num_envs
    median = statistics.median(seconds[1:])
    row = {"code": "akanazawa/fpo (authors')", "env": args.env, "seeds": 1, "env_steps_per_iteration": steps,
           "iteration_s": [round(s, 4) for s in seconds], "median_s_after_first": round(median, 4),
           "env_steps_per_s": round(steps / median, 1), "device": str(jax.devices()[0].device_kind)}
    print(json.dumps(row))
    if args.out:
        with open(args.out, "w") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
