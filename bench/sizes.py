"""What is timed: the seven tasks' observation/action sizes, the network size presets, the case grid.

Task sizes are MuJoCo Playground's DM Control suite (state observations, `impl='jax'`), read from
`registry.load(task).observation_size / action_size` with playground 0.2.0; they are fixed here so the
bench needs no environment package.
"""

from __future__ import annotations

import dataclasses
import itertools

# The paper's seven tasks (sf2_common.agents.tasks): (obs_size D, action_size A).
TASKS: dict[str, tuple[int, int]] = {
    "AcrobotSwingup": (6, 1),
    "CartpoleBalanceSparse": (5, 1),
    "CartpoleSwingupSparse": (5, 1),
    "CheetahRun": (17, 6),
    "FishSwim": (24, 5),
    "HopperHop": (15, 4),
    "PendulumSwingup": (3, 1),
}
# Short names accepted on the command line.
ALIASES = {
    "acrobot": "AcrobotSwingup", "cartpole": "CartpoleBalanceSparse",
    "cartpole-swingup": "CartpoleSwingupSparse", "cheetah": "CheetahRun", "fish": "FishSwim",
    "hopper": "HopperHop", "pendulum": "PendulumSwingup",
}

# Network/batch presets. `paper`: Table 1 (B = F = 512, every hidden width 512, embedding 64).
# `small`: the cores' test size (SF2Config.small) with B = 256, for CPUs and the pytest-benchmark suite.
# `medium`: in between, for CPU tables where the ζ algebra is visible above the Python overhead.
# `quick`: the agents' `quick` preset (sf2_common.agents.configs), the size of the CPU training runs.
SIZES: dict[str, dict] = {
    "small": dict(batch_size=256, feature_size=16, hidden_sizes=(32, 32), q_hidden_size=32,
                  zeta_hidden_sizes=(32, 32), embedding_size=8),
    "quick": dict(batch_size=128, feature_size=32, hidden_sizes=(64, 64), q_hidden_size=64,
                  zeta_hidden_sizes=(64, 64), embedding_size=16),
    "medium": dict(batch_size=256, feature_size=128, hidden_sizes=(128, 128, 128), q_hidden_size=128,
                   zeta_hidden_sizes=(128, 128), embedding_size=16),
    "paper": dict(batch_size=512, feature_size=512, hidden_sizes=(512, 512, 512), q_hidden_size=512,
                  zeta_hidden_sizes=(512, 512), embedding_size=64),
}

FRAMEWORKS = ("jax", "jax-scan", "torch", "torch-graphs", "torch-compile", "torch-cudagraphs")
JAX = ("jax", "jax-scan")
COMPILED = ("torch-compile", "torch-cudagraphs")
CUDA_ONLY = ("torch-graphs", "torch-cudagraphs")   # CUDA graphs
ALGOS = ("td3", "sac")
INTEGRATORS = ("midpoint", "euler")
DEFAULT_STEPS = (1, 2, 4, 8)
# Representations registered by a bench module rather than by the cores (JAX only, midpoint; timed at
# `variant_steps` for `variant_algos`). Empty here: a module that registers one adds its name.
VARIANT_REPS: set[str] = set()


def resolve_task(name: str) -> str:
    """Resolve a task name or alias.

    Args:
        name: a task of `TASKS` (any case) or an alias of `ALIASES` ("cheetah").

    Returns:
        The task's full name; a ValueError names the valid ones.
    """
    if name in TASKS:
        return name
    key = name.lower()
    if key in ALIASES:
        return ALIASES[key]
    for task in TASKS:
        if task.lower() == key:
            return task
    raise ValueError(f"unknown task {name!r}: valid are {', '.join(TASKS)} or {', '.join(ALIASES)}")


def unique_sizes(tasks) -> list[str]:
    """Keep one task per distinct (D, A).

    Args:
        tasks: task names.

    Returns:
        The tasks whose sizes differ, the first name of each kept (the two Cartpoles share theirs).
    """
    seen, out = set(), []
    for t in tasks:
        if TASKS[t] not in seen:
            seen.add(TASKS[t])
            out.append(t)
    return out


@dataclasses.dataclass(frozen=True)
class Case:
    """One timed update: framework, algorithm, representation (`none` = vanilla, `sf2`, baselines),
    denoising steps T and integrator (SF² only), task sizes, size preset."""

    framework: str
    algo: str
    rep: str
    task: str
    size: str
    steps: int = 0          # T; 0 for representations without an ODE
    integrator: str = ""    # "" for representations without an ODE

    @property
    def obs_size(self) -> int:
        return TASKS[self.task][0]

    @property
    def action_size(self) -> int:
        return TASKS[self.task][1]

    @property
    def batch_size(self) -> int:
        return SIZES[self.size]["batch_size"]

    @property
    def has_ode(self) -> bool:
        """Whether the case has denoising steps and an integrator (SF² and its variants `sf2-*`)."""
        return self.rep == "sf2" or self.rep.startswith("sf2-")

    @property
    def key(self) -> str:
        tail = f"/T{self.steps}/{self.integrator}" if self.has_ode else ""
        return f"{self.framework}/{self.algo}/{self.rep}{tail}/{self.task}/{self.size}"

    def sf2_overrides(self) -> dict:
        """The `SF2Config` keyword arguments of this case: sizes, and T and integrator for SF²."""
        kw = {k: v for k, v in SIZES[self.size].items() if k != "batch_size"}
        if self.has_ode:
            kw.update(denoising_steps=self.steps, integrator=self.integrator)
        return kw


def grid(frameworks, algos, reps, tasks, size, steps=DEFAULT_STEPS, integrators=INTEGRATORS,
         compiled_steps=None, variant_steps=None, compiled_algos=None, variant_algos=None,
         compiled_integrators=None) -> list[Case]:
    """List every case of the product of the arguments, task-major.

    Args:
        frameworks, algos, reps, tasks: the product's axes (`FRAMEWORKS`, `ALGOS`, representations, tasks).
        size: network/batch preset.
        steps: denoising steps T of the SF² cases.
        integrators: integrators of the SF² cases.
        compiled_steps: T of the compiled torch cases (compiling is slow); None: every T.
        variant_steps: T of the `VARIANT_REPS` cases (JAX only, midpoint); None: every T.
        compiled_algos, variant_algos: algorithms of those cases; None: all.
        compiled_integrators: integrators of the compiled torch cases; None: all.

    Returns:
        The cases, task-major, so a run cut short by its budget keeps whole tasks.
    """
    cases = []
    for task, fw, algo, rep in itertools.product(tasks, frameworks, algos, reps):
        bench_only = rep in VARIANT_REPS
        if bench_only and (fw not in JAX or (variant_algos and algo not in variant_algos)):
            continue
        if fw in COMPILED and compiled_algos and algo not in compiled_algos:
            continue
        probe = Case(fw, algo, rep, task, size)
        if probe.has_ode:
            for integ, T in itertools.product(integrators, steps):
                if bench_only and (integ != "midpoint" or (variant_steps and T not in variant_steps)):
                    continue
                if fw in COMPILED and compiled_steps is not None and T not in compiled_steps:
                    continue
                if fw in COMPILED and compiled_integrators and integ not in compiled_integrators:
                    continue
                cases.append(Case(fw, algo, rep, task, size, T, integ))
        else:
            cases.append(Case(fw, algo, rep, task, size))
    return cases
