"""sf2_testing, the shared test support of every package (not shipped; pytest.ini puts it on the path):
the CLI's bad-input cases (the same flags and messages in `sf2-jax` and `sf2-torch`) and how a test runs
one; the kill-and-resume protocol (both trainers run `sf2_common.agents.hostloop`, so a kill lands at the
same points), in-process at the host loop's hook points and as a real `kill -9` of a CLI process, also in
the middle of a checkpoint's save; the run-folder faults of docs/run-folders.md; two writers at once."""

from __future__ import annotations

__all__ = ["BAD_TRAIN_INPUTS", "cli_error", "check_cli_misuse", "check_baselines_resolve",
           "check_paper_preset", "check_cli_eval", "check_two_writers", "check_obs_noise_eval", "KILL_POINTS",
           "Killed",
           "kill_and_resume", "kill9", "check_cli_resume", "strip_wall", "cli_args", "FAULTS", "damage",
           "folder_digest"]

# (arguments after `train --config quick --out ...`, texts the error message must contain)
BAD_TRAIN_INPUTS = [
    (["--task", "CartpoleBalanse"], ["unknown task 'CartpoleBalanse'", "Did you mean CartpoleBalance",
                                     "AcrobotSwingup", "WalkerWalk"]),
    (["--task", "CartpoleBalance", "--algo", "ddpg"], ["algo = 'ddpg'", "td3, sac"]),
    (["--task", "CartpoleBalance", "--repr", "bogus"],
     ["representation = 'bogus'", "must be one of none, sf2", "sim", "simlap", "spr"]),
    (["--task", "CartpoleBalance", "--repr", "test_sac_only"],
     ["algo 'td3' with representation 'test_sac_only' does not exist", "sac+test_sac_only"]),
    (["--task", "CartpoleBalance", "--num-timesteps", "1000"],
     ["num_timesteps = 1000 does not exceed the prefill", "min_replay_size = 4096"]),
    (["--task", "CartpoleBalance", "--set", "min_replay_size=300000"],
     ["min_replay_size", "max_replay_size"]),
    (["--task", "CartpoleBalance", "--set", "batch_size=0"], ["batch_size = 0", ">= 1"]),
    (["--task", "CartpoleBalance", "--set", "batch_size=1.5"], ["batch_size", "integer"]),
    (["--task", "CartpoleBalance", "--set", "bogus=1"], ["unknown config field 'bogus'"]),
    (["--task", "CartpoleBalance", "--set", "clip_eps=0.1"],
     ["config field clip_eps = 0.1 would change nothing", "only --algo ppo, fpo read it, not --algo td3"]),
    (["--task", "CartpoleBalance", "--set", "gamma_su"], ["expected field=value"]),
    (["--task", "CartpoleBalance", "--gamma-su", "1.0"], ["gamma_su", "0 <= gamma_su < 1"]),
    (["--task", "CartpoleBalance", "--embedding-size", "7"], ["embedding_size", "even"]),
    (["--task", "CartpoleBalance", "--integrator", "rk4"], ["integrator", "midpoint"]),
    (["--task", "CartpoleBalance", "--algo", "ppo"],
     ["task 'CartpoleBalance' is a Playground DM Control task", "--algo ppo is the MinAtar tasks'"]),
    (["--task", "minatar-breakout", "--algo", "sac"], ["task 'minatar-breakout' is a MinAtar task"]),
    # users' environments (sf2_testing.toy_env), refused before anything is built or compiled
    (["--task", "no_such_module:make_env"], ["task 'no_such_module:make_env': module 'no_such_module' cannot "
                                             "be imported", "'module:callable'"]),
    (["--task", "sf2_testing.toy_env:make_no_env"], ["module 'sf2_testing.toy_env' has no attribute"]),
    (["--task", "sf2_testing.toy_env:make_not_env"], ["returned dict, which is not an environment",
                                                      "it lacks reset, step, observation_size, action_size"]),
    (["--task", "sf2_testing.toy_env:make_image_env"],
     ["has image observations {'pixels/view_0': (64, 64, 3)}", "the off-policy trainers take flat state"]),
    (["--task", "sf2_testing.toy_env:make_discrete_env"],
     ["has discrete actions (num_actions = 3)", "discrete actions are MinAtar's, with --algo ppo"]),
    (["--task", "CartpoleBalance", "--seeds", "3-1"], ["seeds '3-1' are invalid"]),
    (["--task", "CartpoleBalance", "--seeds", "0,0"], ["duplicates"]),
    (["--task", "CartpoleBalance", "--repr", "sf2,sf2"], ["repeats"]),
    # negative values reach the validation whatever their spelling (argparse alone refuses -1e-3)
    (["--task", "CartpoleBalance", "--learning-rate", "-1e-3"], ["learning_rate = -0.001 is invalid", "> 0"]),
    (["--task", "CartpoleBalance", "--learning-rate", "-0.001"], ["learning_rate = -0.001 is invalid"]),
    (["--task", "CartpoleBalance", "--set", "spr_augmentation_std=-0.05"],
     ["spr_augmentation_std = -0.05 is invalid", ">= 0"]),
]


def cli_error(main, capsys, *args) -> str:
    """Run `main(["train", ...args])`, assert exit status 2, return what it wrote to stderr."""
    argv = ["train", "--config", "quick", "--out", "/nonexistent/should-not-be-created", *args]
    assert main(argv) == 2
    return capsys.readouterr().err


def check_cli_misuse(main, capsys, tmp_path) -> None:
    """Exit status 2 with the problem named: an unknown `--config` preset; a method among several that the
    algorithm lacks (the test module registers "test_sac_only", a SAC-only representation), refused before
    any method trains; `eval` of a folder that holds no run."""
    assert main(["train", "--task", "CartpoleBalance", "--config", "huge", "--out", "/x"]) == 2
    assert "unknown config preset 'huge'" in capsys.readouterr().err
    err = cli_error(main, capsys, "--task", "CartpoleBalance", "--repr", "sf2,test_sac_only")
    assert "test_sac_only" in err
    assert main(["eval", str(tmp_path / "nothing")]) == 2
    assert "not a run folder" in capsys.readouterr().err


def check_baselines_resolve(cli, representations, reprs: str) -> None:
    """`--repr <reprs>` (e.g. "sim,spr") selects, for both algorithms, the core's classes: sf2-baselines'
    (entry points of "sf2.representations.<framework>", imported on first use) for sim/simlap/spr, each
    validated like sf2. `cli` is the core's CLI module, `representations` its registry module."""
    for algo in ("td3", "sac"):
        args = cli.build_parser().parse_args(["train", "--task", "CartpoleBalance", "--algo", algo, "--repr",
                                              reprs, "--seeds", "0-1", "--out", "/nonexistent"])
        cfgs, seeds = cli.resolve_configs(args)
        assert [c.representation for c in cfgs] == reprs.split(",") and seeds == (0, 1)
        for cfg in cfgs:
            cls = representations.get(cfg.representation)
            assert cls.name == cfg.representation and algo in cls.supported_algos
            if cfg.representation not in ("none", "sf2"):
                framework = cli.backend().name   # "jax" / "torch"
                assert cls.__module__ == f"sf2_baselines.{framework}.representations"


def check_paper_preset(make_config, envs):
    """The `paper` preset as docs/core-contract.md gives it (paper Table 1, with lr 1e-3 and tau_zeta 0.05
    as the authors' runs; 10M env steps, FishSwim 5M; action repeat 4 on PendulumSwingup); the core's
    `envs` knows every paper task. Returns PendulumSwingup's SAC+SF² config for the core's own checks."""
    paper = make_config("paper", "PendulumSwingup", "sac", "sf2")
    assert (paper.num_timesteps, paper.action_repeat, paper.learning_rate, paper.tau_zeta) == (
        10_000_000, 4, 1e-3, 0.05)
    assert (paper.num_envs, paper.batch_size, paper.grad_updates_per_step, paper.min_replay_size,
            paper.max_replay_size, paper.num_evals, paper.hidden_sizes, paper.feature_size) == (
        128, 512, 8, 8192, 4_194_304, 100, (512, 512, 512), 512)
    assert make_config("paper", "FishSwim").num_timesteps == 5_000_000
    assert set(envs.PAPER_TASKS) <= set(envs.valid_tasks())
    return paper


def check_cli_eval(main, capsys, run_path, episodes: int, last_eval_return: float) -> None:
    """`main(["eval", run_path, ...])` on a finished run of 1 seed (seed 0) with deterministic evaluation and
    `episodes` evaluation envs: the last checkpoint replays training's last evaluation (the same start
    states: the mean return equals `last_eval_return`); `--episodes 3 --stochastic` acts on 3 fresh starts,
    stochastically; `--episodes 0` exits 2 naming the value."""
    import json

    import numpy as np
    import pytest

    assert main(["eval", str(run_path), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["epoch"] == max(res["checkpoints"]) and len(res["returns"]["0"]) == episodes
    assert res["deterministic"] is True
    assert np.mean(res["returns"]["0"]) == pytest.approx(last_eval_return, rel=1e-5)
    assert main(["eval", str(run_path), "--json", "--episodes", "3", "--stochastic"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert len(res["returns"]["0"]) == 3 and res["deterministic"] is False
    assert main(["eval", str(run_path), "--episodes", "0"]) == 2
    assert "episodes = 0 is invalid" in capsys.readouterr().err


def check_obs_noise_eval(trainer, main, capsys, monkeypatch, run) -> None:
    """A core's evaluation under observation noise (paper App. C.2.2) on a copy `run` of a finished run of
    1 seed with checkpoints 2 and 3 (`trainer`: the core's trainer module, `main`: its CLI's): std 0 is the
    plain evaluation (the same program and acting noise: the same returns); a std > 0 changes what the
    policy sees and so the returns, reproducibly; several stds from one restore give one evaluation's
    numbers per std; a negative std is refused; `eval --obs-noise 0,1 --checkpoints 2 --save` restores
    each checkpoint once whatever the number of stds and saves obs_noise.json."""
    import json

    import numpy as np
    import pytest
    from sf2_common.errors import ConfigError

    plain = trainer.evaluate_checkpoint(run)
    assert plain["checkpoints"] == [2, 3] and plain["obs_noise"] == 0.0
    assert trainer.evaluate_checkpoint(run, obs_noise=0.0)["returns"] == plain["returns"]
    noisy = trainer.evaluate_checkpoint(run, obs_noise=1.0)
    assert noisy["obs_noise"] == 1.0 and noisy["returns"] != plain["returns"]
    assert trainer.evaluate_checkpoint(run, obs_noise=1.0)["returns"] == noisy["returns"]   # reproducible
    both = trainer.evaluate_checkpoint_noises(run, None, None, None, (0.0, 1.0))
    assert [(r["obs_noise"], r["returns"]) for r in both] == [(0.0, plain["returns"]),
                                                               (1.0, noisy["returns"])]
    with pytest.raises(ConfigError, match="obs_noise = -0.1 is invalid"):
        trainer.evaluate_checkpoint(run, obs_noise=-0.1)
    restored = []
    real_restore = trainer.Checkpointer.restore

    def counting_restore(self, epoch, *args, **kwargs):
        restored.append(epoch)
        return real_restore(self, epoch, *args, **kwargs)

    monkeypatch.setattr(trainer.Checkpointer, "restore", counting_restore)
    assert main(["eval", str(run), "--obs-noise", "0,1", "--checkpoints", "2", "--save"]) == 0
    assert restored == [3, 2]
    saved = json.loads((run / "obs_noise.json").read_text())
    assert [(r["noise"], r["epoch"]) for r in saved["results"]] == [(0.0, 2), (1.0, 2), (0.0, 3), (1.0, 3)]
    # written with the shortest decimal of each float32 return: the same float32 values
    assert {k: np.float32(v).tolist() for k, v in saved["results"][3]["returns"].items()} == {
        str(k): np.float32(v).tolist() for k, v in noisy["returns"].items()}
    assert saved["settings"] == {"obs_noise": [0.0, 1.0], "checkpoints": 2, "episodes": None,
                                 "deterministic": None}
    assert "noise std" in capsys.readouterr().out


# (event, epoch) a run is killed at, and the checkpoint its resume must start from: after an epoch's rows
# but before its checkpoint (rows must not be duplicated), during an epoch's training (after the previous
# checkpoint), and during the first evaluation (nothing to resume: a fresh start). Nothing is written while
# an epoch trains or evaluates, so a kill anywhere in one leaves the folder as at its start. A kill in the
# middle of a save, `("mid-save", epoch)`, leaves the checkpoint's files written but not its manifest;
# where the run resumes then depends on the framework's save (see the cores' fault tests).
KILL_POINTS = [(("rows", 2), 1), (("train", 2), 1), (("evaluate", 0), None)]


class Killed(Exception):
    pass


def kill_and_resume(train, cfg, out, event: str, epoch: int, expected_resume):
    """Train `cfg` (seed 0) into `out`, killed at `(event, epoch)` through the trainer's hook (or, for
    "mid-save", as the save's last step begins); tear the last line of metrics.jsonl as a kill in the
    middle of a write would; train again. Checks where the resumed run started and returns its result (the
    caller compares it with an uninterrupted run). The exception stands for SIGKILL: the folder is left as
    it was at that point (`kill9` checks this with a real one)."""
    import pytest
    from sf2_common.agents import checkpoints

    def hook(e, n):
        if (e, n) == (event, epoch):
            raise Killed(f"killed at {event} {epoch}")

    write_manifest = checkpoints.write_manifest

    def write_or_die(folder):
        hook("mid-save", int(str(folder).rstrip("/").split("/")[-1].lstrip(".").split(".")[0]))
        write_manifest(folder)

    checkpoints.write_manifest = write_or_die
    try:
        with pytest.raises(Killed):
            train(cfg, (0,), out, progress=False, hook=hook)
    finally:
        checkpoints.write_manifest = write_manifest
    with open(out / "metrics.jsonl", "a") as f:
        f.write('{"epoch": 3, "seed": 0, "eval_ret')
    resumed = train(cfg, (0,), out, progress=False)
    assert resumed.resumed_from == expected_resume
    return resumed


# ------------------------------------------------------------------------------------------- kill -9
_KILL9_DRIVER = """
import importlib, os, signal, sys
from sf2_common.agents import checkpoints, hostloop
event, epoch, module = sys.argv[1], int(sys.argv[2]), sys.argv[3]

def die():
    os.kill(os.getpid(), signal.SIGKILL)

if event == "mid-save":  # the checkpoint's files are written, its manifest (the save's last step) is not
    write_manifest = checkpoints.write_manifest

    def write_or_die(folder):
        if int(os.path.basename(str(folder)).lstrip(".").split(".")[0]) == epoch:
            die()
        write_manifest(folder)

    checkpoints.write_manifest = write_or_die
else:
    call_hook = hostloop.call_hook

    def hook_or_die(hook, e, n):
        if (e, n) == (event, epoch):
            die()
        call_hook(hook, e, n)

    hostloop.call_hook = hook_or_die
sys.exit(importlib.import_module(module).main(sys.argv[4:]))
"""


def kill9(cli_module: str, argv: list[str], at: tuple[str, int], env: dict | None = None,
          timeout: float = 600):
    """Run `python -m cli_module argv` in a new process that sends itself SIGKILL at `at`: a host-loop
    hook point (`("train", 2)`: as epoch 2 starts training, ...) or `("mid-save", epoch)` (the checkpoint's
    files written, the save not finished). Returns the `subprocess.CompletedProcess`; asserts the kill."""
    import os
    import signal
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _KILL9_DRIVER, at[0], str(at[1]), cli_module, *argv],
                          capture_output=True, text=True, timeout=timeout, env={**os.environ, **(env or {})})
    assert proc.returncode == -signal.SIGKILL, (proc.returncode, proc.stderr[-3000:])
    return proc


def strip_wall(rows) -> list[dict]:
    """metrics rows without their wall-clock fields (`hostloop.WALL_FIELDS`): what a resumed or repeated run
    must reproduce exactly."""
    from sf2_common.agents.hostloop import WALL_FIELDS

    return [{k: v for k, v in r.items() if k not in WALL_FIELDS} for r in rows]


def check_cli_resume(main, args, out, capfd, resumed_from: str, reference_rows) -> list[dict]:
    """After `kill9` of `train args`: the same command resumes, saying `resuming OUT from RESUMED_FROM`
    (e.g. "checkpoint 0 (epoch 0 of 3, env step 0)") without library noise on stderr, to the uninterrupted
    run's rows; run once more, it says the run is complete and its table shows the training's own wall
    time, not the rerun's; config.json and each session's train.log line name the hardware. Returns the
    rows."""
    import re

    from sf2_common.agents.runfolder import RunFolder

    capfd.readouterr()
    assert main(args) == 0
    err = capfd.readouterr().err
    assert f"resuming {out} from {resumed_from}" in err, err
    # the killed process's lock file still names it: taken over, said in one line
    assert re.search(rf"{out}: taking over the lock of pid \d+ on host .* \(sf2-\w+ train, since .*\), which "
                     rf"is gone", err), err
    assert "absl" not in err and "Waiting for previous save" not in err
    rows = RunFolder(out).read_rows()
    assert strip_wall(rows) == strip_wall(reference_rows)
    assert main(args) == 0
    captured = capfd.readouterr()
    assert "taking over" not in captured.err   # a clean exit leaves no stale holder
    walltime = max(r["walltime"] for r in rows)
    assert f"{out}: the run is complete (epoch 3 of 3, 144 env steps, trained in {walltime:.0f} s)" in \
        captured.err
    assert re.search(rf"\| {walltime:.0f} s\n", captured.out), captured.out
    # the hardware of the first session is in config.json, each of the three sessions named it in train.log
    # (the killed one, the resume, the "complete" one); these tests run on the CPU
    from sf2_common.agents.hostloop import environment_line, hardware, numerics_environment

    run = RunFolder(out)
    assert run.read_config()["hardware"] == hardware([])
    log = run.log_path.read_text()
    assert log.count(f" hardware: {hardware([])}\n") == 3, log
    # and the environment variables that change the numbers (XLA_FLAGS, ...), as this process has them
    assert run.read_config()["environment"] == numerics_environment()
    assert log.count(f" {environment_line(numerics_environment())}\n") == 3, log
    return rows


def check_two_writers(train, cli_module: str, cfg, out, reference_rows, at=("train", 2)):
    """Two `train`s on one run folder at once: while `train(cfg, (0,), out)` runs (at the hook point `at`),
    `python -m cli_module train` on the same folder exits with status 2 naming this process's pid and host,
    and changes nothing; the first run's rows equal the uninterrupted run's, one line each. Returns the
    first run's `TrainResult` (the caller checks its checkpoints)."""
    import os
    import socket
    import subprocess
    import sys

    from sf2_common.agents.runfolder import RunFolder

    second = {}

    def files():   # what the second process could change (checkpoints: the first may be saving one now)
        return {k: v for k, v in folder_digest(out).items() if not k.startswith("checkpoints/")}

    def hook(event, epoch):
        if (event, epoch) == at and not second:
            before = files()
            second["proc"] = subprocess.run([sys.executable, "-m", cli_module, *cli_args(cfg, out)],
                                            capture_output=True, text=True, timeout=600)
            second["unchanged"] = files() == before

    first = train(cfg, (0,), out, progress=False, hook=hook, plot=False)
    proc = second["proc"]
    assert proc.returncode == 2, proc.stderr[-3000:]
    holder = f"pid {os.getpid()} on host {socket.gethostname()} ("
    assert f"run folder {out} is in use by {holder}" in proc.stderr, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr and second["unchanged"]
    assert strip_wall(first.rows) == strip_wall(reference_rows)
    lines = [line for line in RunFolder(out).metrics_path.read_text().splitlines() if line.strip()]
    assert len(lines) == len(reference_rows)
    assert strip_wall(RunFolder(out).read_rows()) == strip_wall(reference_rows)
    return first


def cli_args(cfg, out, fields_skipped=("task", "algo", "representation")) -> list[str]:
    """`train` arguments that make the CLI build exactly `cfg` (every field as its own flag)."""
    args = ["train", "--task", cfg.task, "--algo", cfg.algo, "--repr", cfg.representation,
            "--config", "quick", "--seeds", "0", "--out", str(out), "--no-progress"]
    for name, value in cfg.to_dict().items():
        if name not in fields_skipped:
            args += [f"--{name.replace('_', '-')}",
                     ",".join(map(str, value)) if isinstance(value, (list, tuple)) else str(value)]
    return args


# ------------------------------------------------------------------------------------------- file faults
FAULTS = ("truncate", "garble", "delete")


def damage(path, fault: str) -> None:
    """Truncate `path` to half its size, flip 16 bytes a third of the way in, or delete it."""
    from pathlib import Path

    path = Path(path)
    if fault == "delete":
        path.unlink()
        return
    data = bytearray(path.read_bytes())
    if fault == "truncate":
        data = data[: len(data) // 2]
    elif fault == "garble":
        start = len(data) // 3
        for i in range(start, min(len(data), start + 16)):
            data[i] ^= 0x5A
    else:
        raise ValueError(f"fault {fault!r}: must be one of {', '.join(FAULTS)}")
    path.write_bytes(bytes(data))


def folder_digest(folder) -> dict[str, str]:
    """{relative path: SHA-256} of every file under `folder` (a folder left unchanged has the same)."""
    import hashlib
    from pathlib import Path

    folder = Path(folder)
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}
