"""Train one model for every (γ, seed) at once and sample its EMA parameters at each evaluation step.

One `jax.jit` program per model: `jax.vmap` over the runs (the (γ, seed) grid flattened), `lax.scan` over
the training steps, EMA of the parameters after every step (`sf2_jax.losses.ema_update` with rate
1 − decay; the EMA starts at the initial parameters), and the EMA parameters snapshotted after the steps of
`Settings.eval_steps()`. The snapshots are then sampled (`Settings.eval_samples` each) in the same program.

Randomness: run (γ, seed) of model m uses `fold_in(key(seed), index of m in MODELS)`, the same key for
every γ (common random numbers across γ); evaluation noise is the same for every snapshot of a run.
"""

from __future__ import annotations

from itertools import groupby

import jax
import jax.numpy as jnp
import numpy as np

from sf2_jax.losses import ema_update

from .models import MODELS, Model, Settings

__all__ = ["run_grid"]


def _segments(settings: Settings) -> list[tuple[int, int]]:
    """[(length, count), …]: the training steps between consecutive evaluations, run-length encoded, so each
    distinct length compiles one scan body (1500 steps every 200 → [(200, 7), (100, 1)])."""
    bounds = (0, *settings.eval_steps())
    lengths = [b - a for a, b in zip(bounds[:-1], bounds[1:])]
    return [(length, len(list(group))) for length, group in groupby(lengths)]


def _train(model: Model, settings: Settings, key, gamma):
    """One run: (EMA parameter snapshots with a leading axis E, final training loss)."""
    k_init, k_train = jax.random.split(key)
    params = model.init(k_init)
    carry = (params, model.opt_init(params), params, jnp.zeros((), jnp.result_type(float)))
    rate = 1.0 - settings.ema_decay

    def step(carry, k):
        params, opt_state, ema, _ = carry
        params, opt_state, loss = model.update(params, opt_state, k, gamma)
        return (params, opt_state, ema_update(ema, params, rate), loss), None

    snapshots = []
    done = 0
    for length, count in _segments(settings):
        keys = jax.random.split(jax.random.fold_in(k_train, done), (count, length))

        def segment(carry, seg_keys):
            carry, _ = jax.lax.scan(step, carry, seg_keys)
            return carry, carry[2]

        carry, snaps = jax.lax.scan(segment, carry, keys)
        snapshots.append(snaps)
        done += length * count
    return jax.tree_util.tree_map(lambda *s: jnp.concatenate(s), *snapshots), carry[3]


def _grid(model: Model, settings: Settings, keys, gammas):
    """keys, gammas (R,) → samples (R, E, n), last losses (R,). Training is vmapped over the R runs;
    sampling maps over the R·E snapshots one at a time (`lax.map`), so each snapshot's activations
    (n × width) stay in cache instead of streaming R·E·n × width floats through memory per ODE step."""
    train_keys, eval_keys = jax.vmap(jax.random.split, out_axes=1)(keys)
    snapshots, loss = jax.vmap(lambda k, g: _train(model, settings, k, g))(train_keys, gammas)
    r, e = len(keys), len(settings.eval_steps())
    flat = jax.tree_util.tree_map(lambda p: p.reshape(r * e, *p.shape[2:]), snapshots)
    flat_keys = jnp.repeat(eval_keys, e)          # the same evaluation noise for every snapshot of a run
    samples = jax.lax.map(lambda a: model.sample(a[0], a[1], settings.eval_samples), (flat, flat_keys))
    return samples.reshape(r, e, settings.eval_samples), loss


def run_grid(model: Model, settings: Settings, gammas, seeds) -> tuple[np.ndarray, np.ndarray]:
    """Samples (G, S, E, n) of the EMA parameters at `settings.eval_steps()` and the last training loss
    (G, S), for γ ∈ `gammas` × seed ∈ `seeds`, in one compiled program."""
    gammas, seeds = tuple(float(g) for g in gammas), tuple(int(s) for s in seeds)
    index = MODELS.index(model.name)
    g_grid = jnp.asarray([g for g in gammas for _ in seeds])
    keys = jnp.stack([jax.random.fold_in(jax.random.key(s), index) for _ in gammas for s in seeds])
    samples, loss = jax.device_get(jax.jit(_grid, static_argnums=(0, 1))(model, settings, keys, g_grid))
    shape = (len(gammas), len(seeds))
    return np.asarray(samples).reshape(*shape, *samples.shape[1:]), np.asarray(loss).reshape(shape)
