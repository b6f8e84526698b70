"""The command-line pieces both cores build on (sf2_common.cli), without a framework: commands of other
packages found by entry points (`sf2.commands`), the one line when `study` is not installed, the exit
statuses."""

from __future__ import annotations

import types

import pytest
from sf2_common import cli
from sf2_common.agents.configs import TrainConfig
from sf2_common.errors import ConfigError


def _parser(prog="sf2-x"):
    parser, sub = cli.new_parser(prog, "A test program.\n\nMore.")
    cli.add_train_parser(sub, prog, TrainConfig, "one after the other", "SF2_X_CACHE")
    cli.add_shared_parsers(sub, prog)
    return parser


def test_missing_study_command_says_how_to_install_it(monkeypatch, capsys):
    monkeypatch.setattr(cli, "plugin_commands", dict)
    parser = _parser()
    for argv in (["study", "run", "studies/smoke.toml", "--out", "x", "--dry-run"], ["study", "--help"],
                 ["study"]):
        assert cli.run("sf2-x", parser, {}, lambda: None, argv) == 2
        assert capsys.readouterr().err == ("sf2-x study: error: the study commands come with sf2-studies: "
                                           "pip install packages/sf2-studies\n")


def test_plugin_commands_get_the_backend(monkeypatch, capsys):
    """A command of the `sf2.commands` group adds its own parser and runs with the core's Backend."""
    calls = []

    def add_parser(sub, prog):
        p = sub.add_parser("study", help=f"studies of {prog}")
        p.add_argument("what")

    def main(backend, args):
        calls.append((backend, args.what, args.argv))
        if args.what == "bad":
            raise ConfigError("bad study")
        return 0

    monkeypatch.setattr(cli, "plugin_commands", lambda: {"study": types.SimpleNamespace(add_parser=add_parser,
                                                                                       main=main)})
    parser = _parser()
    backend = cli.Backend("sf2-x", "x", "sf2_x.cli", None, None)
    assert cli.run("sf2-x", parser, {}, lambda: backend, ["study", "report"]) == 0
    assert calls == [(backend, "report", ["study", "report"])]
    assert cli.run("sf2-x", parser, {}, lambda: backend, ["study", "bad"]) == 2
    assert capsys.readouterr().err == "sf2-x study: error: bad study\n"
    with pytest.raises(SystemExit) as exit_:
        cli.run("sf2-x", parser, {}, lambda: backend, ["study", "report", "--bogus"])
    assert exit_.value.code == 2


def test_installed_commands_are_found_by_entry_point():
    """The group each core's command line reads: whatever is installed loads and has the two functions."""
    for name, command in cli.plugin_commands().items():
        assert callable(command.add_parser) and callable(command.main), name


def test_exit_statuses_of_the_core_commands(capsys):
    def diverged(args):
        from sf2_common.agents.hostloop import TrainingDiverged

        raise TrainingDiverged("loss is nan")

    def missing(args):
        raise FileNotFoundError("runs/x is not a run folder")

    parser = _parser()
    commands = {"train": diverged, "plot": missing, "tasks": lambda args: 0}
    train = ["train", "--task", "CartpoleBalance", "--out", "x", "--learning-rate", "-1e-3"]
    assert cli.run("sf2-x", parser, commands, lambda: None, train) == 3
    assert cli.run("sf2-x", parser, commands, lambda: None, ["plot", "x"]) == 2
    assert capsys.readouterr().err.endswith("sf2-x plot: error: runs/x is not a run folder\n")
    assert cli.run("sf2-x", parser, commands, lambda: None, ["tasks"]) == 0
