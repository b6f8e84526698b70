"""Seeds spread over several local devices (`Program.mesh`, a `shard_map` over the "seed" axis; opt-in with
`SF2_SHARD_SEEDS=1`).

A subprocess with two host CPU devices (`--xla_force_host_platform_device_count=2`; XLA reads the flag
once, before the backend starts) trains seeds (0, 1), one per device, for three epochs; the test checks that
- without `SF2_SHARD_SEEDS=1` two devices give no mesh (the run stays on one device),
- building a sharded program switches the process from the Shardy partitioner to GSPMD (Shardy's pass
  segfaults on GPUs),
- every array of the final state is split over both devices (one seed each),
- the compiled epoch program holds no cross-device collective (nothing crosses devices inside an epoch),
- each seed's epoch metrics, parameters and evaluation returns (the sharded `evaluate` program) equal that
  seed trained and evaluated alone on one device (here, in this one-device process, through the same
  `get_program` the other tests use), up to float32 rounding (`test_training.py`'s tolerance for programs
  of different seed counts).
The child compiles only the two-device program; the one-seed program is this process's.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("mujoco_playground", reason="the trainer needs the [train] extra (playground)")

EPOCHS = (1, 2, 3)

SCRIPT = textwrap.dedent('''
    import json, os, re, sys, tempfile
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_compilation_cache_dir", tempfile.mkdtemp())   # the HLO check's compile: a hit
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    from sf2_common.agents.configs import TrainConfig
    from sf2_jax.agents.trainer import get_program

    program = get_program(TrainConfig.from_dict(json.loads(sys.argv[1])))
    assert len(jax.local_devices()) == 2, jax.local_devices()
    os.environ.pop("SF2_SHARD_SEEDS")
    assert program.mesh(2) is None          # opt-in only
    os.environ["SF2_SHARD_SEEDS"] = "1"
    assert program.mesh(2) is not None and program.mesh(3) is None   # 3 seeds do not divide over 2
    assert jax.config.jax_use_shardy_partitioner      # JAX's default: asking for a mesh changes nothing
    state, arrays = program.init((0, 1)), {}
    assert not jax.config.jax_use_shardy_partitioner  # the sharded programs compile with GSPMD (_program)
    for epoch in EPOCHS:
        state, m, _ = program.epoch(state, epoch)
        arrays.update({f"epoch{epoch}/{k}": np.asarray(v) for k, v in jax.device_get(m).items()})
    arrays.update({f"param{i}": np.asarray(x) for i, x in enumerate(jax.tree_util.tree_leaves(state.params))})
    arrays["eval_returns"] = np.asarray(program.evaluate(state.params, state.eval_start, (0, 1), EPOCHS[-1]))
    np.savez(sys.argv[2], **arrays)
    devices = sorted({len(x.sharding.device_set) for x in jax.tree_util.tree_leaves(state)})
    hlo = program._program("epoch", 2).lower(state, jnp.int32(0)).compile().as_text()
    collectives = sorted(set(re.findall(
        r"all-gather|all-reduce|all-to-all|collective-permute|reduce-scatter", hlo)))
    print(json.dumps({"devices": devices, "collectives": collectives}))
''').replace("EPOCHS", repr(EPOCHS))


def _alone(cfg, seed):
    """`seed` trained alone on this process's one device: {name: array} as the child writes them."""
    import jax
    from sf2_jax.agents.trainer import get_program

    program = get_program(cfg)
    state, arrays = program.init((seed,)), {}
    for epoch in EPOCHS:
        state, m, _ = program.epoch(state, epoch)
        arrays.update({f"epoch{epoch}/{k}": np.asarray(v) for k, v in jax.device_get(m).items()})
    arrays.update({f"param{i}": np.asarray(x) for i, x in enumerate(jax.tree_util.tree_leaves(state.params))})
    arrays["eval_returns"] = np.asarray(program.evaluate(state.params, state.eval_start, (seed,), EPOCHS[-1]))
    return arrays


def test_seeds_spread_over_two_devices_without_collectives(tiny_cfg, tmp_path):
    import jax

    assert len(jax.local_devices()) == 1, jax.local_devices()
    env = {**os.environ, "XLA_FLAGS": os.environ.get("XLA_FLAGS", "") +
           " --xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu", "SF2_SHARD_SEEDS": "1"}
    proc = subprocess.run([sys.executable, "-c", SCRIPT, tiny_cfg.to_json(), str(tmp_path / "both.npz")],
                          env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-4000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["devices"] == [2], result        # every state array split over both devices
    assert result["collectives"] == [], result     # no cross-device traffic in the epoch program

    both = dict(np.load(tmp_path / "both.npz"))
    for seed in (0, 1):
        alone = _alone(tiny_cfg, seed)
        assert sorted(alone) == sorted(both)
        assert any(k.startswith("epoch3/") for k in alone) and "param0" in alone
        assert np.all(alone["eval_returns"] > 0), alone["eval_returns"]   # episodes that scored something
        for k, y in alone.items():
            x = both[k][seed]
            if k.startswith("param"):
                np.testing.assert_allclose(x, y[0], rtol=1e-4, atol=1e-6, err_msg=k)
            else:
                np.testing.assert_allclose(x, y[0], rtol=1e-4, atol=1e-5, err_msg=k)


def test_a_run_stays_on_one_device_unless_opted_in(monkeypatch):
    """Two local devices (the one CPU device listed twice): without `SF2_SHARD_SEEDS=1` no mesh, and `train`
    says how to use both; with it, seeds that do not divide over the devices still stay on one."""
    import jax
    from sf2_jax.agents import trainer

    device = jax.local_devices()[0]
    assert trainer.device_note(4) is None                      # one device: nothing to say
    monkeypatch.setattr(trainer.jax, "local_devices", lambda: [device, device])
    monkeypatch.delenv(trainer.SHARD_SEEDS, raising=False)
    assert trainer.Program.mesh(4) is None
    note = trainer.device_note(4)
    assert note.startswith("note: this host has 2 CPU devices and this run uses one; run one run per device "
                           "with `study run`") and "SF2_SHARD_SEEDS=1" in note
    monkeypatch.setenv(trainer.SHARD_SEEDS, "1")
    assert trainer.Program.mesh(3) is None and trainer.device_note(3) == note
