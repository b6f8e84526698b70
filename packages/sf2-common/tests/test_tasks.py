"""The task table's kinds: MinAtar ids are valid without Playground or pgx, carry their kind's data
(image observations, discrete actions, the on-policy trainer, the 10,000-step limit), are listed by
`tasks`, and are refused by the off-policy trainers' config validation, as Playground tasks are for the
on-policy `ppo`; a MinAtar task without pgx names the extra to install. Users' environments by import path
and entry point: their kind and preset values, the checks of their observations and actions (fakes with
Playground's conventions), `ObsKey`.

Playground is not needed: its task list is replaced by a fixed one, or hidden to prove it is not read; the
list's cache between processes reads a fake registry.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import types
from importlib import metadata

import pytest
from sf2_common import cli
from sf2_common.agents import configs, tasks
from sf2_common.errors import ConfigError

MINATAR = ("minatar-asterix", "minatar-breakout", "minatar-freeway", "minatar-seaquest",
           "minatar-space_invaders")
INSTALL = 'pip install "packages/sf2-core-jax[minatar]"'


@pytest.fixture
def no_playground(monkeypatch):
    """Playground's task list raises as it does where Playground is not installed."""
    def missing():
        raise ModuleNotFoundError("No module named 'mujoco_playground'")
    monkeypatch.setattr(tasks, "playground_tasks", missing)


@pytest.fixture
def playground(monkeypatch):
    """A fixed list of paper tasks (their budgets are the table's: no Playground config is read)."""
    listed = dict.fromkeys(("CheetahRun", "FishSwim"), "playground")
    monkeypatch.setattr(tasks, "playground_tasks", lambda: listed)


def test_minatar_tasks_are_valid_without_playground_and_carry_their_kind(no_playground):
    assert tuple(tasks.MINATAR_TASKS) == MINATAR and set(MINATAR) <= set(tasks.TASKS)
    for task in MINATAR:
        assert tasks.validate_task(task) == task
        kind = tasks.task_kind(task)
        assert (kind.name, kind.label, kind.observation, kind.action, kind.trainer, kind.algos) == (
            "minatar", "MinAtar", "image", "discrete", "on-policy", ("ppo",))
        assert kind.episode_length == 10_000 and kind.requires == "pgx" and kind.install == INSTALL
        row = tasks.TASKS[task]
        assert row.kind == "minatar" and row.obs_shape[:2] == (10, 10) and 3 <= row.num_actions <= 6
        assert tasks.paper_budget(task) == 20_000_000 and tasks.paper_action_repeat(task) == 1
    playground = tasks.KINDS["playground"]
    assert (playground.observation, playground.action, playground.algos[:2]) == ("vector", "continuous",
                                                                                ("td3", "sac"))
    with pytest.raises(ModuleNotFoundError):   # other names still need Playground's list
        tasks.validate_task("CheetahRun")


def test_unknown_names_list_the_valid_ones_by_kind(playground):
    assert tasks.valid_tasks() == ("CheetahRun", "FishSwim", *MINATAR, "ant-goal")
    assert tasks.task_kind("CheetahRun") is tasks.KINDS["playground"]
    with pytest.raises(ConfigError) as err:
        tasks.validate_task("minatar-breakot")
    assert "unknown task 'minatar-breakot'. Did you mean minatar-breakout, " in str(err.value)
    assert (f"Valid tasks (Playground DM Control: CheetahRun, FishSwim; MinAtar: {', '.join(MINATAR)}; "
            f"goal-reaching: ant-goal)" in str(err.value))


def test_the_off_policy_trainers_refuse_minatar_tasks_before_compiling(playground):
    msg = ("task 'minatar-breakout' is a MinAtar task: MinAtar tasks take the on-policy trainer "
           "(--algo ppo); --algo td3 is the Playground DM Control, Playground locomotion, Playground "
           "manipulation and user environment tasks' off-policy trainer")
    with pytest.raises(ConfigError) as err:
        configs.make_config("quick", "minatar-breakout", algo="td3")
    assert str(err.value) == msg
    cfg = configs.TrainConfig(task="minatar-breakout", algo="sac")   # built without make_config
    with pytest.raises(ConfigError) as err:
        configs.validate(cfg, (0,), registry=None)
    assert str(err.value) == msg.replace("td3", "sac")
    tasks.check_algo("minatar-breakout", "ppo")        # the on-policy trainer's pairing passes
    tasks.check_algo("minatar-breakout", "no-such")    # an algo no kind lists: the trainer's own check
    with pytest.raises(ConfigError) as err:            # fpo: named as the on-policy trainer's, not its kind's
        tasks.check_algo("minatar-breakout", "fpo")
    assert str(err.value) == ("task 'minatar-breakout' is a MinAtar task: MinAtar tasks take the "
                              "on-policy trainer (--algo ppo); --algo fpo is the Playground DM Control "
                              "tasks' on-policy trainer")


def test_a_playground_task_is_refused_for_ppo(playground):
    """`ppo` is the on-policy trainer's algo; the task-kind hook refuses it for Playground tasks."""
    assert "ppo" in configs.ALGOS and "ppo" in configs.ONPOLICY_ALGOS
    assert tasks.KINDS["playground"].algos == ("td3", "sac", "fpo")
    msg = ("task 'CheetahRun' is a Playground DM Control task: Playground DM Control tasks take the "
           "off-policy trainer (--algo td3 or --algo sac) or the on-policy trainer (--algo fpo); "
           "--algo ppo is the MinAtar tasks' on-policy trainer")
    with pytest.raises(ConfigError) as err:
        tasks.check_algo("CheetahRun", "ppo")
    assert str(err.value) == msg
    with pytest.raises(ConfigError) as err:
        configs.validate(configs.TrainConfig(task="CheetahRun", algo="ppo"), (0,), registry=None)
    assert str(err.value) == msg
    tasks.check_algo("CheetahRun", "sac")
    tasks.check_installed("CheetahRun")   # Playground's list itself needs Playground: nothing to find


def test_a_minatar_task_without_pgx_says_how_to_install_it(monkeypatch, no_playground):
    monkeypatch.setitem(sys.modules, "pgx", None)   # `import pgx` raises ImportError; find_spec finds none
    msg = f"task 'minatar-seaquest' is a MinAtar task and needs 'pgx', which is not installed: {INSTALL}"
    with pytest.raises(ConfigError) as err:
        tasks.check_installed("minatar-seaquest")
    assert str(err.value) == msg
    with pytest.raises(ConfigError) as err:   # the on-policy pairing gets as far as the install check
        configs.validate(configs.TrainConfig(task="minatar-seaquest", algo="ppo"), (0,), registry=None)
    assert str(err.value) == msg


def test_the_table_imports_neither_playground_nor_pgx():
    code = ("import sys; from sf2_common.agents import configs, tasks; t = 'minatar-freeway'; "
            "tasks.validate_task(t); tasks.task_kind(t); tasks.check_algo(t, 'ppo'); tasks.paper_budget(t); "
            "\ntry: tasks.check_installed(t)\nexcept Exception: pass\n"
            "print(sorted(m for m in ('pgx', 'mujoco_playground', 'jax', 'torch') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_tasks_lists_each_task_with_its_kind(playground, capsys):
    assert cli.tasks_command(None) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["task", "kind", "paper", "budget", "episode", "repeat", "in", "paper"]
    rows = {line.split()[0]: line for line in lines[1:-1]}
    assert list(rows) == ["CheetahRun", "FishSwim", *MINATAR, "ant-goal"]
    assert rows["CheetahRun"].split() == ["CheetahRun", "Playground", "DM", "Control", "10,000,000", "1000",
                                          "1", "yes"]
    assert rows["minatar-breakout"].split() == ["minatar-breakout", "MinAtar", "20,000,000", "10000", "1"]
    assert rows["ant-goal"].split() == ["ant-goal", "goal-reaching", "10,000,000", "1000", "1"]
    assert lines[-1] == "(your own environment: --task module:callable, or an entry point of 'sf2.tasks'; " \
                        "docs/agents.md)"


def test_tasks_without_playground_lists_minatar_and_the_install_line(no_playground, capsys):
    assert cli.tasks_command(None) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines[1:-2]] == [*MINATAR, "ant-goal"]
    assert lines[-2] == '(Playground tasks: not installed; pip install "packages/sf2-core-jax[train]")'


# ------------------------------------------------------------------------------------------- users' envs
@dataclasses.dataclass(frozen=True)
class FakeState:
    obs: object
    info: dict

    def replace(self, **changes):
        return dataclasses.replace(self, **changes)


class FakeEnv:
    """An environment as the trainers see one (Playground's conventions for sizes); never stepped here
    except by `ObsKey`'s test: `step` records the observation it was given."""

    def __init__(self, observation_size, action_size=2, **extra):
        self.observation_size, self.action_size = observation_size, action_size
        self.seen = []
        self.__dict__.update(extra)

    def reset(self, rng):
        return FakeState({"state": [rng], "privileged_state": [rng, 0]}, {"steps": 0})

    def step(self, state, action):
        self.seen.append(state.obs)
        steps = state.info["steps"] + 1
        return FakeState({"state": [action], "privileged_state": [action, 1]}, {"steps": steps})


LOCOMOTION = {"state": (48,), "privileged_state": (123,)}    # Go1's observation_size in Playground
FAKES = {
    "flat": lambda: FakeEnv(5),
    "locomotion": lambda: FakeEnv(LOCOMOTION, 12),
    "image": lambda: FakeEnv((64, 64, 3)),
    "vision": lambda: FakeEnv({"pixels/view_0": (64, 64, 3)}),    # Playground's vision observations
    "no_state": lambda: FakeEnv({"proprio": (7,), "target": (3,)}),
    "discrete": lambda: FakeEnv(5, num_actions=4),
    "bad_action": lambda: FakeEnv(5, action_size=(2, 2)),
    "not_env": lambda: object(),
    "needs_args": lambda size: FakeEnv(size),
    "not_callable": 3,
}
SUPPORTED = ("the off-policy trainers take flat state vectors (observation_size an int, or a dict holding "
             "one under 'state') and continuous actions in [-1, 1] (action_size an int); image observations "
             "and discrete actions are MinAtar's, with --algo ppo")


@pytest.fixture
def user_envs(monkeypatch, no_playground):
    """The module `fake_user_envs` holding `FAKES`, and the entry point `toy` of sf2.tasks naming its flat
    env; Playground is absent (a user's environment does not read its task list)."""
    module = types.ModuleType("fake_user_envs")
    module.__dict__.update(FAKES)
    monkeypatch.setitem(sys.modules, "fake_user_envs", module)
    toy = metadata.EntryPoint(name="toy", value="fake_user_envs:locomotion", group=tasks.GROUP)
    monkeypatch.setattr(tasks, "task_entry_points", lambda: {"toy": toy})
    for cached in (tasks.env_factory, tasks.load_env):
        cached.cache_clear()
    yield
    for cached in (tasks.env_factory, tasks.load_env):
        cached.cache_clear()


def test_user_environments_by_import_path_and_entry_point(user_envs, monkeypatch):
    monkeypatch.setattr(sys.modules["fake_user_envs"], "Envs", types.SimpleNamespace(flat=FAKES["flat"]),
                        raising=False)
    for task, sizes in (("fake_user_envs:flat", (5, 2, None)), ("toy", (48, 12, "state")),
                        ("fake_user_envs:Envs.flat", (5, 2, None)),   # an attribute path, as entry points
                        ("fake_user_envs:locomotion", (48, 12, "state"))):
        assert tasks.validate_task(task) == task and tasks.task_kind(task) is tasks.KINDS["user"]
        env, got = tasks.load_env(task)
        assert isinstance(env, FakeEnv) and (got.obs_size, got.action_size, got.obs_key) == sizes
        paper = configs.make_config("paper", task, "sac")
        assert (paper.num_timesteps, paper.episode_length, paper.action_repeat) == (
            max(tasks.PAPER_BUDGETS.values()), 1000, 1)
        tasks.check_env(task)
    with pytest.raises(ConfigError) as err:   # the user kind takes the off-policy trainer
        configs.make_config("quick", "toy", algo="ppo")
    assert str(err.value).startswith("task 'toy' is a user environment task: user environment tasks take the "
                                     "off-policy trainer (--algo td3 or --algo sac)")


@pytest.mark.parametrize("name,message", [
    ("no_such_module_xyz:make", "task 'no_such_module_xyz:make': module 'no_such_module_xyz' cannot be "
                                "imported (No module named 'no_such_module_xyz'); an import-path task is "
                                "'module:callable'"),
    ("fake_user_envs:missing", "task 'fake_user_envs:missing': module 'fake_user_envs' has no attribute "
                               "'missing'"),
    ("fake_user_envs:", "task 'fake_user_envs:' is not an import path: expected 'module:callable'"),
    ("fake_user_envs:not_callable", "task 'fake_user_envs:not_callable': 3 is not callable; it must be a "
                                    "callable of no arguments returning the environment"),
])
def test_an_import_path_that_does_not_import_is_refused(user_envs, name, message):
    with pytest.raises(ConfigError) as err:
        tasks.validate_task(name)
    assert str(err.value).startswith(message)
    with pytest.raises(ConfigError) as again:    # make_config refuses it as the CLIs and study files do
        configs.make_config("quick", name)
    assert str(again.value) == str(err.value)


@pytest.mark.parametrize("name,message", [
    ("image", f"has image observations (64, 64, 3); {SUPPORTED}"),
    ("vision", f"has image observations {{'pixels/view_0': (64, 64, 3)}}; {SUPPORTED}"),
    ("no_state", f"has observations {{'proprio': (7,), 'target': (3,)}}, which the agents cannot read; "
                 f"{SUPPORTED}"),
    ("discrete", f"has discrete actions (num_actions = 4); {SUPPORTED}"),
    ("bad_action", f"has action_size (2, 2); {SUPPORTED}"),
    ("not_env", "its callable returned object, which is not an environment: it lacks reset, step, "
                "observation_size, action_size; an environment has reset(rng) -> state and step(state, "
                "action) -> state"),
    ("needs_args", "calling <function <lambda>"),
])
def test_an_environment_the_agents_cannot_drive_is_refused_before_compiling(user_envs, name, message):
    task = f"fake_user_envs:{name}"
    cfg = configs.make_config("quick", task)   # valid as a name: its callable imports
    with pytest.raises(ConfigError) as err:
        configs.validate(cfg, (0,), registry=None)   # refused before the representation is looked up
    assert message in str(err.value) and str(err.value).startswith(f"task {task!r}")


def test_obs_key_hands_the_whole_observation_back_to_the_env(user_envs):
    env = FAKES["locomotion"]()
    wrapped = tasks.ObsKey(env, "state")
    first = wrapped.reset(7)
    whole = {"state": [7], "privileged_state": [7, 0]}
    assert first.obs == [7] and first.info == {"steps": 0, tasks.ObsKey.FULL: whole}
    second = wrapped.step(first, 9)
    assert env.seen == [whole]     # the env's own observation, whole
    assert second.obs == [9] and second.info[tasks.ObsKey.FULL]["privileged_state"] == [9, 1]
    assert wrapped.observation_size == 48 and wrapped.action_size == 12


def test_locomotion_and_manipulation_tasks_take_playgrounds_env_config(monkeypatch):
    """Kinds by suite; the `paper` preset's budget is OFF_POLICY_BUDGET and the episode length and action
    repeat are Playground's env config's (a stand-in here: the real configs are read in the cores' tests)."""
    listed = {"CheetahRun": "playground", "Go1Getup": "locomotion", "PandaRobotiqPushCube": "manipulation"}
    monkeypatch.setattr(tasks, "playground_tasks", lambda: listed)
    conf = {"Go1Getup": types.SimpleNamespace(episode_length=300, action_repeat=1),
            "PandaRobotiqPushCube": types.SimpleNamespace(episode_length=3000, action_repeat=4)}
    monkeypatch.setattr(tasks, "_playground_config", conf.__getitem__)
    for task, kind, length, repeat in (("Go1Getup", "locomotion", 300, 1),
                                       ("PandaRobotiqPushCube", "manipulation", 3000, 4),
                                       ("CheetahRun", "playground", 1000, 1)):
        assert tasks.task_kind(task) is tasks.KINDS[kind]
        paper = configs.make_config("paper", task, "td3")
        assert (paper.num_timesteps, paper.episode_length, paper.action_repeat) == (
            tasks.paper_budget(task), length, repeat)
        assert configs.make_config("quick", task).episode_length == length
    assert tasks.paper_budget("Go1Getup") == tasks.OFF_POLICY_BUDGET == 10_000_000
    assert tasks.paper_budget("CheetahRun") == tasks.PAPER_BUDGETS["CheetahRun"]


def test_a_locomotion_task_whose_models_cannot_be_fetched_says_why(monkeypatch):
    """Playground clones MuJoCo Menagerie with git when a locomotion or manipulation task is first built;
    without a network that fails (git's CalledProcessError), and the task says so instead of a traceback."""
    listed = {"Go1Getup": "locomotion", "CheetahRun": "playground"}
    monkeypatch.setattr(tasks, "playground_tasks", lambda: listed)

    def clone_fails():
        raise subprocess.CalledProcessError(128, ["git", "clone"])

    monkeypatch.setattr(tasks, "env_factory", lambda task: clone_fails)
    tasks.load_env.cache_clear()
    with pytest.raises(ConfigError) as err:
        tasks.load_env("Go1Getup")
    assert str(err.value).startswith("task 'Go1Getup': Playground could not build it (Command '['git', "
                                     "'clone']' returned non-zero exit status 128.); its locomotion and "
                                     "manipulation tasks need MuJoCo Menagerie's models")
    with pytest.raises(subprocess.CalledProcessError):   # a DM Control task's failure is not about models
        tasks.load_env("CheetahRun")
    tasks.load_env.cache_clear()


@pytest.fixture
def registry_cache(monkeypatch, tmp_path):
    """Playground's task names kept under tmp_path, its stamp fixed, and a fake registry to import."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(tasks, "_registry_stamp", lambda: "v1")
    suites = {k.suite: types.SimpleNamespace(ALL_ENVS=()) for k in tasks.KINDS.values() if k.suite}
    suites["dm_control_suite"] = types.SimpleNamespace(ALL_ENVS=("CheetahRun", "FishSwim"))
    suites["locomotion"] = types.SimpleNamespace(ALL_ENVS=("Go1JoystickFlatTerrain",))
    fake = types.ModuleType("mujoco_playground")
    fake.registry = types.SimpleNamespace(**suites)
    monkeypatch.setitem(sys.modules, "mujoco_playground", fake)
    tasks.playground_tasks.cache_clear()
    yield tmp_path / "sf2" / "playground-tasks.json"
    tasks.playground_tasks.cache_clear()


REGISTRY = {"CheetahRun": "playground", "FishSwim": "playground", "Go1JoystickFlatTerrain": "locomotion"}


def test_playground_task_names_are_kept_and_read_back_without_the_registry(registry_cache, monkeypatch):
    assert tasks.playground_tasks() == REGISTRY
    assert json.loads(registry_cache.read_text()) == {"stamp": "v1", "tasks": REGISTRY}
    monkeypatch.delitem(sys.modules, "mujoco_playground")
    monkeypatch.setattr("builtins.__import__", _refuse_playground(__import__))
    tasks.playground_tasks.cache_clear()
    assert tasks.playground_tasks() == REGISTRY
    assert list(tasks.playground_tasks()) == list(REGISTRY)   # the registries' order, for the error message


def test_a_stale_or_damaged_cache_is_read_again_from_the_registry(registry_cache):
    registry_cache.parent.mkdir(parents=True)
    for kept in ({"stamp": "v0", "tasks": {"Gone": "playground"}}, "not json", {"stamp": "v1"},
                 {"stamp": "v1", "tasks": {"CheetahRun": "a kind sf2 no longer has"}},
                 {"stamp": "v1", "tasks": 3}):
        registry_cache.write_text(json.dumps(kept) if isinstance(kept, dict) else kept)
        tasks.playground_tasks.cache_clear()
        assert tasks.playground_tasks() == REGISTRY
        assert json.loads(registry_cache.read_text()) == {"stamp": "v1", "tasks": REGISTRY}


def test_an_unwritable_cache_still_lists_the_tasks(registry_cache, monkeypatch, tmp_path):
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "file"))   # sf2/ cannot be made under a file
    assert tasks.playground_tasks() == REGISTRY
    assert not registry_cache.exists()


def test_without_a_stamp_nothing_is_kept(registry_cache, monkeypatch):
    monkeypatch.setattr(tasks, "_registry_stamp", lambda: None)
    assert tasks.playground_tasks() == REGISTRY
    assert not registry_cache.exists()


def _refuse_playground(real):
    def guarded(name, *args, **kwargs):
        if name.startswith("mujoco_playground"):
            raise AssertionError("Playground imported although its task names are kept")
        return real(name, *args, **kwargs)
    return guarded
