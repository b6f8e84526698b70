"""The two cores' `SF2Config` are one contract: same fields, same order, same defaults, same validation.

Both cores re-export the one class of `sf2_common.config` (the framework-free package each core depends
on), so today the copies cannot drift; this test keeps the contract checked should a core ever define its
own class again.
"""

from __future__ import annotations

import dataclasses

import pytest
import sf2_jax
import sf2_torch


def test_same_fields_and_defaults():
    jf = [(f.name, f.default) for f in dataclasses.fields(sf2_jax.SF2Config)]
    tf = [(f.name, f.default) for f in dataclasses.fields(sf2_torch.SF2Config)]
    assert jf == tf


def test_small_preset_agrees():
    assert dataclasses.asdict(sf2_jax.SF2Config.small(5, 1)) == dataclasses.asdict(
        sf2_torch.SF2Config.small(5, 1)
    )


@pytest.mark.parametrize(
    "bad",
    [
        dict(denoising_steps=0),
        dict(gamma_su=1.0),
        dict(gamma_su=-0.1),
        dict(integrator="rk4"),
        dict(embedding_size=7),
        dict(feature_size=0),
    ],
    ids=lambda b: next(iter(b)),
)
def test_same_validation(bad):
    """Both reject the same bad values, and each message names the field."""
    messages = []
    for core in (sf2_jax, sf2_torch):
        with pytest.raises(core.ConfigError) as err:
            core.SF2Config(obs_size=5, action_size=1, **bad)
        messages.append(str(err.value))
        assert next(iter(bad)) in str(err.value)
    assert messages[0] == messages[1]
