"""The on-policy trainer (`--algo ppo` on MinAtar Breakout; small sizes, CPU): each representation learns
above the random policy; the same seeds give the same rows; vmapped seeds equal seeds one by one and seeds
in turn (`seed_loop = "map"`, also resuming a vmapped run; evaluation vmapped under both); evaluations
batched between checkpoints equal those of each epoch alone; kill-and-resume equals the uninterrupted run;
the NaN guard; `sf2-jax train` and `eval` (also under observation noise) through the CLI; bad input refused
before compiling (exit status 2). The mechanics run one tiny SF² w AE config (it has every part: the critic
on ψ, the flow and autoencoder losses, ψ's two Adam states, the targets), compiled once per seed count for
the whole module."""

from __future__ import annotations

import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("pgx", reason="the [minatar] extra: pip install \"packages/sf2-core-jax[minatar]\"")

from sf2_jax import cli  # noqa: E402
from sf2_jax.agents import make_config, minatar, onpolicy, trainer  # noqa: E402
from sf2_jax.agents.onpolicy import TrainingDiverged, train  # noqa: E402
from sf2_testing import KILL_POINTS, Killed, check_cli_eval, cli_args, kill_and_resume, strip_wall  # noqa: E402

TASK = "minatar-breakout"


def _seed_rows(rows, seed):
    return [r for r in strip_wall(rows) if r["seed"] == seed]


def _leaves(tree, index=None):
    return [np.asarray(x if index is None else x[index]) for x in jax.tree_util.tree_leaves(tree)]


def _assert_same(a, b, index_a=None, index_b=None):
    la, lb = _leaves(a, index_a), _leaves(b, index_b)
    assert len(la) == len(lb)
    for x, y in zip(la, lb):
        np.testing.assert_array_equal(x, y)


@pytest.fixture(scope="module")
def tiny():
    """SF² w AE, seconds per run: 4 envs × 8 steps per update, 2 epochs of 2 minibatches of 16 (4 SGD steps
    per update), 2 updates per epoch, 3 epochs; episodes truncated at 40 steps (training and evaluation);
    16-wide networks."""
    return make_config("quick", TASK, algo="ppo", representation="sf2-ae", overrides=dict(
        num_envs=4, rollout_length=8, minibatch_size=16, update_epochs=2, num_timesteps=4 * 8 * 2 * 3,
        num_evals=4, num_eval_envs=3, episode_length=40, feature_size=8, hidden_sizes=(16,),
        q_hidden_size=16, zeta_hidden_sizes=(8,), embedding_size=4))


@pytest.fixture(scope="module")
def reference(tiny, tmp_path_factory):
    """An uninterrupted single-seed run."""
    return train(tiny, (0,), tmp_path_factory.mktemp("ref"), progress=False)


@pytest.fixture(scope="module")
def both(tiny, tmp_path_factory):
    """Seeds 0 and 1 in one vmapped program."""
    return train(tiny, (0, 1), tmp_path_factory.mktemp("both"), progress=False)


def test_reference_run_folder(reference):
    run = reference.run
    conf = json.loads(run.config_path.read_text())
    assert conf["label"] == "PPO-Q+SF² w AE" and conf["schedule"]["sgd_steps_per_actor_step"] == 4
    rows = run.read_rows()
    assert [r["epoch"] for r in rows] == [0, 1, 2, 3]
    assert [r["env_steps"] for r in rows] == [0, 64, 128, 192]
    assert [r.get("sgd_steps") for r in rows] == [None, 8, 8, 8]
    for name in ("critic_loss", "q", "flow_loss", "loss_p", "loss_boot", "ae_loss", "bce_per_cell",
                 "actor_loss", "policy_loss", "entropy", "approx_kl", "clip_fraction", "train_return",
                 "train_episodes", "sps"):
        assert np.isfinite(rows[-1][name]), name
    assert sum(r["train_episodes"] for r in rows[1:]) > 0 and rows[-1]["eval_return_std"] >= 0
    state = reference.state
    assert set(state.opt_state) == {"actor", "psi", "q", "psi:aux", "zeta", "encoder", "decoder"}
    assert int(state.updates[0]) == 6 and int(state.env_steps[0]) == 192
    # the targets moved by EMA (τ = 0.02, τ_ζ = 0.05) towards ψ and ζ, which trained
    for target, online in (("target_psi", "psi"), ("target_zeta", "zeta")):
        t, o = _leaves(state.params[target]), _leaves(state.params[online])
        assert any(not np.array_equal(a, b) for a, b in zip(t, o))
    flat = np.load(run.final_dir / "params_seed0.npz")
    assert {"actor.head.dense_0.kernel", "encoder.torso.conv_0.kernel", "target_psi.head.dense_0.bias",
            "target_zeta.dense_0.kernel"} <= set(flat), sorted(flat)


def test_same_seed_same_rows(reference, tiny, tmp_path):
    again = train(tiny, (0,), tmp_path / "again", progress=False)
    assert strip_wall(again.rows) == strip_wall(reference.rows)
    _assert_same(again.state, reference.state)


def _assert_close_rows(a, b):
    assert [(r["epoch"], r["seed"], r["env_steps"]) for r in a] == [(r["epoch"], r["seed"], r["env_steps"])
                                                                    for r in b]
    for ra, rb in zip(a, b):
        assert set(ra) == set(rb)
        for k in ra:
            np.testing.assert_allclose(ra[k], rb[k], rtol=1e-4, atol=1e-5, err_msg=k)


def test_vmapped_seeds_equal_seeds_one_by_one(reference, both, tiny, tmp_path):
    """Seeds 0 and 1 in one vmapped program equal seed 0 alone and seed 1 alone: exactly across programs
    of >= 2 seeds ((0, 1) vs (2, 0)), up to float32 rounding against a one-seed program (no vmap: XLA
    orders some reductions differently; the off-policy trainer's test says more)."""
    swapped = train(tiny, (2, 0), tmp_path / "swapped", progress=False)
    one = train(tiny, (1,), tmp_path / "one", progress=False)
    assert _seed_rows(both.rows, 0) == _seed_rows(swapped.rows, 0)
    _assert_same(both.state, swapped.state, 0, 1)
    assert _seed_rows(both.rows, 0) != _seed_rows(both.rows, 1)   # the seeds really differ
    _assert_close_rows(_seed_rows(both.rows, 0), _seed_rows(reference.rows, 0))
    _assert_close_rows(_seed_rows(both.rows, 1), _seed_rows(one.rows, 1))
    for x, y in zip(_leaves(both.state.params, 1), _leaves(one.state.params, 0)):
        np.testing.assert_allclose(x, y, rtol=1e-4, atol=1e-5)


def test_seeds_by_lax_map_equal_vmapped_seeds(both, tiny, tmp_path):
    """`seed_loop = "map"` (the seeds one after another, `jax.lax.map`) trains seeds 0 and 1 as the vmapped
    program does, up to float32 rounding (each seed runs the same operations, batched or not, which XLA
    orders differently), in a folder of its own, whose config.json says "map". The rows take the file's
    tolerance for that rounding (`_assert_close_rows`; observed here within 6e-5 relative after 6 updates);
    the state's floats were within 3e-7 absolute (atol 1e-6), its integers (counters, keys) equal."""
    mapped = train(tiny.replace(seed_loop="map"), (0, 1), tmp_path / "map", progress=False)
    assert json.loads(mapped.run.config_path.read_text())["config"]["seed_loop"] == "map"
    _assert_close_rows(strip_wall(mapped.rows), strip_wall(both.rows))
    assert jax.tree_util.tree_structure(mapped.state) == jax.tree_util.tree_structure(both.state)
    for x, y in zip(_leaves(mapped.state), _leaves(both.state)):
        assert x.dtype == y.dtype and x.shape == y.shape
        if np.issubdtype(x.dtype, np.floating):
            np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-6)
        else:
            np.testing.assert_array_equal(x, y)


def test_a_vmapped_run_resumes_by_lax_map(both, tiny, tmp_path):
    """A run of vmapped seeds killed after its first checkpoint resumes with `seed_loop = "map"` (an
    execution field: `configs.EXECUTION_FIELDS`) and ends with the uninterrupted vmapped run's rows, up to the
    float32 rounding of `test_seeds_by_lax_map_equal_vmapped_seeds`; its config.json keeps "vmap", and the
    change is said and logged."""
    def hook(event, epoch):
        if (event, epoch) == ("train", 2):
            raise Killed

    out = tmp_path / "run"
    with pytest.raises(Killed):
        train(tiny, (0, 1), out, progress=False, hook=hook)
    resumed = train(tiny.replace(seed_loop="map"), (0, 1), out, progress=False)
    assert resumed.resumed_from == 1
    assert json.loads(resumed.run.config_path.read_text())["config"]["seed_loop"] == "vmap"
    assert "resumes with seed_loop = 'map'; it started with 'vmap'" in resumed.run.log_path.read_text()
    _assert_close_rows(strip_wall(resumed.run.read_rows()), strip_wall(both.rows))


def test_evaluation_vmaps_the_seeds_under_either_seed_loop(tiny):
    """Evaluation runs the policy alone on `num_eval_envs` envs a seed, which in turn would be latency-bound:
    under `seed_loop = "map"` its program is the vmapped one (the same jaxpr), while the epoch's is not (the
    seeds in turn, a `lax.map`); both programs return the same evaluation."""
    vmapped, mapped = onpolicy.Program(tiny), onpolicy.Program(tiny.replace(seed_loop="map"))
    seeds = (0, 1)
    state = vmapped.init(seeds)
    params = {g: state.params[g] for g in vmapped.acting}
    keys = trainer.eval_keys(seeds, 1)

    def jaxpr(program, name, *args, static=()):
        return str(jax.make_jaxpr(program._program(name, len(seeds), *static))(*args))

    static = (tiny.num_eval_envs, 0.0, tiny.deterministic_eval)
    assert jaxpr(mapped, "evaluate", params, keys, static=static) == jaxpr(
        vmapped, "evaluate", params, keys, static=static)
    assert jaxpr(mapped, "epoch", state) != jaxpr(vmapped, "epoch", state)
    np.testing.assert_array_equal(mapped.evaluate(state.params, seeds, 1),
                                  vmapped.evaluate(state.params, seeds, 1))


def test_evaluate_many_equals_evaluate_of_each(tiny):
    """`Program.evaluate_many` (the host loop's between checkpoints when `checkpoint_every` > 1) against the
    plain `evaluate` it replaces: three policies (scaled parameters) at three epochs in one program give each
    policy's `evaluate` at its epoch, up to float32 rounding (vmapping over the epochs adds a batch axis to
    the policy's products); the policies, and one policy's evaluations at two epochs, really differ
    (actions sampled, `deterministic_eval` off; 16 envs of 200 steps)."""
    cfg = tiny.replace(deterministic_eval=False, num_eval_envs=16, episode_length=200)
    program, seeds, epochs = onpolicy.Program(cfg), (0, 1), [4, 5, 6]
    acting = {g: program.init(seeds).params[g] for g in program.acting}
    policies = [jax.tree_util.tree_map(lambda x, s=s: x * s, acting) for s in (1.0, 4.0, 16.0)]
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *policies)
    many = np.asarray(program.evaluate_many(stacked, seeds, epochs))
    one = np.stack([np.asarray(program.evaluate(p, seeds, e)) for p, e in zip(policies, epochs)])
    other_keys = np.asarray(program.evaluate(policies[0], seeds, epochs[1]))
    assert many.shape == (3, 2, 16)
    np.testing.assert_allclose(many, one, rtol=1e-5, atol=1e-6)
    assert not np.array_equal(one[0], one[2]) and not np.array_equal(one[0], other_keys)


def test_batched_evaluation_writes_the_per_epoch_rows(both, tiny, tmp_path):
    """With `checkpoint_every = 2` the host loop evaluates epochs 1-2 in one program before checkpoint 2 and
    epoch 3 alone (padded to two epochs: the program compiles once) before the last: the per-epoch
    evaluation's rows (`both`), up to float32 rounding (`_assert_close_rows`), and the same final state
    (resuming between checkpoints is the host loop's, shared with the off-policy trainer's tests)."""
    assert tiny.checkpoint_every == 1   # `both` evaluates each epoch on its own
    cfg = tiny.replace(checkpoint_every=2)
    batched = train(cfg, (0, 1), tmp_path / "batched", progress=False)
    _assert_close_rows(strip_wall(batched.rows), strip_wall(both.rows))
    _assert_same(batched.state, both.state)
    key = ("evaluate_many", cfg.num_eval_envs, 0.0, cfg.deterministic_eval)
    assert onpolicy.get_program(cfg)._programs[key]._cache_size() == 1


@pytest.mark.parametrize("n_seeds", [1, 3])
def test_seed_map_by_lax_map_stacks_outputs_as_vmap(n_seeds):
    """`trainer._seed_map(..., "map")`: the outputs of `jax.vmap` (pytree, shapes, dtypes, values), an
    `in_axes` entry None passed whole to every seed, `fn`'s name kept (bench.hlo finds modules by it); an
    unknown loop is refused naming the valid ones."""
    def step(state, scale):
        return {"x": state["x"] * scale, "n": state["n"] + 1}, jnp.sum(state["x"])

    state = {"x": jnp.arange(n_seeds * 6, dtype=jnp.float32).reshape(n_seeds, 2, 3),
             "n": jnp.arange(n_seeds, dtype=jnp.int32)}
    scale = jnp.float32(0.5)
    want = jax.vmap(step, in_axes=(0, None))(state, scale)
    mapped = trainer._seed_map(step, (0, None), n_seeds, "map")
    assert mapped.__name__ == "step"
    got = jax.jit(mapped)(state, scale)
    assert jax.tree_util.tree_structure(got) == jax.tree_util.tree_structure(want)
    for x, y in zip(_leaves(got), _leaves(want)):
        assert x.dtype == y.dtype and x.shape == y.shape
        np.testing.assert_array_equal(x, y)
    with pytest.raises(ValueError, match="seed loop 'pmap' is invalid: must be one of vmap, map"):
        trainer._seed_map(step, (0, None), n_seeds, "pmap")


@pytest.mark.parametrize("kill,expected_resume", KILL_POINTS)
def test_kill_and_resume_equals_uninterrupted(reference, tiny, tmp_path, kill, expected_resume):
    """Killed at each of `KILL_POINTS` (a torn last metrics line too), the resumed run has exactly the
    uninterrupted run's rows and final state (parameters, Adam states, env states, keys)."""
    resumed = kill_and_resume(train, tiny, tmp_path / "killed", *kill, expected_resume)
    assert strip_wall(resumed.run.read_rows()) == strip_wall(reference.rows)
    _assert_same(resumed.state, reference.state)


def test_finished_run_is_not_retrained(reference, tiny):
    again = train(tiny, (0,), reference.run.path, progress=False)
    assert again.resumed_from == 3 and strip_wall(again.rows) == strip_wall(reference.rows)


def test_nan_stops_the_run_and_keeps_the_last_good_checkpoint(tiny, tmp_path, monkeypatch):
    """A NaN in the Q head at the start of epoch 3 makes the critic's loss non-finite at that epoch's first
    SGD step (16: epochs 1 and 2 hold SGD steps 0-15); the run stops naming it and keeps checkpoint 2."""
    program = onpolicy.get_program(tiny)
    real_epoch = program.epoch

    def poisoned_epoch(state, epoch):
        if epoch == 3:
            q = jax.tree_util.tree_map(lambda x: x * jnp.nan, state.params["q"])
            state = state._replace(params={**state.params, "q": q})
        return real_epoch(state, epoch)

    monkeypatch.setattr(program, "epoch", poisoned_epoch)
    with pytest.raises(TrainingDiverged) as err:
        train(tiny, (0,), tmp_path / "nan", progress=False)
    msg = str(err.value)
    assert "loss 'critic_loss' became NaN/inf at gradient step 16 (env step 160, epoch 3, seed 0)" in msg, msg
    assert "last good checkpoint (epoch 2) is kept" in msg, msg
    rows = [json.loads(line) for line in (tmp_path / "nan" / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [0, 1, 2]


def test_cli_trains_two_seeds_and_evaluates(both, tiny, tmp_path, capsys, monkeypatch):
    """`sf2-jax train --task minatar-breakout --algo ppo --repr sf2-ae --config quick --seeds 0-1` (with the
    tiny config's fields as flags) gives the API's rows; `sf2-jax eval` replays the last evaluation, acts
    on fresh envs with --episodes, and refuses --episodes 0 (`check_cli_eval`)."""
    monkeypatch.setenv("SF2_JAX_COMPILE_CACHE", "")
    out = tmp_path / "cli"
    args = cli_args(tiny, out)
    args[args.index("--seeds") + 1] = "0-1"
    assert cli.main(args) == 0
    assert "PPO-Q+SF² w AE" in capsys.readouterr().out
    rows = json.loads("[" + ",".join((out / "metrics.jsonl").read_text().splitlines()) + "]")
    assert strip_wall(rows) == strip_wall(both.rows)
    last = [r for r in rows if r["seed"] == 0][-1]
    check_cli_eval(cli.main, capsys, out, tiny.num_eval_envs, last["eval_return"])


def test_evaluation_under_observation_noise(reference, tmp_path, capsys, monkeypatch):
    """`eval --obs-noise` of a ppo run folder (paper App. C.2.2): std 0 is the plain evaluation; a std > 0
    changes what the policy sees (its own key: the sampled actions' and the games' draws stay the plain
    run's), reproducibly; several stds from one restore; `--save` writes obs_noise.json. Sampled actions
    on 32 fresh envs: the tiny greedy policy returns 0 whatever it sees."""
    from sf2_jax.agents.checkpoint import Checkpointer

    monkeypatch.setenv("SF2_JAX_COMPILE_CACHE", "")
    run = reference.run.path
    kw = dict(num_eval_envs=32, deterministic=False)
    plain = onpolicy.evaluate_checkpoint(run, **kw)
    assert plain["checkpoints"] == [2, 3] and plain["deterministic"] is False
    assert onpolicy.evaluate_checkpoint(run, obs_noise=0.0, **kw)["returns"] == plain["returns"]
    noisy = onpolicy.evaluate_checkpoint(run, obs_noise=1.0, **kw)
    assert noisy["returns"] != plain["returns"]
    assert onpolicy.evaluate_checkpoint(run, obs_noise=1.0, **kw)["returns"] == noisy["returns"]
    both = onpolicy.evaluate_checkpoint_noises(run, None, 32, False, (0.0, 1.0))
    assert [r["returns"] for r in both] == [plain["returns"], noisy["returns"]]
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    restored = []
    real_restore = Checkpointer.restore

    def counting_restore(self, epoch, *args, **kwargs):
        restored.append(epoch)
        return real_restore(self, epoch, *args, **kwargs)

    monkeypatch.setattr(Checkpointer, "restore", counting_restore)
    assert cli.main(["eval", str(copy), "--obs-noise", "0,1", "--checkpoints", "2", "--save"]) == 0
    assert restored == [3, 2] and (copy / "obs_noise.json").exists()
    assert "noise std" in capsys.readouterr().out


def _refuse(*args, **kwargs):
    raise AssertionError("a program was built: validation did not stop the bad input first")


@pytest.mark.parametrize("args,texts", [
    (["--task", "CartpoleBalance", "--algo", "ppo", "--repr", "none"],
     ["task 'CartpoleBalance' is a Playground DM Control task", "--algo ppo is the MinAtar tasks'"]),
    (["--task", TASK, "--algo", "td3", "--repr", "none"],
     ["task 'minatar-breakout' is a MinAtar task: MinAtar tasks take the on-policy trainer (--algo ppo)"]),
    (["--task", TASK, "--algo", "ppo", "--repr", "none", "--set", "minibatch_size=100"],
     ["minibatch_size = 100 is invalid: must divide the rollout's num_envs × rollout_length = 32 × 32 = "
      "1024"]),
    (["--task", TASK, "--algo", "ppo", "--repr", "none,sf2", "--critic", "v"],
     ["critic = 'v' is invalid: representation 'sf2' takes critic 'q'"]),
    (["--task", TASK, "--algo", "ppo", "--repr", "spr"],
     ["representation = 'spr' is invalid: must be one of none, sf2, sf2-ae"]),
    (["--task", "CartpoleBalance", "--algo", "td3", "--repr", "sf2-ae"],
     ["representation = 'sf2-ae' is invalid: must be one of none, sf2"]),
    (["--task", TASK, "--algo", "ppo", "--repr", "none", "--set", "shared_torso=true"],
     ["shared_torso = True is invalid: pgx's shared torso exists for algo 'ppo' with critic 'v' and "
      "representation 'none' only, found algo 'ppo', critic 'q'"]),
    (["--task", TASK, "--algo", "ppo", "--repr", "none", "--set", "seed_loop=pmap"],
     ["seed_loop = 'pmap' is invalid: must be one of vmap, map"]),
    (["--task", "CartpoleBalance", "--algo", "td3", "--repr", "none", "--set", "seed_loop=map"],
     ["seed_loop = 'map' is invalid: only the on-policy trainer (algo ppo, fpo) runs its seeds by "
      "jax.lax.map; algo 'td3' takes 'vmap' (valid for ppo, fpo: vmap, map)"]),
], ids=["ppo on Playground", "td3 on MinAtar", "minibatch", "sf2 with V", "off-policy repr", "ppo repr",
        "shared torso with Q", "seed loop", "seed loop off-policy"])
def test_bad_input_exits_2_before_compiling(args, texts, capsys, monkeypatch):
    """Refused with exit status 2, naming the problem, before a program of either trainer is built and
    before `--out` is created (`cli_error` points it at a folder that must not appear)."""
    from sf2_testing import cli_error

    monkeypatch.setattr(onpolicy, "get_program", _refuse)
    monkeypatch.setattr(trainer, "get_program", _refuse)
    err = cli_error(cli.main, capsys, *args)
    for text in texts:
        assert text in err, err
    if "ppo" in args:   # the on-policy trainer's registry has no baselines to install
        assert "sf2-baselines" not in err, err


def test_each_trainer_refuses_the_others_algo(tiny, tmp_path):
    from sf2_common.errors import ConfigError

    cfg = make_config("quick", "CartpoleBalance", algo="td3", representation="none")
    with pytest.raises(ConfigError, match="algo 'td3' is the off-policy trainer's"):
        train(cfg, (0,), tmp_path / "x", progress=False)
    with pytest.raises(ConfigError, match="algo 'ppo' is the on-policy trainer's"):
        trainer.train(tiny, (0,), tmp_path / "x", progress=False)
    assert not (tmp_path / "x").exists()


# ------------------------------------------------------------------------------------------- learning
RANDOM_EPISODES = 4096
K = 5   # standard errors of the difference between the trained and the random mean


@pytest.fixture(scope="module")
def random_policy():
    """The uniformly random policy's returns on the evaluation's protocol (fresh envs, one episode each,
    capped at the episode limit): (mean, standard deviation of one episode, max) over 4096 episodes."""
    env = minatar.make(TASK)
    n = RANDOM_EPISODES

    @jax.jit
    def run(key):
        k_reset, k_run = jax.random.split(key)

        def step(carry):
            state, ret, alive, t, k = carry
            k, k_act, k_env = jax.random.split(k, 3)
            action = jax.random.randint(k_act, (n,), 0, env.spec.num_actions)
            state, tr = env.step(state, action, k_env)
            alive_next = alive & ~(tr.terminal | tr.truncation)
            return state, ret + jnp.where(alive, tr.reward, 0.0), alive_next, t + 1, k

        carry = (env.reset(jax.random.split(k_reset, n)), jnp.zeros(n), jnp.ones(n, bool), 0, k_run)
        return jax.lax.while_loop(lambda c: jnp.any(c[2]) & (c[3] < env.spec.episode_length), step, carry)[1]

    returns = np.asarray(run(jax.random.PRNGKey(123)))
    return float(returns.mean()), float(returns.std()), float(returns.max())


@pytest.mark.slow
@pytest.mark.parametrize("representation,overrides", [
    ("none", {}), ("sf2", {}), ("sf2-ae", {}),
    ("none", {"critic": "v", "shared_torso": True}),   # PPO with pgx's one network and joint step
], ids=["none", "sf2", "sf2-ae", "pgx-shared-torso"])
def test_quick_preset_learns_breakout(representation, overrides, random_policy, tmp_path):
    """The `quick` preset itself (keys are split per update, so this is the start of `sf2-jax train
    --config quick`), cut to 40 updates (40,960 env steps; 15-50 s of training on a 2-core CPU), beats the
    random policy by K = 5 standard errors of the difference of the two means: the trained mean over its
    64 greedy episodes minus the random mean over 4096 episodes, each episode with the random policy's
    standard deviation (under "no better than random", the trained mean's spread too). The random policy
    returns 0.38 ± 0.64 (at most 5), so the threshold is 0.79; seeds 0-2 of `none` reach 3.2-3.3, of PPO
    with pgx's shared torso (critic "v") 2.8-3.6 (~13 s with its compilation)."""
    mean, std, _ = random_policy
    updates = 40
    cfg = make_config("quick", TASK, algo="ppo", representation=representation,
                      overrides=dict(num_timesteps=updates * 1024, num_evals=2, **overrides))
    threshold = mean + K * std * np.sqrt(1 / cfg.num_eval_envs + 1 / RANDOM_EPISODES)
    result = train(cfg, (0,), tmp_path / representation, progress=False, plot=False)
    final = result.rows[-1]
    assert final["env_steps"] == updates * cfg.num_envs * cfg.rollout_length
    assert final["eval_return"] > threshold, (final["eval_return"], threshold, mean, std)
