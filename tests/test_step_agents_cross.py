"""Full-step equivalence of the agents: consecutive SGD steps of `sf2_torch.agents` (the core losses on the
representation's critic, `backward(inputs=...)`, torch Adam, one lerp per rate) and of `sf2_jax.agents`
(the same losses, `jax.grad` over the trained groups, optax) leave both identical.

TD3 (policy delay 1 and 2) and SAC, each with SF² and vanilla (`none`: the same losses on the critic
Q(s, a), whose noise is explicit too), SF² also with k > 1 flow steps (`aux_steps_per_sgd_step`). Every
group of the agent (the algorithm's `obs_norm`, `policy`, `target_policy` | `log_alpha` and the
representation's) gets non-trivial values under its canonical name, loaded into both agents; fresh Adam
states; the same batches. After every step the test compares every parameter and target (canonical names),
every Adam first and second moment, and the step's metrics.

Noise: the JAX step's `Algorithm.step_noise(key, batch)` draws every random input; the test hands the same
arrays, under the same names (`noise_keys()` of both agents), to both `sgd_step`s. Tolerances:
tests/cross_bridge.py, docs/parity.md (float64 1e-10 relative; float32 the "grad" bound 5e-4, since Adam
divides by √v̂ + ε and amplifies the rounding differences of the gradients).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sf2_jax
import sf2_torch
import torch
from cross_bridge import canonical_values, check, make_batch
from sf2_jax import params as jparams
from sf2_jax.agents import algorithms as jalgs
from sf2_jax.agents import representations as jreps
from sf2_torch import params as tparams
from sf2_torch.agents import algorithms as talgs
from sf2_torch.agents import representations as treps

KW = dict(obs_size=5, action_size=2, feature_size=16, hidden_sizes=(32, 32), q_hidden_size=32,
          zeta_hidden_sizes=(32, 32), embedding_size=8, denoising_steps=2)
BATCH = 16


def _unflatten(flat: dict, like, dtype):
    """The nested JAX params of `like`'s structure holding the canonical `flat` values (as `dtype`)."""
    def fill(tree, prefix):
        if isinstance(tree, dict):
            return {k: fill(v, f"{prefix}{k}.") for k, v in tree.items()}
        return jnp.asarray(flat[prefix[:-1]], dtype)

    return fill(dict(like), "")


def talg_states(algo, rep, kw) -> set[str]:
    """The names of a torch agent's Adam states (one per trained group, `psi:aux` too when not shared)."""
    return set(talgs.make_algorithm(algo, sf2_torch.SF2Config(**kw), treps.get(rep)).optimizers)


def _renamed(flat: dict, group: str, state: str) -> dict:
    """`flat`'s canonical names of `group` under the name of its Adam state (`psi` -> `psi:aux`)."""
    return {state + name[len(group):]: v for name, v in flat.items()}


def torch_moments(talg) -> dict[str, dict[str, np.ndarray]]:
    """{"mu"|"nu": {canonical name: moment}} of every Adam state of the torch agent (a second state of a
    group, `psi:aux` with `shared_adam = False`, under its own name): exported as if they were gradients
    (`to_canonical(..., grads=True)` lays them out canonically)."""
    out = {"mu": {}, "nu": {}}
    for k, sk in (("mu", "exp_avg"), ("nu", "exp_avg_sq")):
        for state, opt in talg.optimizers.items():
            group = state.split(":")[0]
            saved = {}
            for p in talg._params((group,)):
                saved[p] = p.grad
                p.grad = opt.state[p][sk]
            flat = tparams.to_canonical({group: talg.groups[group]}, grads=True)
            out[k].update(_renamed(flat, group, state))
            for p, g in saved.items():
                p.grad = g
    return out


def jax_moments(jopt) -> dict[str, dict[str, np.ndarray]]:
    out = {"mu": {}, "nu": {}}
    for state, opt in jopt.items():
        adam, group = opt[0], state.split(":")[0]
        for k in ("mu", "nu"):
            tree = getattr(adam, k)
            flat = {group: np.asarray(tree)} if group == "log_alpha" else jparams.to_canonical({group: tree})
            out[k].update(_renamed(flat, group, state))
    return out


# (algo, representation, policy delay, shared_adam, aux_steps_per_sgd_step): shared_adam = False gives ψ a
# second Adam state for the flow loss's step; aux steps k > 1 repeat the flow step with the draws "<key>:more"
CASES = [("td3", "sf2", 1, True, 1), ("td3", "sf2", 2, True, 1), ("sac", "sf2", 1, True, 1),
         ("td3", "none", 2, True, 1), ("sac", "none", 1, True, 1), ("td3", "sf2", 1, False, 1),
         ("sac", "sf2", 1, True, 2), ("td3", "sf2", 2, False, 3)]


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("algo,rep,policy_delay,shared_adam,aux_steps", CASES,
                         ids=[f"{a}-{r}-delay{d}" + ("" if s else "-own-adam") + (f"-aux{k}" if k > 1 else "")
                              for a, r, d, s, k in CASES])
def test_full_sgd_step(dtype, algo, rep, policy_delay, shared_adam, aux_steps):
    kw = dict(KW, policy_delay=policy_delay, shared_adam=shared_adam, aux_steps_per_sgd_step=aux_steps)
    jdt, tdt = getattr(jnp, dtype), getattr(torch, dtype)

    jalg = jalgs.make_algorithm(algo, sf2_jax.SF2Config(**kw), jreps.get(rep), dtype=jdt)
    structure, _ = jalg.init(jax.random.PRNGKey(0))
    shapes = {name: np.shape(v) for name, v in jparams.to_canonical(structure).items()}
    flat = canonical_values(shapes, seed=21)
    jp = _unflatten(flat, structure, jdt)
    jopt = {g: jalg._tx(g).init(jp[g]) for g in jalg.trained_groups()}
    jopt.update({state: jalg._tx(g).init(jp[g]) for g, state in jalg.aux_states.items()})
    assert set(jopt) == set(jalg.init(jax.random.PRNGKey(0))[1]) == set(talg_states(algo, rep, kw))
    jstep = jax.jit(jalg.sgd_step)

    torch.manual_seed(0)
    talg = talgs.make_algorithm(algo, sf2_torch.SF2Config(**kw), treps.get(rep), dtype=tdt)
    tparams.from_canonical(flat, talg.groups)  # validates: the same canonical names and shapes
    assert set(talg.groups) == set(jp) and talg.trained_groups() == jalg.trained_groups()
    assert talg.noise_keys() == jalg.noise_keys()

    first = tparams.to_canonical(talg.groups)
    for step in range(3):
        raw, _ = make_batch(kw, BATCH, seed=300 + step, truncation=step != 0)
        jb = sf2_jax.losses.Batch(**{k: jnp.asarray(v, dtype=jdt) for k, v in raw.items()})
        tb = sf2_torch.losses.Batch(**{k: torch.as_tensor(np.asarray(v), dtype=tdt) for k, v in raw.items()})
        jnoise = jalg.step_noise(jax.random.PRNGKey(step), jb)
        assert list(jnoise) == list(talg.noise_keys())
        jp, jopt, jm = jstep(jp, jopt, jb, jnoise, step)
        tm = talg.sgd_step(tb, {k: torch.as_tensor(np.array(v)) for k, v in jnoise.items()}, step)

        jflat, tflat = jparams.to_canonical(jp), tparams.to_canonical(talg.groups)
        assert set(jflat) == set(tflat)
        for name in sorted(jflat):
            check(f"agent step {rep}: {name.split('.')[0]}", jflat[name], tflat[name], dtype, kind="grad")
        jmom, tmom = jax_moments(jopt), torch_moments(talg)
        for k in ("mu", "nu"):
            assert set(jmom[k]) == set(tmom[k])
            for name in sorted(jmom[k]):
                check(f"agent step {rep}: adam {k}", jmom[k][name], tmom[k][name], dtype, kind="grad")
        assert set(jm) == set(tm), (sorted(jm), sorted(tm))
        for name in jm:
            check(f"agent step {rep}: metric {name}", np.asarray(jm[name]), tm[name].numpy(), dtype,
                  kind="grad")

    # Everything trained moved, and the targets moved (at their own rates, compared above).
    last = tparams.to_canonical(talg.groups)
    moving = {g for g in talg.groups if g != "obs_norm"}
    for group in moving:
        assert any(not np.array_equal(first[n], last[n]) for n in first if n.split(".")[0] == group), group
