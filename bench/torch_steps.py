"""torch updates to time: one full SGD step (critic, flow, actor, targets), eager or `torch.compile`d.

The step timed is `sf2_torch.agents`' `sgd_step` (`AgentsUpdate`) whenever that package imports (it
needs torchrl and tensordict). Without them, the step is composed here from `sf2_torch.losses`
(`ComposedUpdate`), following docs/core-contract.md "One SGD step" exactly as
`sf2_jax.agents.algorithms` does (bench/test_harness.py proves it equal to the JAX agents' step):

1. critic: Adam on (Q, ψ) from `td3_critic_loss` / `sac_critic_loss` (vanilla: on the (s, a) critic);
2. flow (SF²): Adam on (ψ after step 1, ζ) from `flow_loss`; ψ keeps one Adam state across 1 and 2;
   ā′ = target policy at s′ (TD3) or an online-policy sample (SAC);
3. actor: Adam on the policy from Q and ψ as they were *before* step 1 (SAC: temperature first, from
   the pre-step policy). The actor's gradient is computed first, before step 1 changes Q and ψ, and
   applied after step 2: the same update, without copying the pre-step networks;
4. targets: ψ̄, Q̄, π̄ (TD3) ← EMA τ; ζ̄ ← EMA τ_ζ.

Random draws (smoothing ξ, ε, k, SAC ξ) are made inside the step with `torch.randn`/`torch.rand`, as
the JAX step draws them inside its jitted function. The vanilla critic mirrors `sf2_jax.agents`'
`VanillaQ` (two heads MLP(hidden_sizes → 1) with LayerNorm on concat[normalize(s), a]).

Frameworks: `torch` = eager with torch's default (foreach) Adam; `torch-compile` wraps each loss
(forward and, through AOTAutograd, backward) in `torch.compile` (inductor, default mode) and uses the
fused Adam kernel; `torch-cudagraphs` is the same with `mode="reduce-overhead"` (CUDA graphs, CUDA
only). The optimizer and EMA steps run eagerly in all three. Synchronization: `torch.cuda.synchronize()`
on CUDA.
"""

from __future__ import annotations

import copy
import time

from .data import FIELDS, make_batches
from .sizes import Case
from .timing import Runner


def configure(allow_tf32: bool = False, threads: int | None = None) -> None:
    """Full fp32 matmuls for published numbers (DESIGN.md §4)."""
    import torch

    torch.backends.cuda.matmul.allow_tf32 = allow_tf32
    torch.backends.cudnn.allow_tf32 = allow_tf32
    torch.set_float32_matmul_precision("medium" if allow_tf32 else "highest")
    if threads:
        torch.set_num_threads(threads)


def agents_available() -> bool:
    """True when `sf2_torch.agents` (which needs torchrl and tensordict) provides the algorithms; then
    its step is timed instead of the composed one."""
    try:
        from sf2_torch.agents import algorithms
    except Exception:  # noqa: BLE001
        return False
    return hasattr(algorithms, "make_algorithm")


class _VanillaQ:
    """Twin Q(s, a) as `sf2_jax.agents.representations.VanillaQ`."""

    def __new__(cls, cfg, device):
        import torch
        from sf2_torch.networks import MLP

        class VanillaQ(torch.nn.Module):
            def __init__(self):
                super().__init__()
                n_in = cfg.obs_size + cfg.action_size
                self.head_0 = MLP(n_in, cfg.hidden_sizes, 1, cfg.layer_norm, device=device)
                self.head_1 = MLP(n_in, cfg.hidden_sizes, 1, cfg.layer_norm, device=device)

            def forward(self, x):
                return torch.cat([self.head_0(x), self.head_1(x)], dim=-1)

        return VanillaQ()


class ComposedUpdate:
    """One SGD step of `case` on `device`, composed from `sf2_torch.losses` (module docstring)."""

    def __init__(self, case: Case, device: str, compile: bool | str = False, seed: int = 0, dtype=None):
        import torch
        from sf2_torch import losses, networks
        from sf2_torch.config import SF2Config

        self.torch, self.L, self.nw = torch, losses, networks
        self.case, self.device = case, torch.device(device)
        cfg = SF2Config(obs_size=case.obs_size, action_size=case.action_size, **case.sf2_overrides())
        self.cfg = cfg
        torch.manual_seed(seed)
        self.dtype = dtype or torch.float32
        nets = networks.make_networks(cfg, case.algo, device=self.device, dtype=self.dtype)
        self.nets = nets
        self.sf2 = case.rep == "sf2"
        if case.rep not in ("none", "sf2"):
            raise ValueError(f"torch has no representation {case.rep!r} yet")
        adam = dict(lr=cfg.learning_rate, eps=cfg.adam_eps)
        if compile:
            adam["fused"] = True
        if self.sf2:
            critic_params = [*nets.q.parameters(), *nets.psi.parameters(), *nets.zeta.parameters()]
        else:
            self.vq = _VanillaQ(cfg, self.device).to(self.dtype)
            self.target_vq = copy.deepcopy(self.vq).requires_grad_(False)
            critic_params = list(self.vq.parameters())
        self.opt_critic = torch.optim.Adam(critic_params, **adam)
        groups = [{"params": list(nets.policy.parameters())}]
        if case.algo == "sac":
            # Brax SAC's temperature optimizer: optax.adam(alpha_learning_rate), default ε = 1e-8
            groups.append({"params": [nets.log_alpha], "lr": cfg.alpha_learning_rate, "eps": 1e-8})
        self.opt_actor = torch.optim.Adam(groups, **adam)

        raw = make_batches(case.obs_size, case.action_size, case.batch_size, 4, seed)
        self.batches = [losses.Batch(*(torch.as_tensor(b[f], device=self.device, dtype=self.dtype)
                                       for f in FIELDS))
                        for b in raw]
        self.i = 0
        fns = self._loss_fns()
        self.cudagraphs = compile == "reduce-overhead"
        if compile:
            mode = compile if isinstance(compile, str) else None
            fns = {k: torch.compile(v, mode=mode) for k, v in fns.items()}
        self.fns = fns

    # ------------------------------------------------------------------------------------ losses
    def _loss_fns(self) -> dict:
        L, nw, nets, cfg = self.L, self.nw, self.nets, self.cfg
        torch = self.torch
        fns = {}
        if self.sf2:
            if self.case.algo == "td3":
                fns["critic"] = lambda b, xi: L.td3_critic_loss(nets, b, xi)[0]
                fns["actor"] = lambda b: L.td3_actor_loss(nets, b)[0]
            else:
                fns["critic"] = lambda b, xi: L.sac_critic_loss(nets, b, xi)[0]
                fns["actor"] = lambda b, xi: L.sac_actor_loss(nets, b, xi)[0]
                fns["alpha"] = lambda b, xi: L.sac_alpha_loss(nets, b, xi)[0]
            fns["flow"] = lambda b, na, eps, k: L.flow_loss(nets, b, na, eps, k)[0]
            return fns

        vq, tvq = self.vq, self.target_vq

        def q_in(obs, action):
            return torch.cat([nw.normalize(obs, nets.obs_norm), action], dim=-1)

        def td(q, y, trunc):
            err = (1.0 - trunc)[:, None] * (q - y.detach()[:, None])
            return 0.5 * torch.mean(err.square())

        def frozen_q(x):
            return torch.func.functional_call(vq, {n: p.detach() for n, p in vq.named_parameters()}, (x,))

        if self.case.algo == "td3":
            def critic(b, xi):
                with torch.no_grad():
                    noise = torch.clamp(cfg.smoothing_noise * xi, -cfg.noise_clip, cfg.noise_clip)
                    na = torch.clamp(nw.td3_action(nets, b.next_obs, target=True) + noise, -1.0, 1.0)
                    y = cfg.reward_scaling * b.reward + b.discount * cfg.discount * tvq(
                        q_in(b.next_obs, na)).min(-1).values
                return td(vq(q_in(b.obs, b.action)), y, b.truncation)

            def actor(b):
                return -torch.mean(frozen_q(q_in(b.obs, nw.td3_action(nets, b.obs)))[:, 0])
        else:
            def critic(b, xi):
                with torch.no_grad():
                    alpha = torch.exp(nets.log_alpha)
                    na, logp = nw.sac_sample(nets, b.next_obs, xi)
                    soft = tvq(q_in(b.next_obs, na)).min(-1).values - alpha * logp
                    y = cfg.reward_scaling * b.reward + b.discount * cfg.discount * soft
                return td(vq(q_in(b.obs, b.action)), y, b.truncation)

            def actor(b, xi):
                alpha = torch.exp(nets.log_alpha.detach())
                a, logp = nw.sac_sample(nets, b.obs, xi)
                return torch.mean(alpha * logp - frozen_q(q_in(b.obs, a)).min(-1).values)

            fns["alpha"] = lambda b, xi: L.sac_alpha_loss(nets, b, xi)[0]
        fns["critic"], fns["actor"] = critic, actor
        return fns

    # ------------------------------------------------------------------------------------ the step
    def draw(self, name: str, shape: tuple[int, ...], like) -> torch.Tensor:  # noqa: F821
        """The step's random inputs: `flow_time` ~ U(0, 1), everything else ~ N(0, 1). A test replaces
        this method to feed the same noise as the JAX step."""
        if name == "flow_time":
            return self.torch.rand(shape, device=like.device, dtype=like.dtype)
        return self.torch.randn(shape, device=like.device, dtype=like.dtype)

    def step(self) -> None:
        torch, nets, cfg, fns = self.torch, self.nets, self.cfg, self.fns
        b = self.batches[self.i % len(self.batches)]
        self.i += 1
        B, A, D = b.obs.shape[0], cfg.action_size, cfg.obs_size
        o = b.obs
        sac = self.case.algo == "sac"
        if self.cudagraphs:
            torch.compiler.cudagraph_mark_step_begin()
        # 3 (gradient only): actor (and temperature) from the pre-step Q, ψ and policy
        self.opt_actor.zero_grad(set_to_none=True)
        if sac:
            fns["alpha"](b, self.draw("alpha", (B, A), o)).backward()
            fns["actor"](b, self.draw("actor", (B, A), o)).backward()
        else:
            fns["actor"](b).backward()
        # 2's next action ā′ from the pre-step policy (unchanged until the actor step is applied)
        if self.sf2:
            with torch.no_grad():
                if sac:
                    next_action = self.nw.sac_sample(nets, b.next_obs, self.draw("next", (B, A), o))[0]
                else:
                    next_action = self.nw.td3_action(nets, b.next_obs, target=True)
        # 1 critic
        self.opt_critic.zero_grad(set_to_none=True)
        fns["critic"](b, self.draw("critic", (B, A), o)).backward()
        self.opt_critic.step()
        # 2 flow
        if self.sf2:
            self.opt_critic.zero_grad(set_to_none=True)
            eps = self.draw("eps", (B, D), o)
            k = self.draw("flow_time", (B,), o)
            fns["flow"](b, next_action, eps, k).backward()
            self.opt_critic.step()
        # 3 apply the actor step
        self.opt_actor.step()
        # 4 targets
        L = self.L
        if self.sf2:
            L.ema_update(nets.target_psi, nets.psi, cfg.tau)
            L.ema_update(nets.target_zeta, nets.zeta, cfg.tau_zeta)
            L.ema_update(nets.target_q, nets.q, cfg.tau)
        else:
            L.ema_update(self.target_vq, self.vq, cfg.tau)
        if not sac:
            L.ema_update(nets.target_policy, nets.policy, cfg.tau)

    def sync(self) -> None:
        if self.device.type == "cuda":
            self.torch.cuda.synchronize(self.device)

    def finite(self) -> bool:
        mods = [self.nets] + ([] if self.sf2 else [self.vq])
        return all(bool(self.torch.isfinite(p).all()) for m in mods for p in m.parameters())


class AgentsUpdate:
    """One SGD step of `sf2_torch.agents` (`Algorithm.sgd_step(td, actor_step=True)`, cross-tested
    against the JAX agents in tests/test_step_agents_cross.py). Its noise is drawn inside every step
    with `Algorithm.draw_noise` (the thin wrapper the trainer uses), as the JAX step draws inside its
    jitted function. `torch-compile`: `compile_mode="default"` (the whole step under torch.compile);
    `torch-cudagraphs`: the same plus tensordict's `CudaGraphModule` (the trainer's default on CUDA)."""

    def __init__(self, case: Case, device: str, seed: int = 0, dtype=None):
        import torch
        from sf2_torch.agents import algorithms, representations
        from sf2_torch.config import SF2Config
        from tensordict import TensorDict

        self.torch = torch
        self.device = torch.device(device)
        dtype = dtype or torch.float32
        cfg = SF2Config(obs_size=case.obs_size, action_size=case.action_size, **case.sf2_overrides())
        compile_mode = "default" if case.framework in ("torch-compile", "torch-cudagraphs") else None
        cudagraphs = case.framework == "torch-cudagraphs"
        torch.manual_seed(seed)
        if case.rep not in representations.names():
            import importlib

            importlib.import_module("sf2_baselines.torch")   # registers Sim, SimLap, SPR
        self.alg = algorithms.make_algorithm(case.algo, cfg, representations.get(case.rep), dtype=dtype,
                                             device=self.device, compile_mode=compile_mode,
                                             cudagraphs=cudagraphs)
        self.generator = torch.Generator(self.device)
        self.generator.manual_seed(seed + 1)
        self.batches = []
        for b in make_batches(case.obs_size, case.action_size, case.batch_size, 4, seed):
            def t(x):
                return torch.as_tensor(x, dtype=dtype, device=self.device)

            done = torch.as_tensor(b["discount"] == 0, device=self.device).unsqueeze(-1)
            trunc = torch.as_tensor(b["truncation"] > 0.5, device=self.device).unsqueeze(-1)
            self.batches.append(TensorDict({
                "observation": t(b["obs"]), "action": t(b["action"]),
                "next": {"observation": t(b["next_obs"]), "reward": t(b["reward"]).unsqueeze(-1),
                         "done": done, "terminated": done & ~trunc, "truncated": trunc},
            }, [case.batch_size], device=self.device))
        self.B = case.batch_size
        self.i = 0

    def step(self) -> None:
        td = self.batches[self.i % len(self.batches)].clone(False)
        self.i += 1
        td.update(self.alg.draw_noise((self.B,), self.generator))
        self.alg.sgd_step(td, actor_step=True)

    def sync(self) -> None:
        if self.device.type == "cuda":
            self.torch.cuda.synchronize(self.device)

    def finite(self) -> bool:
        return all(bool(self.torch.isfinite(p).all()) for p in self.alg.modules().parameters())


def update_runner(case: Case, device: str, seed: int = 0, warm_compile: int = 3,
                  impl: str = "auto") -> tuple[Runner, dict]:
    """A Runner over one torch SGD step: `sf2_torch.agents`' step when importable (`impl="auto"` or
    "agents"), else the step composed here from `sf2_torch.losses` ("composed"). For compiled
    frameworks `warm_compile` steps run here and their time is reported as the compile time."""
    use_agents = impl == "agents" or (impl == "auto" and agents_available())
    compiled = {"torch-compile": True, "torch-cudagraphs": "reduce-overhead"}.get(case.framework, False)
    if case.framework == "torch-cudagraphs" and not str(device).startswith("cuda"):
        raise RuntimeError("torch-cudagraphs needs a CUDA device")
    if use_agents:
        upd = AgentsUpdate(case, device, seed=seed)
        label = "sf2_torch.agents sgd_step"
    else:
        upd = ComposedUpdate(case, device, compile=compiled, seed=seed)
        label = "composed from sf2_torch.losses (bench/torch_steps.py)"
    t0 = time.perf_counter()
    for _ in range(warm_compile if compiled else 1):
        upd.step()
    upd.sync()
    compile_s = time.perf_counter() - t0
    runner = Runner(case.key, upd.step, upd.sync, compile_s=compile_s)
    return runner, {"finite": upd.finite, "impl": label}


def count_flops(case: Case, device: str = "cpu", seed: int = 0) -> float:
    """FLOPs of one eager update from torch's FlopCounterMode (matmuls only: a documented lower count),
    counted on the composed step: the same arithmetic as the agents' step (both are cross-tested against
    the JAX agents), and FlopCounterMode's module hooks cannot walk TorchRL's tensordict modules."""
    from torch.utils.flop_counter import FlopCounterMode

    eager = case.__class__(**{**case.__dict__, "framework": "torch"})
    upd = ComposedUpdate(eager, device, seed=seed)
    upd.step()
    with FlopCounterMode(display=False) as counter:
        upd.step()
    return float(counter.get_total_flops())
