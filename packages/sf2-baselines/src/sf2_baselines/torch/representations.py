"""The baselines as pluggable representations of `sf2_torch.agents` (TD3 and SAC, `--repr NAME`).

The torch mirror of `sf2_baselines.jax.representations`; `init(core)` builds the baseline's modules with
`make_networks(..., core=core)`, so the normalizer, the policy, its target and log α are the agent's own.
`register_all()` adds them to the registry; `sf2_baselines.torch` calls it on import.

==================  ==============  ==================  =====================================  ============
name                critic trains   aux step trains     aux loss                               targets (τ)
==================  ==============  ==================  =====================================  ============
``sim``             q, phi          task                sim.reward_loss (every 10 TD3/16 SAC)  φ̄
``simlap``          q               phi, task           simlap.simlap_loss (w every 10/16)     φ̄
``simlap_authors``  q, phi          phi, task           simlap.simlap_loss (w every 10/16)     φ̄
``spr``             q, encoder      encoder, proj, pred spr.spr_loss                           f̄, ḡ
==================  ==============  ==================  =====================================  ============
The w schedules are `Representation.aux_every`.
"""

from __future__ import annotations

import torch
from sf2_torch.agents import representations as reps

from . import sim, simlap, spr

__all__ = [
    "SimRepresentation",
    "SimLapRepresentation",
    "SimLapAuthorsRepresentation",
    "SPRRepresentation",
    "register_all",
    "NAMES",
]

NAMES = ("sim", "simlap", "simlap_authors", "spr")


def _kw(core) -> dict:
    p = core.obs_norm.mean
    return dict(dtype=p.dtype, device=p.device, core=core)


def _groups(nets, names) -> dict:
    return {name: getattr(nets, name) for name in names}


class _SimBase(reps.Representation):
    aux_loss_name = "reward_loss"

    def __init__(self, cfg, nets):
        super().__init__(cfg, nets)
        self.aux_every = {"task": sim.REWARD_EVERY[nets.algo]}

    def init(self, core):
        self.baseline_nets = sim.make_networks(self.cfg, core.algo, **_kw(core))
        return _groups(self.baseline_nets, sim.GROUPS)

    def critic(self, obs, action, target=False):
        return sim.critic(self.baseline_nets, obs, action, target)

    def targets(self):
        return {"target_phi": ("phi", self.cfg.tau)}


@reps.register
class SimRepresentation(_SimBase):
    """`sim`: TD3Sim / SACSim, Chua et al. (2024) as the SF² paper runs them (§4.2).

    The TD loss trains the SF heads and φ; the reward-prediction step trains w every `sim.REWARD_EVERY[algo]`
    gradient steps (`aux_every`).
    """

    name = "sim"
    label = "Sim"
    critic_groups = ("phi",)
    aux_groups = ("task",)

    def aux_loss(self, batch, next_action, noise):
        return sim.reward_loss(self.baseline_nets, batch, next_action)


@reps.register
class SimLapRepresentation(_SimBase):
    """`simlap`: TD3SimLap / SACSimLap as the paper describes them (§4.2).

    No Q-alignment of φ: the TD loss trains the SF heads only; the aux step trains φ by the Laplacian
    objective and w by reward prediction (w every `sim.REWARD_EVERY[algo]` steps).
    """

    name = "simlap"
    label = "SimLap"
    critic_groups = ()
    aux_groups = ("phi", "task")
    aux_loss_name = "simlap_loss"

    def aux_loss(self, batch, next_action, noise):
        return simlap.simlap_loss(self.baseline_nets, batch, next_action)


@reps.register
class SimLapAuthorsRepresentation(SimLapRepresentation):
    """`simlap_authors`: SimLap as the authors' code runs it.

    The TD loss also trains φ (their `critic_update` updates the feature parameters), then the Laplacian step
    trains φ again.
    """

    name = "simlap_authors"
    label = "SimLap(code)"
    critic_groups = ("phi",)


@reps.register
class SPRRepresentation(reps.Representation):
    """`spr`: TD3+SPR / SAC+SPR (Appendix B.1), self-predictive representations for state inputs.

    The critic sits on the encoder z = f(s, a), trained by the TD loss; the SPR step trains f, g and h on the
    K = 1 self-prediction loss, with Gaussian augmentation of std `cfg.spr_augmentation_std` (paper Figure 5
    sweeps it).
    """

    name = "spr"
    label = "SPR"
    critic_groups = ("encoder",)
    aux_groups = ("encoder", "projection", "prediction")
    aux_loss_name = "spr_loss"
    noise_keys = ("spr_obs_noise", "spr_next_obs_noise")

    def init(self, core):
        self.baseline_nets = spr.make_networks(
            self.cfg, core.algo, augmentation_std=self.cfg.spr_augmentation_std, **_kw(core))
        return _groups(self.baseline_nets, spr.GROUPS)

    def critic(self, obs, action, target=False):
        return spr.critic(self.baseline_nets, obs, action, target)

    def aux_noise(self, generator, batch):
        kw = dict(dtype=batch.obs.dtype, device=batch.obs.device, generator=generator)
        return {"spr_obs_noise": torch.randn(batch.obs.shape, **kw),
                "spr_next_obs_noise": torch.randn(batch.next_obs.shape, **kw)}

    def aux_loss(self, batch, next_action, noise):
        obs_noise, next_obs_noise = noise["spr_obs_noise"], noise["spr_next_obs_noise"]
        return spr.spr_loss(self.baseline_nets, batch, next_action, obs_noise, next_obs_noise)

    def targets(self):
        tau = self.cfg.tau
        return {"target_encoder": ("encoder", tau), "target_projection": ("projection", tau)}


def register_all() -> tuple[str, ...]:
    """(Re-)register every baseline with `sf2_torch.agents.representations`; returns their names."""
    for cls in (SimRepresentation, SimLapRepresentation, SimLapAuthorsRepresentation, SPRRepresentation):
        reps.register(cls)
    return NAMES
