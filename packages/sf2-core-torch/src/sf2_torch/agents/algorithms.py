"""Base algorithms TD3 and SAC, written once against the representation interface (torch mirror of
`sf2_jax.agents.algorithms`).

One SGD step follows docs/core-contract.md "One SGD step" (the authors' order), exactly as the JAX agents:
1. critic step: Adam on `q` + `representation.critic_groups` from the TD loss;
2. representation step: Adam on `representation.aux_groups` (after step 1) from its own loss;
3. actor step (every `policy_delay`): Adam on the policy from Q (and features) as they were *before*
   step 1; SAC also takes its temperature step from the pre-step policy;
4. targets: TD3 averages Q̄ and π̄ into the targets on actor steps; SAC averages Q̄ every step; the
   representation's targets (SF²: ψ̄ at τ, ζ̄ at τ_ζ) every step.

How torch gets "pre-step" values without copying parameters: the critic loss module computes the TD,
actor and temperature losses in one forward from the parameters as they are at the start of the step
(TorchRL's convention: the actor loss reads Q and ψ through detached parameters, the TD target reads the
targets and the policy without gradient), and one backward fills the disjoint gradients of (Q, ψ), the
policy and log α. Step 1 applies the (Q, ψ) gradients; step 2 recomputes ψ's gradient from the flow loss
on the updated ψ; step 3 applies the policy and temperature gradients kept from the first backward.

Each group has its own `torch.optim.Adam` (lr `learning_rate`, ε `adam_eps`; log α: lr
`alpha_learning_rate`, ε 1e-8 as optax's default), so ψ, trained in steps 1 and 2, keeps one state across
both, as in the authors' code and the JAX agents. Targets move with TorchRL `SoftUpdate`s (one per loss
module), run inside the step as one `torch._foreach_lerp_` per rate.

All randomness is explicit: `sgd_step(td, step)` reads every noise tensor from `td` (keys listed by
`noise_keys()`: the algorithm's, then the representation's `noise_keys`, the same names as sf2_jax's
`Algorithm.step_noise`); `draw_noise(shape, generator)` is the thin wrapper that draws them.

Schedules (`step`, the run's gradient-step index, a host int as the trainer counts it): the actor step
is taken when `step % policy_delay == 0`; a group of `representation.aux_every` ({group: period})
takes its aux Adam step only when `step % period == 0`. Off its period that group's Adam does not step,
so its parameters and whole Adam state (moments and step count) stay as they were: the authors' separate
task-vector optimizer only steps when it is used, and sf2_jax keeps the same by `jnp.where`. The
schedule is decided on the host: each combination (actor step or not, the groups skipped) is its own
step function, so nothing in a step branches on a device value.

Compilation: `torch.compile` (`compile_mode`) compiles the two loss forwards, `_critic_losses` and
`_aux_losses`, each once; AOTAutograd compiles their backward with them, so the compiled code is the
loss + gradient computation. The Adam steps and the target lerps run outside it: dynamo guards on the
optimizer object, so a compiled `Optimizer.step` recompiles once per parameter group (4 to 5 groups,
each a full compilation), which buys nothing at these sizes. On CUDA (`cudagraphs`) the whole step of
each schedule combination (compiled forwards, backward, capturable Adam, lerps) is captured as one CUDA
graph by tensordict's `CudaGraphModule`. The step does no `.item()` and no host synchronization.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import torch
from sf2_common.agents.registry import check_aux_every
from tensordict import TensorDict, TensorDictBase
from torchrl.objectives import SoftUpdate

from sf2_torch import networks
from sf2_torch.config import SF2Config

from .objectives import target_pairs
from .representations import Representation

__all__ = ["Algorithm", "TD3", "SAC", "make_algorithm", "METRICS", "check_aux_every"]

METRICS = {
    "td3": ("critic_loss", "q", "actor_loss"),
    "sac": ("critic_loss", "q", "actor_loss", "alpha_loss", "alpha", "entropy"),
}


class Algorithm:
    """Shared machinery: networks, loss modules, per-group Adam, target updaters, the SGD step skeleton."""

    name = ""
    policy_groups: tuple[str, ...] = ()

    def __init__(self, cfg: SF2Config, representation_cls: type[Representation], dtype=torch.float32,
                 device="cpu", compile_mode: str | None = None, cudagraphs: bool = False):
        self.cfg = cfg
        self.dtype = dtype
        self.device = torch.device(device)
        self.nets = networks.make_networks(cfg, self.name, dtype=dtype, device=self.device)
        self.rep = representation_cls(cfg, self.nets)
        check_aux_every(self.rep)
        self.loss = self.rep.critic_loss(self.name)
        self.q_updater = SoftUpdate(self.loss, tau=cfg.tau)
        groups = dict(self.rep.groups(self.loss))
        groups["policy"] = list(self.nets.policy.parameters())
        if self.name == "sac":
            groups["log_alpha"] = [self.loss.log_alpha]
        self.groups = {g: groups[g] for g in self.trained_groups()}
        capturable = bool(cudagraphs)
        self.optimizers = {g: self._make_adam(g, self.groups[g], capturable) for g in self.groups}
        self._q_targets = target_pairs(self.q_updater)
        self._rep_targets = target_pairs(self.rep.target_updater) if self.rep.target_updater else []
        self.compile_mode = compile_mode
        self.cudagraphs = bool(cudagraphs)
        self._steps: dict[tuple[bool, frozenset[str]], Any] = {}
        self._forwards: dict[str, Any] = {}

    # ------------------------------------------------------------------ parameters and optimizers
    def _make_adam(self, group, params, capturable):
        cfg = self.cfg
        lr = cfg.alpha_learning_rate if group == "log_alpha" else cfg.learning_rate
        eps = 1e-8 if group == "log_alpha" else cfg.adam_eps
        if capturable:
            lr = torch.tensor(lr, device=self.device)
        # CUDA: the fused kernel (one launch per group, also under CUDA-graph capture); elsewhere foreach
        fused = self.device.type == "cuda"
        return torch.optim.Adam(params, lr=lr, eps=eps, capturable=capturable,
                                fused=True if fused else None, foreach=None if fused else True)

    def trained_groups(self) -> tuple[str, ...]:
        groups = ["q", *self.rep.critic_groups, *self.rep.aux_groups, *self.policy_groups]
        return tuple(dict.fromkeys(groups))

    def modules(self) -> torch.nn.ModuleDict:
        """Every module whose state a checkpoint must hold (shared tensors appear more than once)."""
        mods = {"nets": self.nets, "loss": self.loss}
        if self.rep.aux_loss is not None:
            mods["aux_loss"] = self.rep.aux_loss
        return torch.nn.ModuleDict(mods)

    def state_dict(self) -> dict:
        return {"modules": self.modules().state_dict(),
                "optimizers": {g: o.state_dict() for g, o in self.optimizers.items()}}

    def load_state_dict(self, state: dict) -> None:
        self.modules().load_state_dict(state["modules"])
        for g, o in self.optimizers.items():
            o.load_state_dict(state["optimizers"][g])

    def canonical(self) -> dict[str, np.ndarray]:
        """Every parameter group in the canonical naming of `sf2_torch.params` (for `final/`)."""
        return self.rep.canonical(self.loss)

    def adam_moments(self) -> dict[str, dict[str, list[torch.Tensor]]]:
        """{group: {"mu": [...], "nu": [...], "step": [...]}} in the order of `self.groups[group]`."""
        out = {}
        for g, opt in self.optimizers.items():
            st = [opt.state.get(p, {}) for p in self.groups[g]]
            out[g] = {"mu": [s.get("exp_avg") for s in st], "nu": [s.get("exp_avg_sq") for s in st],
                      "step": [s.get("step") for s in st]}
        return out

    # ------------------------------------------------------------------ acting (overridden)
    @torch.no_grad()
    def explore(self, obs: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        raise NotImplementedError

    @torch.no_grad()
    def act(self, obs: torch.Tensor, generator: torch.Generator, deterministic: bool) -> torch.Tensor:
        raise NotImplementedError

    @torch.no_grad()
    def observe(self, obs: torch.Tensor) -> None:
        """Brax's running-statistics update of the observation normalizer with a batch of observations."""
        networks.update_normalizer(self.nets.obs_norm, obs, self.cfg)

    # ------------------------------------------------------------------ noise (the thin wrapper)
    def _randn(self, shape, generator):
        return torch.randn(*shape, self.cfg.action_size, dtype=self.dtype, device=self.device,
                           generator=generator)

    def noise_keys(self) -> tuple[str, ...]:
        raise NotImplementedError

    def draw_noise(self, shape: tuple[int, ...], generator: torch.Generator) -> dict[str, torch.Tensor]:
        """Every random input of `shape` SGD steps' losses (e.g. (G, B)), drawn from `generator`."""
        raise NotImplementedError

    # ------------------------------------------------------------------ the SGD step
    def aux_next_action(self, td: TensorDictBase) -> torch.Tensor:
        raise NotImplementedError

    def _critic_total(self, out: dict[str, torch.Tensor], actor_step: bool) -> torch.Tensor:
        raise NotImplementedError

    def _actor_metrics(self, out: dict[str, torch.Tensor], actor_step: bool) -> dict[str, torch.Tensor]:
        raise NotImplementedError

    def _updates_q_target(self, actor_step: bool) -> bool:
        raise NotImplementedError

    def _adam(self, group: str) -> None:
        self.optimizers[group].step()

    def _zero(self, groups) -> None:
        for g in groups:
            for p in self.groups[g]:
                p.grad = None

    def _critic_losses(self, td: TensorDictBase) -> dict[str, torch.Tensor]:
        """The critic loss module's forward (TD, actor and temperature losses from the parameters as they
        are): {entry: tensor}. Compiled by `_forward`."""
        out = self.loss(td)
        return {k: out.get(k) for k in out.keys()}

    def _aux_losses(self, td: TensorDictBase) -> dict[str, torch.Tensor]:
        """ā′ (no gradient) and the representation loss module's forward: {entry: tensor}. Compiled by
        `_forward`."""
        with torch.no_grad():
            next_action = self.aux_next_action(td)
        aux_td = td.clone(False)
        aux_td.set(self.rep.aux_loss.tensor_keys.next_action, next_action)
        out = self.rep.aux_loss(aux_td)
        return {k: out.get(k) for k in out.keys()}

    def _forward(self, name: str):
        """`_critic_losses` or `_aux_losses`, `torch.compile`d once when `compile_mode` is set."""
        fn = self._forwards.get(name)
        if fn is None:
            fn = getattr(self, name)
            if self.compile_mode is not None:
                # fill the flow-time embedding's table cache first: a miss inside the traced region
                # would make dynamo recompile once on the next call (its guard on the cache)
                p = next(self.nets.parameters())  # its device carries the index ("cuda:0"), as k's will
                networks._embedding_tables(self.cfg.embedding_size, p.dtype, p.device)
                fn = torch.compile(fn, mode=self.compile_mode)
            self._forwards[name] = fn
        return fn

    def _step(self, td: TensorDictBase, actor_step: bool, skip: frozenset[str] = frozenset()
              ) -> TensorDictBase:
        """One SGD step (module docstring) on the transition batch + noise `td`; returns metrics. The aux
        groups in `skip` (off their `aux_every` period) take no Adam step."""
        critic_groups = ("q", *self.rep.critic_groups)
        self._zero(self.groups)
        # 1. critic (the actor and temperature losses are evaluated here too, from pre-step parameters)
        out = self._forward("_critic_losses")(td)
        self._critic_total(out, actor_step).backward()
        for g in critic_groups:
            self._adam(g)
        metrics = {"critic_loss": out["loss_qvalue"].detach(), "q": out["pred_value"].detach()}
        # 2. the representation's own loss, on the parameters after step 1
        if self.rep.aux_loss is not None:
            self._zero(self.rep.aux_groups)
            aux = self._forward("_aux_losses")(td)
            aux[self.rep.aux_loss_key].backward()
            for g in self.rep.aux_groups:
                if g not in skip:
                    self._adam(g)
            for k, v in aux.items():
                metrics[self.rep.aux_loss_name if k == self.rep.aux_loss_key else k] = v.detach()
        # 3. actor (and temperature), with the gradients of the pre-step parameters
        if actor_step:
            for g in self.policy_groups:
                self._adam(g)
        metrics.update(self._actor_metrics(out, actor_step))
        # 4. targets
        with torch.no_grad():
            pairs = list(self._rep_targets)
            if self._updates_q_target(actor_step):
                pairs += self._q_targets
            for w, targets, sources in pairs:
                torch._foreach_lerp_(targets, sources, w)
        return TensorDict(metrics, [])

    def _step_fn(self, actor_step: bool, skip: frozenset[str]):
        """The step of one schedule combination (a CUDA graph of its own with `cudagraphs`)."""
        fn = self._steps.get((actor_step, skip))
        if fn is None:
            fn = functools.partial(self._step, actor_step=actor_step, skip=skip)
            if self.cudagraphs:
                from tensordict.nn import CudaGraphModule

                fn = CudaGraphModule(fn, warmup=3)
            self._steps[(actor_step, skip)] = fn
        return fn

    def sgd_step(self, td: TensorDictBase, step: int = 0, *,
                 actor_step: bool | None = None) -> TensorDictBase:
        """One SGD step on `td` (a transition batch with every noise key). `step`: the gradient-step index
        (a host int; the trainer's counter, sf2_jax's `step`): the policy (and SAC's temperature) steps
        when `step % policy_delay == 0`, unless `actor_step` says otherwise, and each group of
        `representation.aux_every` when `step % period == 0` (module docstring). Returns a TensorDict of
        0-d metric tensors (no host synchronization)."""
        if actor_step is None:
            actor_step = step % self.cfg.policy_delay == 0
        skip = frozenset(g for g, every in self.rep.aux_every.items() if step % every)
        return self._step_fn(bool(actor_step), skip)(td)


class TD3(Algorithm):
    """TD3 (Fujimoto et al., 2018) on the representation's critic (Algorithm 2 for SF²)."""

    name = "td3"
    policy_groups = ("policy",)

    @torch.no_grad()
    def explore(self, obs, generator):
        """Authors' acting: π(s) + clip(σ_e ξ, −c, c), clipped to [−1, 1]."""
        cfg = self.cfg
        action = networks.td3_action(self.nets, obs)
        noise = torch.randn(action.shape, dtype=action.dtype, device=action.device, generator=generator)
        noise = torch.clamp(noise * cfg.exploration_noise, -cfg.noise_clip, cfg.noise_clip)
        return torch.clamp(action + noise, -1.0, 1.0)

    @torch.no_grad()
    def act(self, obs, generator, deterministic):
        return networks.td3_action(self.nets, obs) if deterministic else self.explore(obs, generator)

    def noise_keys(self):
        return ("smoothing_noise", *(self.rep.noise_keys if self.rep.aux_loss is not None else ()))

    def draw_noise(self, shape, generator):
        out = {"smoothing_noise": self._randn(shape, generator)}
        out.update(self.rep.aux_noise(shape, generator))
        return out

    def aux_next_action(self, td):
        """ā′ = π̄(s′) (no smoothing)."""
        return networks.td3_action(self.nets, td.get(("next", "observation")), target=True)

    def _critic_total(self, out, actor_step):
        total = out.get("loss_qvalue")
        return total + out.get("loss_actor") if actor_step else total

    def _actor_metrics(self, out, actor_step):
        loss = out.get("loss_actor").detach()
        return {"actor_loss": loss if actor_step else torch.zeros_like(loss)}

    def _updates_q_target(self, actor_step):
        return actor_step


class SAC(Algorithm):
    """SAC (Haarnoja et al., 2018) with a learned temperature, on the representation's critic
    (Algorithm 3 for SF²)."""

    name = "sac"
    policy_groups = ("policy", "log_alpha")

    @torch.no_grad()
    def explore(self, obs, generator):
        noise = torch.randn(*obs.shape[:-1], self.cfg.action_size, dtype=obs.dtype, device=obs.device,
                            generator=generator)
        return networks.sac_sample(self.nets, obs, noise)[0]

    @torch.no_grad()
    def act(self, obs, generator, deterministic):
        return networks.sac_mode(self.nets, obs) if deterministic else self.explore(obs, generator)

    def noise_keys(self):
        keys = ("next_action_noise", "actor_noise", "alpha_noise")
        if self.rep.aux_loss is not None:
            keys += ("flow_action_noise", *self.rep.noise_keys)
        return keys

    def draw_noise(self, shape, generator):
        out = {"next_action_noise": self._randn(shape, generator),
               "actor_noise": self._randn(shape, generator), "alpha_noise": self._randn(shape, generator)}
        if self.rep.aux_loss is not None:
            out["flow_action_noise"] = self._randn(shape, generator)
            out.update(self.rep.aux_noise(shape, generator))
        return out

    def aux_next_action(self, td):
        """ā′ ~ π(s′) with the explicit noise `flow_action_noise`."""
        return networks.sac_sample(self.nets, td.get(("next", "observation")), td.get("flow_action_noise"))[0]

    def _critic_total(self, out, actor_step):
        total = out.get("loss_qvalue")
        return total + out.get("loss_actor") + out.get("loss_alpha") if actor_step else total

    def _actor_metrics(self, out, actor_step):
        zero = torch.zeros_like(out.get("loss_actor").detach())
        keep = (lambda x: x.detach()) if actor_step else (lambda x: zero)
        return {"actor_loss": keep(out.get("loss_actor")), "alpha_loss": keep(out.get("loss_alpha")),
                "alpha": torch.exp(self.loss.log_alpha.detach()), "entropy": keep(out.get("entropy"))}

    def _updates_q_target(self, actor_step):
        return True


_ALGORITHMS = {"td3": TD3, "sac": SAC}


def make_algorithm(algo: str, cfg: SF2Config, representation_cls: type[Representation], dtype=torch.float32,
                   device="cpu", compile_mode: str | None = None, cudagraphs: bool = False) -> Algorithm:
    return _ALGORITHMS[algo](cfg, representation_cls, dtype, device, compile_mode, cudagraphs)
