"""Variants of the SF² update timed beside the cores' code: `python -m bench.lab.variants` is
`python -m bench` with them registered.

- `psi-only`: TD3/SAC on ψ features with no flow loss, so SF² − psi-only is the flow step's share of
  the update;
- `x3tf32` / `x6bf16`: `sf2_jax.losses.flow_loss` with the contractions M = Wψ, M̄ = W̄ψ̄′ traced under an
  error-compensated XLA dot algorithm (3 TF32 / 6 bf16 passes, fp32 accumulation; GPU only);
- `wt-ode3xtf32` / `wt-ode6xbf16`: the same for the target field's evaluations (the ODE and the target).

None copies a loss: each is `flow_loss` with one `sf2_jax.networks` function traced under another
precision. `flow-step --variants x3tf32` times one in the flow step alone, `run --reps sf2-x3tf32` in the
agents' full update.

    python -m bench.lab.variants run --size paper --tasks cheetah --frameworks jax-scan \
        --reps none,sf2,psi-only,sf2-x3tf32
"""

from __future__ import annotations

import functools
import sys
from unittest import mock

import jax
from sf2_jax import losses
from sf2_jax import networks as nw
from sf2_jax.agents import representations

from bench import jax_steps, sizes

# variant: (the networks function traced under the algorithm, only its target=True calls, the algorithm)
PRECISION = {
    "x3tf32": ("contract", False, "TF32_TF32_F32_X3"),
    "x6bf16": ("contract", False, "BF16_BF16_F32_X6"),
    "wt-ode3xtf32": ("velocity_contracted", True, "TF32_TF32_F32_X3"),
    "wt-ode6xbf16": ("velocity_contracted", True, "BF16_BF16_F32_X6"),
}


def with_precision(function: str, target_only: bool, algorithm: str):
    """Build `flow_loss` with one networks function traced under another matmul precision.

    Args:
        function: the `sf2_jax.networks` function to trace under `algorithm` ("contract",
            "velocity_contracted").
        target_only: only its calls with `target=True`.
        algorithm: a `jax.default_matmul_precision` value (a dot algorithm preset or "highest").

    Returns:
        A function with `sf2_jax.losses.flow_loss`'s signature.
    """
    original = getattr(nw, function)

    def traced(*args, target=False, **kwargs):
        if target_only and not target:
            return original(*args, target=target, **kwargs)
        with jax.default_matmul_precision(algorithm):
            return original(*args, target=target, **kwargs)

    @functools.wraps(losses.flow_loss)
    def flow_loss(*args, **kwargs):
        with mock.patch.object(nw, function, traced):
            return losses.flow_loss(*args, **kwargs)

    return flow_loss


VARIANTS = {name: with_precision(*spec) for name, spec in PRECISION.items()}
jax_steps.FLOW_VARIANTS.update(VARIANTS)


def _sf2_variant(name: str, label: str, fn):
    class Variant(representations.SF2Representation):
        def aux_loss(self, params, batch, next_action, noise):
            return fn(self.nets, params, batch, next_action, noise["flow_noise"], noise["flow_time"])

    Variant.name, Variant.label = name, label
    Variant.__name__ = Variant.__qualname__ = f"SF2_{name.replace('-', '_')}"
    return representations.register(Variant)


@representations.register
class PsiOnly(representations.SF2Representation):
    """TD3/SAC on ψ features with no flow loss (ζ untouched): the SF² update minus its flow step."""

    name = "psi-only"
    label = "ψ critic, no flow loss"
    aux_groups = ()

    def targets(self):
        return {"target_psi": ("psi", self.cfg.tau)}


for _name, _fn in VARIANTS.items():
    _sf2_variant(f"sf2-{_name}", f"SF² ({_name})", _fn)

REPRESENTATIONS = ("psi-only", *(f"sf2-{n}" for n in VARIANTS))
sizes.VARIANT_REPS.update(REPRESENTATIONS)


if __name__ == "__main__":
    from bench.cli import main

    sys.exit(main())
