"""Base algorithms TD3 and SAC, written once against the representation interface.

The losses are the core's (`sf2_torch.losses`, with `critic=` the representation's critic); this module
schedules them: one SGD step in the authors' order (docs/core-contract.md "One SGD step"), every random
input drawn up front by `step_noise` (keys `noise_keys()`, the JAX agents' too) so `sgd_step` is pure.
The vocabulary is the JAX agents' (docs/core-contract.md "Agents: the plug-in vocabulary");
torch methods update the modules the algorithm holds in place and take a `torch.Generator` where JAX takes
a PRNG key. Each loss's gradient lands only in the groups it trains (`loss.backward(inputs=...)`); one
Adam per trained group (`shared_adam = False` gives ψ's aux step a second one, `optimizers["psi:aux"]`).

The schedule (`aux_every`, `policy_delay`, the Q̄ update) is decided on the host: each combination is its
own step function, so nothing branches on a device value and the step never synchronizes. `torch.compile`
(`compile_mode`) compiles the loss parts with their backward; on CUDA the Adam steps and target lerps too,
and `graphs.StepGraph` replays each combination's whole step as one CUDA graph
(docs/decisions/torch-trainer-step.md).
"""

from __future__ import annotations

import functools
from collections import defaultdict
from typing import Any

import torch
from sf2_common.agents.registry import aux_states, check_aux_every, check_aux_steps
from sf2_common.config import SF2Config
from torch import nn
from torch.optim.adam import adam as functional_adam

from sf2_torch import losses, networks
from sf2_torch.agents.graphs import StepGraph

from .representations import Representation

__all__ = ["Algorithm", "TD3", "SAC", "make_algorithm"]

Metrics = dict[str, torch.Tensor]


class Algorithm:
    """The SGD step skeleton (module docstring), the groups and their per-group Adam states."""

    name = ""
    policy_groups: tuple[str, ...] = ()
    critic_noise_key = ""   # the `step_noise` entry of the TD loss
    _aux_action_noise_keys: tuple[str, ...] = ()   # ā′'s `step_noise` entries (SAC: flow_action_noise)

    def __init__(self, cfg: SF2Config, representation_cls: type[Representation], dtype=torch.float32,
                 device="cpu", compile_mode: str | None = None, cudagraphs: bool = False):
        self.cfg = cfg
        self.dtype = dtype
        self.device = torch.device(device)
        self.nets = networks.make_networks(cfg, self.name, dtype=dtype, device=self.device)
        self.rep = representation_cls(cfg, self.nets)
        check_aux_every(self.rep)
        check_aux_steps(cfg, self.rep)
        # {group: module | parameter}: the algorithm's groups, then the representation's (as the JAX core's
        # `init` returns its params)
        core = ("obs_norm", "policy", "target_policy", "log_alpha")
        self.groups: dict[str, nn.Module | nn.Parameter] = {
            n: getattr(self.nets, n) for n in core if hasattr(self.nets, n)}
        self.groups.update(self.rep.init(self.nets))
        self.compile_mode = compile_mode
        # the Adam steps and target lerps compiled too (`_update`): on CUDA, where they pay
        self.compile_updates = compile_mode is not None and self.device.type == "cuda"
        capturable = bool(cudagraphs) or self.compile_updates
        self.optimizers = {g: self._make_adam(g, capturable) for g in self.trained_groups()}
        self.aux_states = aux_states(cfg, self.rep)   # {aux group: its optimizer's name in optimizers}
        self.optimizers.update({state: self._make_adam(g, capturable)
                                for g, state in self.aux_states.items() if state != g})
        self.cudagraphs = bool(cudagraphs)
        self._steps: dict[tuple, Any] = {}
        self._compiled: dict[str, Any] = {}
        self._policy_names: tuple[str, ...] | None = None

    # ------------------------------------------------------------------ parameters and optimizers
    def _params(self, groups) -> list[torch.Tensor]:
        out = []
        for g in groups:
            value = self.groups[g]
            out += [value] if isinstance(value, torch.Tensor) else list(value.parameters())
        return out

    def _make_adam(self, group: str, capturable: bool) -> torch.optim.Adam:
        cfg = self.cfg
        lr = cfg.alpha_learning_rate if group == "log_alpha" else cfg.learning_rate
        eps = 1e-8 if group == "log_alpha" else cfg.adam_eps
        if capturable:
            lr = torch.tensor(lr, device=self.device)
        # eager on CUDA: the fused kernel (one launch per group, also under CUDA-graph capture); compiled
        # (`_adam`) and elsewhere: foreach (torch.compile traces torch's foreach Adam)
        fused = self.device.type == "cuda" and not self.compile_updates
        return torch.optim.Adam(self._params((group,)), lr=lr, eps=eps, capturable=capturable,
                                fused=True if fused else None, foreach=None if fused else True)

    def trained_groups(self) -> tuple[str, ...]:
        groups = ["q", *self.rep.critic_groups, *self.rep.aux_groups, *self.policy_groups]
        return tuple(dict.fromkeys(groups))

    def state_dict(self) -> dict:
        """Every group (modules' state dicts, parameters' values) and every Adam state."""
        return {"groups": {g: (v.detach().clone() if isinstance(v, torch.Tensor) else v.state_dict())
                           for g, v in self.groups.items()},
                "optimizers": {g: o.state_dict() for g, o in self.optimizers.items()}}

    def load_state_dict(self, state: dict) -> None:
        for g, v in self.groups.items():
            if isinstance(v, torch.Tensor):
                with torch.no_grad():
                    v.copy_(state["groups"][g])
            else:
                v.load_state_dict(state["groups"][g])
        for g, o in self.optimizers.items():
            (group,) = o.param_groups
            flags = {k: group[k] for k in ("capturable", "fused", "foreach", "lr")}
            o.load_state_dict(state["optimizers"][g])
            # this agent's Adam implementation, whichever wrote the checkpoint: torch's load_state_dict takes
            # the saved flags and learning rate (a run with compiled updates resuming a checkpoint of a fused
            # Adam would step it fused; a CPU run resuming a CUDA-graph run's would get a tensor learning
            # rate, which foreach Adam refuses without capturable). The learning rate is the config's either
            # way. The step counts go where this agent's flags keep them (its device when capturable or
            # fused, else the CPU).
            o.param_groups[0].update(flags)
            device = self.device if flags["capturable"] or flags["fused"] else torch.device("cpu")
            for s in o.state.values():
                s["step"] = s["step"].to(device=device, dtype=torch.float32)

    # ------------------------------------------------------------------ acting (overridden)
    @torch.no_grad()
    def explore(self, obs: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        raise NotImplementedError

    @torch.no_grad()
    def act(self, obs: torch.Tensor, generator: torch.Generator, deterministic: bool) -> torch.Tensor:
        raise NotImplementedError

    # ------------------------------------------------------------------ noise (the thin wrapper)
    def noise_keys(self) -> tuple[str, ...]:
        raise NotImplementedError

    def _algo_noise(self, generator: torch.Generator, batch: losses.Batch) -> dict[str, torch.Tensor]:
        raise NotImplementedError

    def _randn(self, generator, batch):
        a = batch.action
        return torch.randn(a.shape, dtype=a.dtype, device=a.device, generator=generator)

    def aux_noise_keys(self) -> tuple[str, ...]:
        """The `noise_keys()` of the representation's step (step 3): ā′'s noise (SAC), then the
        representation's `noise_keys`; empty without an aux loss."""
        if not self.rep.aux_groups:
            return ()
        return (*self._aux_action_noise_keys, *self.rep.noise_keys)

    def _more_aux_keys(self) -> tuple[str, ...]:
        """"<key>:more" for each of `aux_noise_keys()` when `aux_steps_per_sgd_step` > 1: the draws of the
        later representation steps, stacked on an axis of size k − 1 before the batch axis."""
        if self.cfg.aux_steps_per_sgd_step == 1:
            return ()
        return tuple(f"{k}:more" for k in self.aux_noise_keys())

    def _aux_action_noise(self, generator, batch) -> dict[str, torch.Tensor]:
        return {}

    def step_noise(self, generator: torch.Generator, batch: losses.Batch) -> dict[str, torch.Tensor]:
        """Every random input of one SGD step on `batch`, drawn from `generator` (module docstring): the
        keys are `noise_keys()`, shapes from `batch.obs.shape[:-1]` (a (G, B) stack of batches draws G
        steps' noise at once). Order: the algorithm's noise, then the representation's `aux_noise`, then
        with k = `aux_steps_per_sgd_step` > 1 the draws of representation steps 2..k ("<key>:more", shape
        (..., k − 1, B, ...))."""
        noise = self._algo_noise(generator, batch)
        if self.rep.aux_groups:
            aux = self.rep.aux_noise(generator, batch)
            if set(aux) != set(self.rep.noise_keys):
                raise ValueError(f"{type(self.rep).__name__}.aux_noise returned {sorted(aux)}, but its "
                                 f"noise_keys are {self.rep.noise_keys}")
            noise.update(aux)
        if self._more_aux_keys():
            more = self._aux_step_noise(generator, _repeated(batch, self.cfg.aux_steps_per_sgd_step - 1))
            noise.update({f"{k}:more": more[k] for k in self.aux_noise_keys()})
        return noise

    def _aux_step_noise(self, generator, batch) -> dict[str, torch.Tensor]:
        """The random inputs of representation steps (`aux_noise_keys()`) with `batch`'s shapes: ā′'s,
        then the representation's `aux_noise`."""
        return {**self._aux_action_noise(generator, batch), **self.rep.aux_noise(generator, batch)}

    # ------------------------------------------------------------------ the losses (overridden)
    def critic_loss(self, batch: losses.Batch, noise: dict[str, torch.Tensor]):
        """The TD loss of the representation's critic with `noise[critic_noise_key]`: (loss, aux)."""
        raise NotImplementedError

    def policy_losses(self, batch: losses.Batch, noise: dict[str, torch.Tensor]) -> dict[str, tuple]:
        """{policy group: (metric name, loss, aux metrics)}, each at the current parameters."""
        raise NotImplementedError

    def aux_next_action(self, batch: losses.Batch, noise: dict[str, torch.Tensor]) -> torch.Tensor:
        """ā′, the next action of the representation's loss."""
        raise NotImplementedError

    def updates_q_target(self, step: int) -> bool:
        """Whether Q̄ (TD3: and π̄) move this step."""
        raise NotImplementedError

    def _actor_step(self, step: int) -> bool:
        return step % self.cfg.policy_delay == 0

    # ------------------------------------------------------------------ the SGD step
    def sgd_step(self, batch: losses.Batch, noise: dict[str, torch.Tensor], step: int) -> Metrics:
        """One SGD step (module docstring) on the 2-D `batch` with `noise` (keys `noise_keys()`, from
        `step_noise`); `step` is the gradient-step index (policy delay, `aux_every`), a host int. Returns
        the metrics, a dict of 0-d tensors (no host synchronization)."""
        step = int(step)
        skip = frozenset(g for g, every in self.rep.aux_every.items() if step % every)
        actor_step = self._actor_step(step)
        if not actor_step and self._policy_names is None:  # the metrics a step without policy step zeroes
            with torch.no_grad():
                self._policy_names = tuple(self._policy(batch, noise)[1])
        return self._step_fn(actor_step, skip, self.updates_q_target(step))(batch, noise)

    def _step_fn(self, actor_step: bool, skip: frozenset[str], q_target: bool):
        """The step of one schedule combination (a CUDA graph of its own with `cudagraphs`)."""
        key = (actor_step, skip, q_target)
        fn = self._steps.get(key)
        if fn is None:
            pairs = {"target_q": ("q", self.cfg.tau)}
            if "target_policy" in self.groups:
                pairs["target_policy"] = ("policy", self.cfg.tau)
            lerps = self._lerps({**(pairs if q_target else {}), **self.rep.targets()})
            fn = functools.partial(self._step, actor_step=actor_step, skip=skip, lerps=lerps)
            if self.cudagraphs:
                fn = StepGraph(fn, warmup=3)
            self._steps[key] = fn
        return fn

    def _step(self, batch, noise, actor_step: bool, skip: frozenset[str], lerps) -> Metrics:
        """One SGD step (module docstring) of one schedule combination; returns the metrics."""
        rep = self.rep
        critic_groups = ("q", *rep.critic_groups)
        self._zero(self.trained_groups())
        # 1. the critic gradient and the policy groups' gradients at the pre-step parameters
        loss, metrics = self._part("_critic")(batch, noise)
        loss.backward(inputs=self._params(critic_groups))
        if actor_step:
            policy, policy_metrics = self._part("_policy")(batch, noise)
            # no policy loss reaches another policy group: one backward serves them all
            torch.autograd.backward(list(policy.values()), inputs=self._params(policy))
        # 2. Adam on the critic groups
        self._adam(critic_groups)
        # 3. the representation's own loss, on the parameters after step 2 (`aux_steps_per_sgd_step` times)
        if rep.aux_groups:
            metrics.update(self._aux_step(batch, noise, skip))
            if self.cfg.aux_steps_per_sgd_step > 1:
                self._more_aux_steps(batch, noise, skip)
        # 4. Adam on the policy groups (actor steps only; zeros as their metrics otherwise)
        if actor_step:
            self._adam(self.policy_groups)
        else:
            policy_metrics = {name: torch.zeros_like(metrics["q"]) for name in self._policy_names}
        metrics.update(policy_metrics)
        if "log_alpha" in self.groups:  # SAC's temperature after this step
            metrics["alpha"] = torch.exp(self.groups["log_alpha"].detach())
        # 5. targets
        if lerps:
            self._update("_move_targets", _move_targets)(lerps)
        return metrics

    def _aux_step(self, batch, noise, skip: frozenset[str]) -> Metrics:
        """One representation step (step 3 of the SGD step): θ_aux ← Adam(θ_aux, ∇ L_aux(θ; ā′, ξ)).

        Args:
          batch: the minibatch.
          noise: the draws of this step, keyed by `aux_noise_keys()` (more keys are ignored).
          skip: the aux groups off their `aux_every` period (no Adam step).

        Returns:
          {aux loss name: loss, its aux metrics} at the parameters before this step.
        """
        rep = self.rep
        self._zero(rep.aux_groups)
        loss, aux_metrics = self._part("_aux")(batch, noise)
        loss.backward(inputs=self._params(rep.aux_groups))
        self._adam(self.aux_states[g] for g in rep.aux_groups if g not in skip)
        return aux_metrics

    def _more_aux_steps(self, batch, noise, skip: frozenset[str]) -> None:
        """Representation steps 2..k (`aux_steps_per_sgd_step` = k) after the first: `_aux_step` with draw j
        of noise["<key>:more"]; their metrics are not reported (the step's are the first representation
        step's)."""
        for j in range(self.cfg.aux_steps_per_sgd_step - 1):
            self._aux_step(batch, {k: noise[f"{k}:more"][j] for k in self.aux_noise_keys()}, skip)

    # the parts of the step, compiled by `_part`
    def _critic(self, batch, noise):
        loss, aux = self.critic_loss(batch, noise)
        return loss, {"critic_loss": loss.detach(), "q": aux["q"]}

    def _policy(self, batch, noise):
        losses_, metrics = {}, {}
        for group, (name, loss, aux) in self.policy_losses(batch, noise).items():
            losses_[group] = loss
            metrics.update({name: loss.detach(), **aux})
        return losses_, metrics

    def _aux(self, batch, noise):
        with torch.no_grad():
            next_action = self.aux_next_action(batch, noise)
        loss, aux = self.rep.aux_loss(batch, next_action, {k: noise[k] for k in self.rep.noise_keys})
        return loss, {self.rep.aux_loss_name: loss.detach(), **aux}

    def _part(self, name: str):
        """`_critic`, `_policy` or `_aux`, `torch.compile`d once when `compile_mode` is set."""
        fn = self._compiled.get(name)
        if fn is None:
            fn = getattr(self, name)
            if self.compile_mode is not None:
                # fill the flow-time embedding's table cache first: a miss inside the traced region
                # would make dynamo recompile once on the next call (its guard on the cache)
                p = self.nets.obs_norm.mean  # its device carries the index ("cuda:0"), as k's will
                networks._embedding_tables(self.cfg.embedding_size, p.dtype, p.device)
                fn = torch.compile(fn, mode=self.compile_mode)
            self._compiled[name] = fn
        return fn

    def _zero(self, groups) -> None:
        for p in self._params(groups):
            p.grad = None

    def _adam(self, groups) -> None:
        optimizers = [self.optimizers[g] for g in groups]
        if not self.compile_updates or not all(o.state for o in optimizers):
            for optimizer in optimizers:   # eager; an optimizer's first step also creates its state
                optimizer.step()
        elif optimizers:
            self._update("_adam_steps", _adam_steps)([_adam_inputs(o) for o in optimizers])

    def _update(self, name: str, fn):
        """`_adam_steps` or `_move_targets`, `torch.compile`d when `compile_updates` (module docstring,
        "Compilation": with `compile_mode` on CUDA). Their inputs are lists of tensors, so one program serves
        every seed's agent whose tensors have the same shapes (`dynamic=False`: each keeps its exact
        shapes)."""
        if not self.compile_updates:
            return fn
        compiled = self._compiled.get(name)
        if compiled is None:
            compiled = self._compiled[name] = torch.compile(fn, dynamic=False)
        return compiled

    def _lerps(self, pairs: dict[str, tuple[str, float]]) -> list[tuple[float, list, list]]:
        """[(τ, target tensors, online tensors)] of `pairs` = {target: (online, τ)}, one entry per rate."""
        by_rate = defaultdict(lambda: ([], []))
        for target, (online, tau) in pairs.items():
            by_rate[float(tau)][0].extend(self._params((target,)))
            by_rate[float(tau)][1].extend(self._params((online,)))
        return [(tau, t, o) for tau, (t, o) in by_rate.items()]


def _repeated(batch: losses.Batch, r: int) -> losses.Batch:
    """`batch` with an axis of size `r` inserted before its batch axis (a view: (..., B, ...) → (..., r, B,
    ...)), for drawing `r` steps' noise of its shapes at once."""
    at = batch.obs.dim() - 2
    return losses.Batch(*(x.unsqueeze(at).expand(*x.shape[:at], r, *x.shape[at:]) for x in batch))


def _adam_inputs(optimizer: torch.optim.Adam) -> tuple[list, list, list, list, list, dict]:
    """The arguments of torch's functional Adam (`torch.optim.adam.adam`) that `optimizer.step()` would pass
    it (after its first step has created the state): params that have a gradient, their gradients, first and
    second moments and step counts, and the group's hyperparameters."""
    (group,) = optimizer.param_groups
    params = [p for p in group["params"] if p.grad is not None]
    state = [optimizer.state[p] for p in params]
    beta1, beta2 = group["betas"]
    hyper = {"lr": group["lr"], "beta1": beta1, "beta2": beta2, "eps": group["eps"],
             "weight_decay": group["weight_decay"], "amsgrad": group["amsgrad"],
             "maximize": group["maximize"], "capturable": group["capturable"]}
    return (params, [p.grad for p in params], [s["exp_avg"] for s in state],
            [s["exp_avg_sq"] for s in state], [s["step"] for s in state], hyper)


@torch.no_grad()
def _adam_steps(inputs: list[tuple[list, list, list, list, list, dict]]) -> None:
    """One Adam step per `_adam_inputs(optimizer)`, in order: torch's own foreach Adam, in place."""
    for params, grads, exp_avgs, exp_avg_sqs, steps, hyper in inputs:
        functional_adam(params, grads, exp_avgs, exp_avg_sqs, [], steps, foreach=True, **hyper)


@torch.no_grad()
def _move_targets(lerps: list[tuple[float, list, list]]) -> None:
    """Each target ← lerp(target, online, τ): one `torch._foreach_lerp_` per rate (`Algorithm._lerps`)."""
    for tau, targets, online in lerps:
        torch._foreach_lerp_(targets, online, tau)


class TD3(Algorithm):
    """TD3 (Fujimoto et al., 2018) on the representation's critic (Algorithm 2 for SF²)."""

    name = "td3"
    policy_groups = ("policy",)
    critic_noise_key = "smoothing_noise"

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
        return ("smoothing_noise", *self.aux_noise_keys(), *self._more_aux_keys())

    def _algo_noise(self, generator, batch):
        return {"smoothing_noise": self._randn(generator, batch)}

    def critic_loss(self, batch, noise):
        return losses.td3_critic_loss(self.nets, batch, noise[self.critic_noise_key], critic=self.rep.critic)

    def policy_losses(self, batch, noise):
        loss, _ = losses.td3_actor_loss(self.nets, batch, critic=self.rep.critic)
        return {"policy": ("actor_loss", loss, {})}

    def aux_next_action(self, batch, noise):
        """ā′ = π̄(s′) (no smoothing)."""
        return networks.td3_action(self.nets, batch.next_obs, target=True)

    def updates_q_target(self, step):
        return self._actor_step(step)


class SAC(Algorithm):
    """SAC (Haarnoja et al., 2018) with a learned temperature, on the representation's critic
    (Algorithm 3 for SF²)."""

    name = "sac"
    policy_groups = ("policy", "log_alpha")
    critic_noise_key = "next_action_noise"

    @torch.no_grad()
    def explore(self, obs, generator):
        noise = torch.randn(*obs.shape[:-1], self.cfg.action_size, dtype=obs.dtype, device=obs.device,
                            generator=generator)
        return networks.sac_sample(self.nets, obs, noise)[0]

    @torch.no_grad()
    def act(self, obs, generator, deterministic):
        return networks.sac_mode(self.nets, obs) if deterministic else self.explore(obs, generator)

    _aux_action_noise_keys = ("flow_action_noise",)

    def noise_keys(self):
        keys = ("next_action_noise", "actor_noise", "alpha_noise")
        return keys + self.aux_noise_keys() + self._more_aux_keys()

    def _aux_action_noise(self, generator, batch):
        return {"flow_action_noise": self._randn(generator, batch)}

    def _algo_noise(self, generator, batch):
        out = {k: self._randn(generator, batch) for k in ("next_action_noise", "actor_noise", "alpha_noise")}
        if self.rep.aux_groups:
            out.update(self._aux_action_noise(generator, batch))
        return out

    def critic_loss(self, batch, noise):
        return losses.sac_critic_loss(self.nets, batch, noise[self.critic_noise_key], critic=self.rep.critic)

    def policy_losses(self, batch, noise):
        alpha_loss, _ = losses.sac_alpha_loss(self.nets, batch, noise["alpha_noise"])
        actor_loss, actor_aux = losses.sac_actor_loss(self.nets, batch, noise["actor_noise"],
                                                      critic=self.rep.critic)
        return {"log_alpha": ("alpha_loss", alpha_loss, {}), "policy": ("actor_loss", actor_loss, actor_aux)}

    def aux_next_action(self, batch, noise):
        """ā′ ~ π(s′) with the explicit noise `flow_action_noise`."""
        return networks.sac_sample(self.nets, batch.next_obs, noise["flow_action_noise"])[0]

    def updates_q_target(self, step):
        return True


_ALGORITHMS = {"td3": TD3, "sac": SAC}


def make_algorithm(algo: str, cfg: SF2Config, representation_cls: type[Representation], dtype=torch.float32,
                   device="cpu", compile_mode: str | None = None, cudagraphs: bool = False) -> Algorithm:
    return _ALGORITHMS[algo](cfg, representation_cls, dtype, device, compile_mode, cudagraphs)
