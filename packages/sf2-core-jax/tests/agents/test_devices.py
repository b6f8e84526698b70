"""Seeds spread over several local devices (`Program.mesh`, a `shard_map` over the "seed" axis).

Runs in a subprocess with two host CPU devices (`--xla_force_host_platform_device_count=2`; XLA reads the
flag once, before the backend starts): seeds (0, 1) train one per device, and the test checks that
- every array of the final state is split over both devices (one seed each),
- the compiled epoch program holds no cross-device collective (nothing crosses devices inside an epoch),
- each seed's epoch metrics and parameters equal that seed trained alone on one device, up to float32
  rounding (`test_training.py`'s tolerance for programs of different seed counts).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("mujoco_playground", reason="the trainer needs the [train] extra (playground)")

SCRIPT = textwrap.dedent('''
    import json, re, sys, tempfile
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_compilation_cache_dir", tempfile.mkdtemp())   # the HLO check's compile: a hit
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    from sf2_common.agents.configs import TrainConfig
    from sf2_jax.agents.trainer import get_program

    program = get_program(TrainConfig.from_dict(json.loads(sys.argv[1])))
    assert len(jax.local_devices()) == 2, jax.local_devices()

    def run(seeds):
        state, means = program.init(seeds), []
        for epoch in (1, 2, 3):
            state, m, _ = program.epoch(state, epoch)
            means.append(jax.device_get(m))
        return state, means

    both, alone = run((0, 1)), [run((s,)) for s in (0, 1)]
    devices = sorted({len(x.sharding.device_set) for x in jax.tree_util.tree_leaves(both[0])})
    hlo = program._program("epoch", 2).lower(both[0], jnp.int32(0)).compile().as_text()
    collectives = sorted(set(re.findall(
        r"all-gather|all-reduce|all-to-all|collective-permute|reduce-scatter", hlo)))
    worst = 0.0
    for i in (0, 1):
        state, means = alone[i]
        for ma, mb in zip(both[1], means):
            for k in ma:
                np.testing.assert_allclose(np.asarray(ma[k])[i], np.asarray(mb[k])[0], rtol=1e-4, atol=1e-5,
                                           err_msg=k)
        for x, y in zip(jax.tree_util.tree_leaves(both[0].params), jax.tree_util.tree_leaves(state.params)):
            x, y = np.asarray(x)[i], np.asarray(y)[0]
            np.testing.assert_allclose(x, y, rtol=1e-4, atol=1e-6)
            worst = max(worst, float(np.max(np.abs(x - y))))
    print(json.dumps({"devices": devices, "collectives": collectives, "worst": worst}))
''')


def test_seeds_spread_over_two_devices_without_collectives(tiny_cfg, tmp_path):
    env = {**os.environ, "XLA_FLAGS": os.environ.get("XLA_FLAGS", "") +
           " --xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    proc = subprocess.run([sys.executable, "-c", SCRIPT, tiny_cfg.to_json(), str(tmp_path)], env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-4000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["devices"] == [2], result        # every state array split over both devices
    assert result["collectives"] == [], result     # no cross-device traffic in the epoch program
