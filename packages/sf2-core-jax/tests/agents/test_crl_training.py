"""The goal-conditioned trainer (sf2_jax.agents.crl) on `ant-goal` with `--config quick`, through
`sf2-jax train --task ant-goal --algo crl`: the critic learns (its contrastive accuracy far above chance),
alone and as each of two vmapped seeds, a run stopped after its first epoch resumes to the same rows, bad
input is refused before compiling, and the presets' InfoNCE (paper: backward) against folders written
before the choice existed, and which Adam state CRL+SF²'s flow step advances.

The learning signal: a critic that has learned nothing ranks a row's own goal first among the batch's B
goals with probability 1/B (chance, 1/64 here); the last epoch's mean accuracy over its 2000 SGD steps must
be at least 5/B. Random-policy data make the task easy (a goal k ~ Geometric steps ahead is near the
current (x, y)), so a working critic is far above that (0.26 observed); a broken one (goals from another
episode, a sign error in the energy, negatives that include the positive) stays near 1/B.
"""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import optax
import pytest
from sf2_common.agents import configs
from sf2_common.agents.runfolder import RunFolder, RunFolderMismatch
from sf2_jax import cli
from sf2_jax import losses_crl as lc
from sf2_jax.agents import antgoal, crl, make_config
from sf2_jax.agents.goal_replay import GoalSample
from sf2_testing import cli_args, cli_error, strip_wall


@pytest.fixture(scope="module")
def cfg():
    return make_config("quick", "ant-goal", algo="crl", representation="none")


@pytest.fixture(scope="module")
def cli_run(cfg, tmp_path_factory):
    """The quick config trained by `sf2-jax train` (seed 0): its run folder and rows."""
    out = tmp_path_factory.mktemp("crl") / "run"
    assert cli.main(cli_args(cfg, out)) == 0
    return out, [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_quick_crl_learns_the_contrastive_critic(cfg, cli_run):
    _, rows = cli_run
    assert [r["env_steps"] for r in rows] == [0, 4000, 8000]
    last = rows[-1]
    assert last["sgd_steps"] == 500 * cfg.grad_updates_per_step   # 500 actor steps, none of them prefill
    chance = 1 / cfg.batch_size
    assert last["accuracy"] >= 5 * chance, (last["accuracy"], chance)
    assert last["logits_pos"] > last["logits_neg"]
    # on spring the Ant does not fall under this policy, so every episode runs its 100 steps: 8 envs × 500
    # steps end at most 40 (an Ant that falls, as on MJX, ends more, and shorter)
    assert 0 < last["train_episodes"] <= cfg.num_envs * 500 // cfg.episode_length, last["train_episodes"]
    assert last["train_episode_length"] == pytest.approx(cfg.num_envs * 500 / last["train_episodes"])


@pytest.mark.slow
def test_eval_replays_the_last_evaluation(cfg, cli_run, capsys):
    """`sf2-jax eval RUN` restores the last checkpoint and replays training's last evaluation (the same
    start states and deterministic policy: the same returns); what it does not offer exits 2."""
    out, rows = cli_run
    assert cli.main(["eval", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["epoch"] == max(res["checkpoints"]) and len(res["returns"]["0"]) == cfg.num_eval_envs
    assert sum(res["returns"]["0"]) / cfg.num_eval_envs == pytest.approx(rows[-1]["eval_return"], abs=1e-6)
    # the rows' success share is JaxGCRL's episode_success_any of those episodes
    success = sum(r > 0 for r in res["returns"]["0"]) / cfg.num_eval_envs
    assert [r["eval_success_any"] for r in rows][-1] == pytest.approx(success)
    assert all(0.0 <= r["eval_success_any"] <= 1.0 for r in rows)
    assert cli.main(["eval", str(out), "--episodes", "3"]) == 2
    assert "replays its own deterministic evaluation" in capsys.readouterr().err


@pytest.mark.slow
def test_a_stopped_run_resumes_to_the_same_rows(cfg, cli_run, tmp_path):
    _, reference = cli_run
    out = tmp_path / "stopped"
    crl.train(cfg, "0", out, progress=False, plot=False, stop_after_epoch=1)
    result = crl.train(cfg, "0", out, progress=False, plot=False)
    assert result.resumed_from == 1
    assert strip_wall(result.rows) == strip_wall(reference)


@pytest.mark.slow
def test_vmapped_seeds_each_learn_their_own_critic(cfg, tmp_path):
    """Seeds 0 and 1 in one vmapped program: each seed's critic learns (accuracy ≥ 5/B, as one seed's
    must) and the two are separate runs, not one copied (their losses differ)."""
    result = crl.train(cfg, "0-1", tmp_path / "two", progress=False, plot=False)
    last = {r["seed"]: r for r in result.rows if r["env_steps"] == 8000}
    assert sorted(last) == [0, 1]
    for seed, row in last.items():
        assert row["accuracy"] >= 5 / cfg.batch_size, (seed, row["accuracy"])
        assert row["sgd_steps"] == 500 * cfg.grad_updates_per_step
    assert last[0]["critic_loss"] != last[1]["critic_loss"]


CRL = ("--task", "ant-goal", "--algo", "crl")


@pytest.mark.parametrize("args, text", [
    (("--task", "ant-goal", "--algo", "td3"), "goal-reaching tasks take the goal-conditioned trainer"),
    ((*CRL, "--repr", "sim"), "representation = 'sim' is invalid: must be one of none, sf2"),
    ((*CRL, "--logsumexp-penalty", "-1"), "logsumexp_penalty = -1.0 is invalid"),
    ((*CRL, "--contrastive-loss", "binary"),
     "contrastive_loss = 'binary' is invalid: must be one of ('fwd', 'bwd', 'sym')"),
    ((*CRL, "--batch-size", "1"), "batch_size = 1 is invalid"),
    ((*CRL, "--physics", "generalized"), "physics = 'generalized' is invalid: must be one of mjx, spring"),
    (("--task", "CheetahRun", "--physics", "spring"), "only ant-goal has the spring pipeline"),
    ((*CRL, "--max-replay-size", "8", "--min-replay-size", "0"), "must hold at least 2 steps of every env"),
    ((*CRL, "--flow-feature-norm", "ln"),
     "flow_feature_norm = 'ln' is invalid: must be one of ('none', 'l2')"),
    ((*CRL, "--repr", "none", "--flow-feature-norm", "l2"), "only --repr sf2 has a flow"),
])
def test_bad_input_is_refused_before_compiling(args, text, capsys, monkeypatch):
    monkeypatch.setattr(crl, "get_program", lambda cfg: pytest.fail("a program was built"))
    err = cli_error(cli.main, capsys, *args)
    assert text in err, err


def test_the_paper_preset_trains_the_backward_infonce(cfg, tmp_path):
    """`paper` gives JaxGCRL's train.sh's bwd, `quick` fwd; a folder written before the field existed trained
    fwd: a quick one resumes, a paper one is another run unless `--contrastive-loss fwd` is passed."""
    paper = make_config("paper", "ant-goal", algo="crl", representation="none")
    assert (paper.contrastive_loss, cfg.contrastive_loss) == ("bwd", "fwd")
    for name, now in (("quick", cfg), ("paper", paper)):
        old = {k: v for k, v in now.to_dict().items() if k != "contrastive_loss"}
        RunFolder(tmp_path / name).write_config({"config": old, "seeds": [0]})
    assert RunFolder(tmp_path / "quick").check_compatible(cfg.to_dict(), (0,)) is True
    with pytest.raises(RunFolderMismatch, match="contrastive_loss: 'fwd' .folder. vs 'bwd' .now."):
        RunFolder(tmp_path / "paper").check_compatible(paper.to_dict(), (0,))
    fwd = paper.replace(contrastive_loss="fwd")
    assert RunFolder(tmp_path / "paper").check_compatible(fwd.to_dict(), (0,)) is True
    for direction in lc.CONTRASTIVE_LOSSES:   # every loss the cores have is a config's choice
        assert crl.validate(paper.replace(contrastive_loss=direction)).contrastive_loss == direction


def test_the_program_steps_the_configs_physics(cfg, monkeypatch):
    """`physics` is the ant-goal pipeline the program builds (`antgoal.make`'s backend; training, a session's
    evaluation and `sf2-jax eval` all step `get_program(cfg)`'s); its choices are `antgoal.BACKENDS`."""
    assert set(configs.PHYSICS) == set(antgoal.BACKENDS)
    built = []

    def make(episode_length, backend):   # the sizes alone: building Brax's env is not what is tested
        built.append((episode_length, backend))
        return antgoal.GoalEnvSpec(None, antgoal.STATE_SIZE + 2, antgoal.STATE_SIZE, antgoal.GOAL_INDICES, 8,
                                   episode_length)

    monkeypatch.setattr(antgoal, "make", make)
    for physics in ("spring", "mjx"):
        crl.Program(crl.validate(cfg.replace(physics=physics)))
    assert built == [(cfg.episode_length, "spring"), (cfg.episode_length, "mjx")]


@pytest.mark.slow
def test_quick_crl_sf2_trains_the_flow_and_the_critic(tmp_path):
    """CRL+SF²: the critic learns as CRL's does (accuracy ≥ 5/B) while SF²'s flow loss on the shared φ falls
    from the first epoch to the second (the flow fits s′ better as φ, ζ and the statistics settle)."""
    cfg = make_config("quick", "ant-goal", algo="crl", representation="sf2")
    rows = crl.train(cfg, "0", tmp_path / "sf2", progress=False, plot=False).rows
    first, last = rows[1], rows[-1]
    assert last["accuracy"] >= 5 / cfg.batch_size, last["accuracy"]
    assert last["flow_loss"] < first["flow_loss"], (first["flow_loss"], last["flow_loss"])


class _NoPhysics:
    """An env stand-in whose reset gives one zero observation per key: the SGD step never steps it."""

    def reset(self, keys):
        return jnp.zeros((keys.shape[0], antgoal.STATE_SIZE + 2))


def _stub_physics(monkeypatch):
    """The ant-goal task's spec with `_NoPhysics` (a step of SGD needs no environment)."""
    monkeypatch.setattr(antgoal, "make", lambda episode_length, backend: antgoal.GoalEnvSpec(
        _NoPhysics(), antgoal.STATE_SIZE + 2, antgoal.STATE_SIZE, antgoal.GOAL_INDICES, 8, episode_length))


def _random_sample(cfg):
    """A minibatch of `cfg.batch_size` random transitions and the six keys split for it (k[5], not used
    here, is left for the step's noise)."""
    B, S, A = cfg.batch_size, antgoal.STATE_SIZE, 8
    k = jax.random.split(jax.random.PRNGKey(1), 6)
    sample = GoalSample(jax.random.normal(k[0], (B, S)), jax.random.uniform(k[1], (B, A), minval=-1),
                        jax.random.normal(k[2], (B, S)), jax.random.normal(k[3], (B, S)),
                        jax.random.uniform(k[4], (B, A), minval=-1), jnp.zeros((B,)))
    return sample, k


@pytest.mark.parametrize("shared", [True, False])
def test_the_flow_step_takes_phis_adam_state_of_the_config(shared, monkeypatch):
    """One SGD step of CRL+SF² advances φ's InfoNCE Adam state twice (InfoNCE, then the flow) where
    `shared_adam` (both presets: docs/crl.md, "φ's Adam state in the flow step"), else once each for it and
    φ's own flow state `sa_encoder:aux`; ζ's state once either way."""
    _stub_physics(monkeypatch)
    cfg = make_config("quick", "ant-goal", algo="crl", representation="sf2")
    assert cfg.shared_adam is True
    prog = crl.Program(crl.validate(cfg.replace(shared_adam=shared)))
    state = prog._init_one(jax.random.PRNGKey(0))
    sample, k = _random_sample(cfg)
    _, opt, _ = jax.jit(prog._sgd_step)(state.params, state.opt_state, sample, prog._noise(k[5])[1])
    counts = {g: int(optax.tree_utils.tree_get(s, "count")) for g, s in opt.items() if g != "log_alpha"}
    own = {} if shared else {"sa_encoder:aux": 1}
    assert counts == {"sa_encoder": 2 if shared else 1, "g_encoder": 1, "actor": 1, "zeta": 1, **own}


def test_flow_features_by_hand():
    """`flow_features`: "none" is φ; "l2" divides each row by its norm (3-4-5: (3, 4) → (0.6, 0.8)); a zero
    row stays zero (ε under the root, no NaN)."""
    phi = jnp.array([[3.0, 4.0], [0.0, 0.0], [-1.0, 0.0]])
    assert jnp.array_equal(crl.flow_features(phi, "none"), phi)
    want = jnp.array([[0.6, 0.8], [0.0, 0.0], [-1.0, 0.0]])
    assert jnp.allclose(crl.flow_features(phi, "l2"), want, rtol=0, atol=1e-6)


@pytest.mark.parametrize("norm", ["none", "l2"])
def test_the_l2_flow_sees_only_the_direction_of_phi(norm, monkeypatch):
    """One flow step of CRL+SF² with φ's and φ̄'s last layer (kernel and bias) scaled by c = 5, so that φ, φ̄
    become 5φ, 5φ̄: with `flow_feature_norm = "l2"` the flow is fed (5φ)/‖5φ‖ = φ/‖φ‖ and its loss is
    unchanged (float32, up to the ε under the root); with "none" it is fed 5φ and the loss changes."""
    _stub_physics(monkeypatch)
    cfg = make_config("quick", "ant-goal", algo="crl", representation="sf2")
    assert cfg.flow_feature_norm == "l2"   # the presets' (docs/crl.md); both are stepped below
    prog = crl.Program(crl.validate(cfg.replace(flow_feature_norm=norm)))
    state = prog._init_one(jax.random.PRNGKey(0))
    sample, k = _random_sample(cfg)
    noise = prog._noise(k[5])[1]
    # the targets differ from the online encoder, as after training (else φ̄′ = φ′ at any scale)
    params = {**state.params, "target_sa_encoder": jax.tree_util.tree_map(
        lambda x: 0.7 * x, state.params["target_sa_encoder"])}
    last = f"Dense_{len(cfg.hidden_sizes)}"

    def scaled(enc, c):
        return {**enc, last: jax.tree_util.tree_map(lambda x: c * x, enc[last])}

    big = {**params, "sa_encoder": scaled(params["sa_encoder"], 5.0),
           "target_sa_encoder": scaled(params["target_sa_encoder"], 5.0)}
    flow = jax.jit(lambda p: prog._flow_step(p, state.opt_state, sample, noise)[2]["flow_loss"])
    base, five = float(flow(params)), float(flow(big))
    if norm == "l2":
        assert five == pytest.approx(base, rel=1e-5)
    else:
        assert abs(five - base) > 0.01 * base, (base, five)

