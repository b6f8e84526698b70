"""Helpers for both cores' agent tests: the CLI's bad-input cases (the same flags and messages in
`sf2-jax` and `sf2-torch`, since both are `sf2_common.cli`) and how a test runs one; the kill-and-resume
protocol (both trainers run `sf2_common.agents.hostloop`, so a kill lands at the same points)."""

from __future__ import annotations

__all__ = ["BAD_TRAIN_INPUTS", "cli_error", "KILL_POINTS", "Killed", "kill_and_resume"]

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
    (["--task", "CartpoleBalance", "--set", "gamma_su"], ["expected field=value"]),
    (["--task", "CartpoleBalance", "--gamma-su", "1.0"], ["gamma_su", "0 <= gamma_su < 1"]),
    (["--task", "CartpoleBalance", "--embedding-size", "7"], ["embedding_size", "even"]),
    (["--task", "CartpoleBalance", "--integrator", "rk4"], ["integrator", "midpoint"]),
    (["--task", "CartpoleBalance", "--seeds", "3-1"], ["seeds '3-1' are invalid"]),
    (["--task", "CartpoleBalance", "--seeds", "0,0"], ["duplicates"]),
    (["--task", "CartpoleBalance", "--repr", "sf2,sf2"], ["repeats"]),
]


def cli_error(main, capsys, *args) -> str:
    """Run `main(["train", ...args])`, assert exit status 2, return what it wrote to stderr."""
    argv = ["train", "--config", "quick", "--out", "/nonexistent/should-not-be-created", *args]
    assert main(argv) == 2
    return capsys.readouterr().err


# (event, epoch) a run is killed at, and the checkpoint its resume must start from: after an epoch's rows
# but before its checkpoint (rows must not be duplicated), right after a checkpoint, and before the
# first checkpoint (nothing to resume: a fresh start).
KILL_POINTS = [(("rows", 2), 1), (("checkpoint", 1), 1), (("rows", 0), None)]


class Killed(Exception):
    pass


def kill_and_resume(train, cfg, out, event: str, epoch: int, expected_resume):
    """Train `cfg` (seed 0) into `out`, killed at `(event, epoch)` through the trainer's hook; tear the
    last line of metrics.jsonl as a kill in the middle of a write would; train again. Checks where the
    resumed run started and returns its result (the caller compares it with an uninterrupted run)."""
    import pytest

    def hook(e, n):
        if (e, n) == (event, epoch):
            raise Killed(f"killed at {event} {epoch}")

    with pytest.raises(Killed):
        train(cfg, (0,), out, progress=False, hook=hook)
    with open(out / "metrics.jsonl", "a") as f:
        f.write('{"epoch": 3, "seed": 0, "eval_ret')
    resumed = train(cfg, (0,), out, progress=False)
    assert resumed.resumed_from == expected_resume
    return resumed
