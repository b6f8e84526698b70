"""Full-step equivalence of the agents: one SGD step of `sf2_torch.agents` (TorchRL loss modules, torch
Adam, SoftUpdate targets) and of `sf2_jax.agents` (optax) from the same state leaves both identical.

From one canonical parameter file, fresh (then non-trivial) Adam states and the same batches and noise,
TD3+SF² and SAC+SF² take consecutive SGD steps in both frameworks (the JAX agents' jitted `sgd_step`,
the torch agents' eager `sgd_step`); after every step the test compares every parameter and target
(canonical names), every Adam first and second moment, and the step's metrics.

Noise: `sf2_jax.agents.algorithms.Algorithm.step_noise(key, batch)` draws every random input of the JAX
step (the step uses exactly that draw); the test hands the same arrays, under the same names (the torch
agents' `noise_keys()`), to torch, whose step takes its noise as input.

Tolerances: the `cross_bridge` ones (float64 1e-10 relative; float32 the "grad" bound 2e-4, since Adam divides
by √v̂ + ε and amplifies the rounding differences of the gradients). The largest differences per term are
printed at the end of the cross run.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sf2_jax
import sf2_torch
import torch
from cross_bridge import canonical_file, check, make_batch
from sf2_jax import params as jparams

pytest.importorskip("torchrl")
jalgs = pytest.importorskip("sf2_jax.agents.algorithms")
from sf2_jax.agents import representations as jreps  # noqa: E402
from sf2_torch import params as tparams  # noqa: E402
from sf2_torch.agents import algorithms as talgs  # noqa: E402
from sf2_torch.agents import representations as treps  # noqa: E402
from tensordict import TensorDict  # noqa: E402

KW = dict(obs_size=5, action_size=2, feature_size=16, hidden_sizes=(32, 32), q_hidden_size=32,
          zeta_hidden_sizes=(32, 32), embedding_size=8, denoising_steps=2)
BATCH = 16


def torch_td(batch: dict, noise: dict, dtype) -> TensorDict:
    """The TorchRL transition tensordict of a `cross_bridge.make_batch` batch (done = 1 − discount)."""
    def t(x):
        return torch.as_tensor(np.array(x), dtype=dtype)

    done = torch.as_tensor(np.asarray(batch["discount"]) == 0).unsqueeze(-1)
    trunc = torch.as_tensor(np.asarray(batch["truncation"]) > 0.5).unsqueeze(-1)
    td = TensorDict({
        "observation": t(batch["obs"]), "action": t(batch["action"]),
        "next": {"observation": t(batch["next_obs"]), "reward": t(batch["reward"]).unsqueeze(-1),
                 "done": done, "terminated": done & ~trunc, "truncated": trunc},
    }, [len(batch["reward"])])
    td.update({k: t(v) for k, v in noise.items()})
    return td


def _canonical_name(group: str, module: torch.nn.Module, name: str, p: torch.Tensor):
    """(canonical name, array in canonical layout) of parameter `name` of `module` in `group`."""
    mod_name, leaf = name.rsplit(".", 1)
    sub = module.get_submodule(mod_name)
    arr = p.detach().cpu().numpy()
    if isinstance(sub, torch.nn.Linear) and leaf == "weight":
        return f"{group}.{mod_name}.kernel", arr.T
    if isinstance(sub, torch.nn.LayerNorm) and leaf == "weight":
        return f"{group}.{mod_name}.scale", arr
    return f"{group}.{mod_name}.{leaf}", arr


def torch_moments(talg) -> dict[str, dict[str, np.ndarray]]:
    """{"mu"|"nu": {canonical name: moment}} of every trained group of the torch agent."""
    out = {"mu": {}, "nu": {}}
    for group, opt in talg.optimizers.items():
        if group == "log_alpha":
            st = opt.state[talg.loss.log_alpha]
            out["mu"]["log_alpha"] = st["exp_avg"].detach().numpy()
            out["nu"]["log_alpha"] = st["exp_avg_sq"].detach().numpy()
            continue
        module = getattr(talg.nets, group)
        for name, p in module.named_parameters():
            st = opt.state[p]
            for k, sk in (("mu", "exp_avg"), ("nu", "exp_avg_sq")):
                cname, arr = _canonical_name(group, module, name, st[sk])
                out[k][cname] = arr
    return out


def jax_moments(jopt) -> dict[str, dict[str, np.ndarray]]:
    out = {"mu": {}, "nu": {}}
    for group, state in jopt.items():
        adam = state[0]
        for k in ("mu", "nu"):
            tree = getattr(adam, k)
            flat = {group: np.asarray(tree)} if group == "log_alpha" else jparams.to_canonical({group: tree})
            out[k].update(flat)
    return out


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("algo,policy_delay", [("td3", 1), ("td3", 2), ("sac", 1)])
def test_full_sgd_step(tmp_path, dtype, algo, policy_delay):
    kw = dict(KW, policy_delay=policy_delay)
    path = canonical_file(tmp_path, kw, algo, seed=21)
    jdt, tdt = getattr(jnp, dtype), getattr(torch, dtype)

    jalg = jalgs.make_algorithm(algo, sf2_jax.SF2Config(**kw), jreps.get("sf2"), dtype=jdt)
    jp = jparams.from_canonical(jparams.load(path), jalg.nets, dtype=jdt)
    jopt = {g: jalg._tx(g).init(jp[g]) for g in jalg.trained_groups()}
    jstep = jax.jit(jalg.sgd_step)

    torch.manual_seed(0)
    talg = talgs.make_algorithm(algo, sf2_torch.SF2Config(**kw), treps.get("sf2"), dtype=tdt)
    tparams.from_canonical(tparams.load(path), talg.nets)  # after construction: SoftUpdate copies at init
    assert set(talg.groups) == set(jalg.trained_groups())

    first = tparams.to_canonical(talg.nets)
    for step in range(3):
        raw, _ = make_batch(kw, BATCH, seed=300 + step, truncation=step != 0)
        jb = sf2_jax.losses.Batch(**{k: jnp.asarray(v, dtype=jdt) for k, v in raw.items()})
        key = jax.random.PRNGKey(step)
        noise = {k: np.asarray(v) for k, v in jalg.step_noise(key, jb).items()}
        assert list(noise) == list(talg.noise_keys())
        jp, jopt, jm = jstep(jp, jopt, jb, key, step)
        tm = talg.sgd_step(torch_td(raw, noise, tdt), step=step)

        jflat, tflat = jparams.to_canonical(jp), tparams.to_canonical(talg.nets)
        assert set(jflat) == set(tflat)
        for name in sorted(jflat):
            check(f"agent step: {name.split('.')[0]}", jflat[name], tflat[name], dtype, kind="grad")
        jmom, tmom = jax_moments(jopt), torch_moments(talg)
        for k in ("mu", "nu"):
            assert set(jmom[k]) == set(tmom[k])
            for name in sorted(jmom[k]):
                check(f"agent step: adam {k}", jmom[k][name], tmom[k][name], dtype, kind="grad")
        assert set(jm) == set(tm.keys()), (sorted(jm), sorted(tm.keys()))
        for name in jm:
            check(f"agent step: metric {name}", np.asarray(jm[name]), tm[name].numpy(), dtype, kind="grad")

    # Everything trained moved, and the targets moved at their own rates.
    last = tparams.to_canonical(talg.nets)
    for group in ("psi", "zeta", "q", "policy", "target_psi", "target_zeta", "target_q"):
        assert any(not np.array_equal(first[n], last[n]) for n in first if n.startswith(group + "."))
