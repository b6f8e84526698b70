"""The task table: which tasks exist, of which kind (MuJoCo Playground's DM Control suite, locomotion and
manipulation; MinAtar, docs/minatar.md; a user's own environment) and what the trainers need to know of
each (observation and action kinds, the trainer that takes it, the episode limit, the paper's per-task
settings: Appendix E Table 1; docs/core-contract.md "Agents"; docs/agents.md "Tasks").

Data-driven: `KINDS` describes each kind, `TASKS` lists the tasks known without an import (MinAtar's);
Playground's names are imported lazily. A user's environment is `module:callable` or a name of the entry
point group `sf2.tasks`; `env_sizes` checks any environment's observations and actions before anything is
compiled, and `training_env` builds the batched, time-limited, auto-resetting env both cores step (JAX:
Brax wrappers; torch: a TorchRL env over it). MinAtar's envs are `sf2_jax.agents.minatar`. Neither
Playground nor pgx is imported to validate a MinAtar task.
"""

from __future__ import annotations

import contextlib
import difflib
import functools
import importlib
import importlib.util
import json
import os
import pathlib
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass, replace
from importlib import metadata

from sf2_common.errors import ConfigError
from sf2_common.fileio import atomic_write

__all__ = [
    "PAPER_TASKS", "PAPER_BUDGETS", "PAPER_ACTION_REPEAT", "valid_tasks", "validate_task",
    "paper_budget", "paper_action_repeat", "TaskKind", "Task", "KINDS", "TASKS", "MINATAR_TASKS",
    "playground_tasks", "task_kind", "check_algo", "check_installed", "episode_length", "GROUP", "OBS_KEY",
    "task_entry_points", "env_factory", "EnvSizes", "env_sizes", "load_env", "check_env", "training_env",
    "ObsKey",
]


@dataclass(frozen=True)
class TaskKind:
    """One family of tasks and what a trainer needs to know of it.

    Attributes:
      name: the kind's key in `KINDS`.
      label: its name in messages and in `tasks` listings.
      observation: "vector" (flat state) or "image" (an H×W×C grid).
      action: "continuous" (a box) or "discrete" (an action index).
      trainer: the trainer family that takes it, "off-policy", "on-policy" or "goal-conditioned".
      algos: the `--algo` values of that trainer; any other known algo is refused (`check_algo`).
      episode_length: the episode limit in agent steps; reaching it is a truncation, not a termination.
      requires: the module its environments import, checked by `check_installed`; None where the task
        list itself imports it.
      install: the command that installs what it needs.
      budget: env steps of the `paper` preset for every task of the kind; None: per task (`paper_budget`).
      suite: the module of `mujoco_playground.registry` that lists its tasks; None for other kinds.
    """

    name: str
    label: str
    observation: str
    action: str
    trainer: str
    algos: tuple[str, ...]
    episode_length: int
    requires: str | None
    install: str
    budget: int | None = None
    suite: str | None = None


@dataclass(frozen=True)
class Task:
    """A task known without importing its environment package: its kind and sizes.

    Attributes:
      kind: a key of `KINDS`.
      obs_shape: the observation's shape.
      num_actions: the number of discrete actions (0 for continuous actions).
    """

    kind: str
    obs_shape: tuple[int, ...]
    num_actions: int


_TRAIN = 'pip install "packages/sf2-core-jax[train]"'
# The paper's longest DM Control budget: the `paper` preset's for off-policy tasks without a reference budget
OFF_POLICY_BUDGET = 10_000_000


def _off_policy(name: str, label: str, suite: str | None) -> TaskKind:
    return TaskKind(name, label, observation="vector", action="continuous", trainer="off-policy",
                    algos=("td3", "sac"), episode_length=1000, requires=None, install=_TRAIN,
                    budget=None if suite == "dm_control_suite" else OFF_POLICY_BUDGET, suite=suite)


# ALGOS (sf2_common.agents.configs) holds the algos that exist; each is one trainer's.
ALGO_TRAINER = {"td3": "off-policy", "sac": "off-policy", "ppo": "on-policy", "fpo": "on-policy",
                "crl": "goal-conditioned"}
KINDS = {
    # DM Control tasks also take FPO (`--algo fpo`), the on-policy trainer's (docs/fpo.md)
    "playground": replace(_off_policy("playground", "Playground DM Control", "dm_control_suite"),
                          algos=("td3", "sac", "fpo")),
    "locomotion": _off_policy("locomotion", "Playground locomotion", "locomotion"),
    "manipulation": _off_policy("manipulation", "Playground manipulation", "manipulation"),
    "user": _off_policy("user", "user environment", None),
    "minatar": TaskKind(
        "minatar", "MinAtar", observation="image", action="discrete", trainer="on-policy", algos=("ppo",),
        episode_length=10_000, requires="pgx", install='pip install "packages/sf2-core-jax[minatar]"',
        budget=20_000_000),
    # JaxGCRL's goal-reaching Ant (sf2_jax.agents.antgoal, docs/crl.md): CRL's goal-conditioned trainer
    "goal": TaskKind(
        "goal", "goal-reaching", observation="vector", action="continuous", trainer="goal-conditioned",
        algos=("crl",), episode_length=1000, requires="brax", install=_TRAIN, budget=10_000_000),
}
# pgx's MinAtar games with its defaults (minimal action sets, sticky actions 0.1): bool 10×10×C grids
MINATAR_TASKS = {
    "minatar-asterix": Task("minatar", (10, 10, 4), 5),
    "minatar-breakout": Task("minatar", (10, 10, 4), 3),
    "minatar-freeway": Task("minatar", (10, 10, 7), 3),
    "minatar-seaquest": Task("minatar", (10, 10, 10), 6),
    "minatar-space_invaders": Task("minatar", (10, 10, 6), 4),
}
# The tasks known without an import; every other valid task is Playground's (`valid_tasks`).
TASKS = {**MINATAR_TASKS, "ant-goal": Task("goal", (31,), 0)}

# The seven tasks of the paper's DM Control experiments (§4.2, Appendix E Table 1).
PAPER_TASKS = (
    "AcrobotSwingup", "CartpoleBalanceSparse", "CartpoleSwingupSparse", "CheetahRun", "FishSwim",
    "HopperHop", "PendulumSwingup",
)
# Table 1 "Number of Timesteps" (env steps, counted after action repeat as Brax does).
PAPER_BUDGETS = {
    "CartpoleBalanceSparse": 5_000_000, "CartpoleSwingupSparse": 5_000_000, "FishSwim": 5_000_000,
    "AcrobotSwingup": 10_000_000, "HopperHop": 10_000_000, "CheetahRun": 10_000_000,
    "PendulumSwingup": 10_000_000,
}
# Table 1 "Action Repeat: 1 (4 for PendulumSwingUp)". The authors' runs took action repeat from
# Playground's SAC config, which spells the task "PendulumSwingUp", so their PendulumSwingup runs used
# action repeat 1 and 5M steps; the `paper` preset follows the table (docs/core-contract.md, "The
# authors' code").
PAPER_ACTION_REPEAT = {"PendulumSwingup": 4}


GROUP = "sf2.tasks"   # the entry-point group of users' environments: name = "module:callable"
OBS_KEY = "state"     # the key of a dict observation the agents read (Playground PPO's policy obs_key)
_USER = (f"or your own environment: module:callable, or a name of the entry-point group {GROUP!r} "
         f"(docs/agents.md)")


def _registry_stamp() -> str | None:
    """Playground's version, folder and its suites' modification times, and `KINDS`'s suites, read without
    importing Playground.

    Returns:
      A string that changes when the task lists or the kinds they map to can have changed; None where
      Playground is not installed or a suite's module is not where this version keeps it.
    """
    spec = importlib.util.find_spec("mujoco_playground")
    if spec is None or not spec.submodule_search_locations:
        return None
    root = pathlib.Path(next(iter(spec.submodule_search_locations)))
    try:
        times = [(root / "_src" / k.suite / "__init__.py").stat().st_mtime_ns
                 for k in KINDS.values() if k.suite]
        version = metadata.version("playground")
    except (OSError, metadata.PackageNotFoundError):
        return None
    kinds = ",".join(f"{k.name}={k.suite}" for k in KINDS.values() if k.suite)
    return f"{version} {root} {max(times)} {kinds}"


def _registry_cache() -> pathlib.Path:
    """The file that keeps Playground's task names between processes ($XDG_CACHE_HOME or ~/.cache)."""
    return pathlib.Path(os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache") / "sf2" / \
        "playground-tasks.json"


@functools.lru_cache(maxsize=1)
def playground_tasks() -> dict[str, str]:
    """{name: kind} of every task in Playground's registries, e.g. 'CartpoleBalance': 'playground'.

    Importing Playground to read its registries takes seconds (its torch wrapper included), so the names
    are kept in `_registry_cache()` under `_registry_stamp()` and read from there while the stamp holds.

    Returns:
      Every registered task's name and its key in `KINDS`.

    Raises:
      ImportError: Playground is not installed.
    """
    stamp, cache = _registry_stamp(), _registry_cache()
    if stamp is not None:
        try:
            kept = json.loads(cache.read_text())
            listed = dict(kept["tasks"])
            if kept["stamp"] == stamp and set(listed.values()) <= set(KINDS):
                return listed
        except (OSError, ValueError, KeyError, TypeError):
            pass
    from mujoco_playground import registry

    found = {name: k.name for k in KINDS.values() if k.suite for name in getattr(registry, k.suite).ALL_ENVS}
    if stamp is not None:
        with contextlib.suppress(OSError):   # an unwritable cache folder: the names are read again next time
            atomic_write(cache, json.dumps({"stamp": stamp, "tasks": found}))
    return found


@functools.lru_cache(maxsize=1)
def task_entry_points() -> dict[str, metadata.EntryPoint]:
    """{name: entry point} of the group `GROUP` in the installed distributions (read once per process)."""
    found: dict[str, metadata.EntryPoint] = {}
    for ep in metadata.entry_points(group=GROUP):
        found.setdefault(ep.name, ep)
    return found


def valid_tasks() -> tuple[str, ...]:
    """Every task name: Playground's (imported), `TASKS` (MinAtar's), then the entry points of `GROUP`."""
    named = tuple(playground_tasks()) + tuple(TASKS)
    return named + tuple(sorted(set(task_entry_points()) - set(named)))


def _user_task(task: str) -> bool:
    """Whether `task` (not one of `TASKS`) names a user's environment: an import path, or an entry point
    whose name is not Playground's (Playground's names come first, where it is installed)."""
    if ":" in task or task not in task_entry_points():
        return ":" in task
    try:
        return task not in playground_tasks()
    except ImportError:
        return True


def validate_task(task: str) -> str:
    """Return `task` if it is valid, else raise `ConfigError` listing the valid names by kind.

    Args:
      task: a task name; one of `TASKS` is valid without importing Playground; `module:callable` or an
        entry point of `GROUP` is valid when its callable imports (it is not called: `check_env`).

    Returns:
      `task`.

    Raises:
      ConfigError: an unknown name, or a user's environment that cannot be imported.
    """
    if task in TASKS:
        return task
    if isinstance(task, str) and _user_task(task):
        env_factory(task)
        return task
    tasks = tuple(dict.fromkeys(valid_tasks() + tuple(TASKS)))
    if task in tasks:
        return task
    close = difflib.get_close_matches(str(task), tasks, n=3)
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    by_kind = {k.label: [t for t in tasks if task_kind(t) is k] for k in KINDS.values()}
    listing = "; ".join(f"{label}: {', '.join(names)}" for label, names in by_kind.items() if names)
    raise ConfigError(f"unknown task {task!r}.{hint} Valid tasks ({listing}); {_USER}")


def task_kind(task: str) -> TaskKind:
    """The `TaskKind` of a valid task name: its `TASKS` row's, a user's environment's, else Playground's."""
    if task in TASKS:
        return KINDS[TASKS[task].kind]
    if _user_task(task):
        return KINDS["user"]
    return KINDS[playground_tasks().get(task, "playground")]


def check_algo(task: str, algo: str) -> None:
    """Refuse a task that `algo`'s trainer does not take, before anything is compiled.

    The hook between tasks and trainers: every trainer's config validation calls it. An algo that no
    kind lists is left to the trainer's own check of its algos.

    Args:
      task: a valid task name.
      algo: the `--algo` value.

    Raises:
      ConfigError: the algo trains another kind of task; the message names the algos that take `task`.
    """
    kind = task_kind(task)
    takers = [k for k in KINDS.values() if algo in k.algos]
    if algo in kind.algos or not takers:
        return
    by_trainer = {}                                     # the kind's algos grouped by their trainer
    for a in kind.algos:
        by_trainer.setdefault(ALGO_TRAINER.get(a, kind.trainer), []).append(f"--algo {a}")
    take = " or ".join(f"the {t} trainer ({' or '.join(names)})" for t, names in by_trainer.items())
    labels = [k.label for k in takers]
    other = f"{', '.join(labels[:-1])} and {labels[-1]}" if len(labels) > 1 else labels[0]
    other += f" tasks' {ALGO_TRAINER.get(algo, takers[0].trainer)} trainer"
    raise ConfigError(f"task {task!r} is a {kind.label} task: {kind.label} tasks take {take}; "
                      f"--algo {algo} is the {other}")


def check_installed(task: str) -> None:
    """Refuse a task whose environment package is not installed (found without importing it).

    Args:
      task: a valid task name.

    Raises:
      ConfigError: its kind's `requires` module is missing; the message says how to install it.
    """
    kind = task_kind(task)
    if kind.requires is None:
        return
    try:
        found = importlib.util.find_spec(kind.requires) is not None
    except (ImportError, ValueError):   # a module set to None in sys.modules, or one without a spec
        found = False
    if not found:
        raise ConfigError(f"task {task!r} is a {kind.label} task and needs {kind.requires!r}, which is not "
                          f"installed: {kind.install}")


def paper_budget(task: str) -> int:
    """Env steps for `task`: Table 1 for the paper's tasks; its kind's `budget` where it has one (MinAtar:
    docs/minatar.md; locomotion, manipulation and users' environments: `OFF_POLICY_BUDGET`); for the other
    DM Control tasks, Playground's own SAC budget (`dm_control_suite_params.brax_sac_config`), which is
    what the authors' sweep script would use."""
    if task in PAPER_BUDGETS:
        return PAPER_BUDGETS[task]
    if task_kind(task).budget is not None:
        return task_kind(task).budget
    from mujoco_playground.config import dm_control_suite_params

    return int(dm_control_suite_params.brax_sac_config(task).num_timesteps)


def paper_action_repeat(task: str) -> int:
    """Action repeat of `task`: Table 1's; a locomotion or manipulation task's Playground env config's
    (`registry.get_default_config`); 1 otherwise (every DM Control task's config holds 1)."""
    if task in PAPER_ACTION_REPEAT:
        return PAPER_ACTION_REPEAT[task]
    return int(_playground_config(task).action_repeat) if _config_kind(task) else 1


def episode_length(task: str) -> int:
    """The episode limit of `task` in env steps: a locomotion or manipulation task's Playground env
    config's; its kind's `episode_length` otherwise (DM Control: 1000, every task's config)."""
    if _config_kind(task):
        return int(_playground_config(task).episode_length)
    return task_kind(task).episode_length


def _config_kind(task: str) -> bool:
    return task_kind(task).name in ("locomotion", "manipulation")


@functools.lru_cache(maxsize=64)
def _playground_config(task: str):
    """Playground's default env config of `task` (read without building the env or its assets)."""
    from mujoco_playground import registry

    return registry.get_default_config(task)


# ------------------------------------------------------------------------------------------- environments
_INTERFACE = ("an environment has reset(rng) -> state and step(state, action) -> state, the state holding "
              "obs, reward, done and info, and the ints observation_size and action_size (docs/agents.md)")
_SUPPORTED = (f"the off-policy trainers take flat state vectors (observation_size an int, or a dict holding "
              f"one under {OBS_KEY!r}) and continuous actions in [-1, 1] (action_size an int); image "
              f"observations and discrete actions are MinAtar's, with --algo ppo")


@functools.lru_cache(maxsize=32)
def env_factory(task: str):
    """The callable that builds `task`'s environment, imported, not called.

    Args:
      task: a valid task: Playground's name, `module:callable`, or an entry point of `GROUP`.

    Returns:
      A callable of no arguments returning the environment (Playground's: `registry.load` with the
      pure-JAX MJX backend, `impl='jax'`).

    Raises:
      ConfigError: a malformed import path, a module that cannot be imported, a missing or not callable
        attribute, an entry point that cannot be loaded.
    """
    if not _user_task(task):
        from mujoco_playground import registry

        return functools.partial(registry.load, task, config_overrides={"impl": "jax"})
    if ":" not in task:
        ep = task_entry_points()[task]
        try:
            factory = ep.load()
        except (ImportError, AttributeError) as err:
            raise ConfigError(f"task {task!r} (entry point {ep.value} of {GROUP!r}) could not be imported: "
                              f"{err}") from err
    else:
        module, _, name = task.partition(":")
        if not module or not name or ":" in name:
            raise ConfigError(f"task {task!r} is not an import path: expected 'module:callable', e.g. "
                              f"mypkg.envs:make_env; {_USER}")
        try:
            factory = functools.reduce(getattr, name.split("."), importlib.import_module(module))
        except ImportError as err:
            raise ConfigError(f"task {task!r}: module {module!r} cannot be imported ({err}); an import-path "
                              f"task is 'module:callable' with the module on the Python path") from err
        except AttributeError:
            raise ConfigError(f"task {task!r}: module {module!r} has no attribute {name!r}") from None
    if not callable(factory):
        raise ConfigError(f"task {task!r}: {factory!r} is not callable; it must be a callable of no "
                          f"arguments returning the environment")
    return factory


@dataclass(frozen=True)
class EnvSizes:
    """What the agents see of an environment.

    Attributes:
      obs_size: the length of the observation vector.
      action_size: the number of action dimensions.
      obs_key: the key of a dict observation the agents read (`OBS_KEY`), or None for a flat one.
    """

    obs_size: int
    action_size: int
    obs_key: str | None


def env_sizes(task: str, env) -> EnvSizes:
    """Check that `env` is one the off-policy trainers can drive, before anything is compiled.

    Args:
      task: its task name (for messages).
      env: the environment (`env_factory(task)()`).

    Returns:
      Its `EnvSizes`: a flat observation, or a dict observation's `OBS_KEY` entry.

    Raises:
      ConfigError: not an environment, image or other structured observations, discrete actions.
    """
    missing = [a for a in ("reset", "step", "observation_size", "action_size") if not hasattr(env, a)]
    if isinstance(getattr(env, "num_actions", None), int):
        raise ConfigError(f"task {task!r} has discrete actions (num_actions = {env.num_actions}); "
                          f"{_SUPPORTED}")
    if missing:
        raise ConfigError(f"task {task!r}: its callable returned {type(env).__name__}, which is not an "
                          f"environment: it lacks {', '.join(missing)}; {_INTERFACE}")
    obs, key = env.observation_size, None
    if isinstance(obs, Mapping) and OBS_KEY in obs:
        obs, key = obs[OBS_KEY], OBS_KEY
    shapes = list(obs.values()) if isinstance(obs, Mapping) else [obs]
    if any(isinstance(s, (tuple, list)) and len(s) > 1 for s in shapes):
        raise ConfigError(f"task {task!r} has image observations {env.observation_size}; {_SUPPORTED}")
    if isinstance(obs, (tuple, list)) and len(obs) == 1:
        obs = obs[0]
    if isinstance(obs, Mapping) or not _positive_int(obs):
        raise ConfigError(f"task {task!r} has observations {env.observation_size}, which the agents cannot "
                          f"read; {_SUPPORTED}")
    if not _positive_int(env.action_size):
        raise ConfigError(f"task {task!r} has action_size {env.action_size!r}; {_SUPPORTED}")
    return EnvSizes(int(obs), int(env.action_size), key)


def _positive_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 1


@functools.lru_cache(maxsize=16)
def load_env(task: str):
    """`task`'s environment, built once per process, and its checked `EnvSizes`.

    Args:
      task: a valid task of an off-policy kind.

    Returns:
      (env, `env_sizes(task, env)`).

    Raises:
      ConfigError: as `env_factory` and `env_sizes`; a callable that needs arguments; a locomotion or
        manipulation task whose models (MuJoCo Menagerie) could not be fetched.
    """
    factory = env_factory(task)
    try:
        env = factory()
    except TypeError as err:
        raise ConfigError(f"task {task!r}: calling {factory!r} with no arguments failed: {err}") from err
    except (OSError, subprocess.SubprocessError) as err:
        if not _config_kind(task):
            raise
        raise ConfigError(f"task {task!r}: Playground could not build it ({err}); its locomotion and "
                          f"manipulation tasks need MuJoCo Menagerie's models, which Playground clones from "
                          f"GitHub on first use into mujoco_playground/external_deps/: run it once where "
                          f"GitHub can be reached") from err
    return env, env_sizes(task, env)


def check_env(task: str) -> None:
    """Build and check a user's environment (`load_env`); Playground's are checked when built.

    Args:
      task: a valid task.

    Raises:
      ConfigError: as `load_env`.
    """
    if task not in TASKS and _user_task(task):
        load_env(task)


def training_env(task: str, episode_length: int, action_repeat: int):
    """`task`'s environment as both cores' trainers step it: batched, cut after `episode_length` env steps
    with `info['truncation']` set, each action repeated `action_repeat` times, reset to its first state
    when done (Playground's `wrap_for_brax_training`; Brax's `training.wrap` for a Brax env), and a dict
    observation's `OBS_KEY` entry as its observation (`ObsKey`).

    Args:
      task: a valid task of an off-policy kind.
      episode_length: env steps per episode.
      action_repeat: physics steps per env step.

    Returns:
      (the wrapped env, its `EnvSizes`).

    Raises:
      ConfigError: as `load_env`.
    """
    env, sizes = load_env(task)
    from brax.envs.base import Env as BraxEnv

    if isinstance(env, BraxEnv):
        from brax.envs.wrappers import training

        wrapped = training.wrap(env, episode_length=episode_length, action_repeat=action_repeat)
    else:
        from mujoco_playground import wrapper

        wrapped = wrapper.wrap_for_brax_training(env, episode_length=episode_length,
                                                 action_repeat=action_repeat)
    return (wrapped if sizes.obs_key is None else ObsKey(wrapped, sizes.obs_key)), sizes


class ObsKey:
    """A batched env whose states carry `obs[key]` as their observation: the whole observation rides in
    `info[ObsKey.FULL]` and is handed back to the wrapped env's `step`, so the env and its auto-reset see
    the observations they made."""

    FULL = "sf2_full_obs"

    def __init__(self, env, key: str):
        self.env, self.key = env, key

    def reset(self, rng):
        return self._select(self.env.reset(rng))

    def step(self, state, action):
        info = dict(state.info)
        obs = info.pop(self.FULL)
        return self._select(self.env.step(state.replace(obs=obs, info=info), action))

    def _select(self, state):
        return state.replace(obs=state.obs[self.key], info={**state.info, self.FULL: state.obs})

    @property
    def observation_size(self) -> int:
        return self.env.observation_size[self.key][-1]

    def __getattr__(self, name):          # action_size, unwrapped, ...
        return getattr(self.env, name)
