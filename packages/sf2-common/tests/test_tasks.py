"""The task table's kinds: MinAtar ids are valid without Playground or pgx, carry their kind's data
(image observations, discrete actions, the on-policy trainer, the 10,000-step limit), are listed by
`tasks`, and are refused by the off-policy trainers' config validation, as Playground tasks are for the
on-policy `ppo`; a MinAtar task without pgx names the extra to install.

Playground is not needed: its task list is replaced by a fixed one, or hidden to prove it is not read.
"""

from __future__ import annotations

import subprocess
import sys

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
    monkeypatch.setattr(tasks, "playground_tasks", lambda: ("CheetahRun", "FishSwim"))


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
    assert (playground.observation, playground.action, playground.algos) == ("vector", "continuous",
                                                                            ("td3", "sac"))
    with pytest.raises(ModuleNotFoundError):   # other names still need Playground's list
        tasks.validate_task("CheetahRun")


def test_unknown_names_list_the_valid_ones_by_kind(playground):
    assert tasks.valid_tasks() == ("CheetahRun", "FishSwim", *MINATAR)
    assert tasks.task_kind("CheetahRun") is tasks.KINDS["playground"]
    with pytest.raises(ConfigError) as err:
        tasks.validate_task("minatar-breakot")
    assert "unknown task 'minatar-breakot'. Did you mean minatar-breakout, " in str(err.value)
    assert (f"Valid tasks (Playground DM Control: CheetahRun, FishSwim; MinAtar: {', '.join(MINATAR)})"
            in str(err.value))


def test_the_off_policy_trainers_refuse_minatar_tasks_before_compiling(playground):
    msg = ("task 'minatar-breakout' is a MinAtar task: MinAtar tasks take the on-policy trainer "
           "(--algo ppo); --algo td3 is the Playground DM Control tasks' off-policy trainer")
    with pytest.raises(ConfigError) as err:
        configs.make_config("quick", "minatar-breakout", algo="td3")
    assert str(err.value) == msg
    cfg = configs.TrainConfig(task="minatar-breakout", algo="sac")   # built without make_config
    with pytest.raises(ConfigError) as err:
        configs.validate(cfg, (0,), registry=None)
    assert str(err.value) == msg.replace("td3", "sac")
    tasks.check_algo("minatar-breakout", "ppo")        # the on-policy trainer's pairing passes
    tasks.check_algo("minatar-breakout", "no-such")    # an algo no kind lists: the trainer's own check


def test_a_playground_task_is_refused_for_ppo(playground):
    """`ppo` is the on-policy trainer's algo; the task-kind hook refuses it for Playground tasks."""
    assert "ppo" in configs.ALGOS and "ppo" in configs.ONPOLICY_ALGOS
    msg = ("task 'CheetahRun' is a Playground DM Control task: Playground DM Control tasks take the "
           "off-policy trainer (--algo td3 or --algo sac); --algo ppo is the MinAtar tasks' on-policy "
           "trainer")
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
    assert lines[0].split() == ["task", "kind", "paper", "budget", "action", "repeat", "in", "paper"]
    rows = {line.split()[0]: line for line in lines[1:]}
    assert list(rows) == ["CheetahRun", "FishSwim", *MINATAR]
    assert rows["CheetahRun"].split() == ["CheetahRun", "Playground", "DM", "Control", "10,000,000", "1",
                                          "yes"]
    assert rows["minatar-breakout"].split() == ["minatar-breakout", "MinAtar", "20,000,000", "1"]


def test_tasks_without_playground_lists_minatar_and_the_install_line(no_playground, capsys):
    assert cli.tasks_command(None) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines[1:-1]] == list(MINATAR)
    assert lines[-1] == ('(Playground DM Control tasks: not installed; '
                         'pip install "packages/sf2-core-jax[train]")')
