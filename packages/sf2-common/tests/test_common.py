"""sf2_common without a framework: config parsing and validation, the representation registry (entry
points, the unknown-name message), run folders, the NaN guard's message, pooled curves and tables.

Playground is not needed: the task list is replaced by a fixed one where a test validates a config.
"""

from __future__ import annotations

import json
import sys
from importlib import metadata

import numpy as np
import pytest
from sf2_common import cli
from sf2_common.agents import configs, hostloop, plotting, registry, tasks
from sf2_common.agents.runfolder import RunFolder, RunFolderError, RunFolderMismatch
from sf2_common.errors import ConfigError


class _Rep:
    """A stand-in representation class (the registry only reads `name`, `label`, `supported_algos`)."""

    name = "fake"
    label = "Fake"
    supported_algos = ("sac",)


@pytest.fixture
def known_tasks(monkeypatch):
    known = dict.fromkeys(("CartpoleBalance", "PendulumSwingup"), "playground")
    monkeypatch.setattr(tasks, "playground_tasks", lambda: known)


@pytest.fixture
def reg():
    """A registry of a group nothing is installed under, holding `none` and `fake`."""
    r = registry.Registry("nothing-installed-under-this-group")
    none = type("NoRep", (), {"name": "none", "label": "", "supported_algos": ("td3", "sac")})
    r.register(none)
    r.register(_Rep)
    return r


# ------------------------------------------------------------------------------------------- registry
def test_registry_unknown_name_lists_valid_ones_and_the_baselines_install(reg):
    assert reg.names() == ("none", "fake")
    with pytest.raises(ConfigError) as err:
        reg.get("sim")
    msg = str(err.value)
    assert "unknown representation 'sim'" in msg and "must be one of none, fake" in msg
    assert "sim, simlap, spr" in msg and registry.INSTALL_BASELINES in msg
    assert reg.label("sim") == "sim" and reg.label("fake") == "Fake"
    with pytest.raises(ValueError, match="name is empty"):
        reg.register(type("Nameless", (), {"name": ""}))


def test_registry_loads_entry_points_on_first_use(reg, monkeypatch):
    ep = metadata.EntryPoint(name="late", value="sf2_common.agents.registry:Registry", group=reg.group)
    monkeypatch.setattr(reg, "_entry_points", {"late": ep, "fake": ep})
    assert reg.names() == ("none", "fake", "late")          # listed, not imported
    assert reg.get("late") is registry.Registry and reg.get("fake") is _Rep   # registered names win
    broken = metadata.EntryPoint(name="broken", value="no_such_module_xyz:Cls", group=reg.group)
    reg._entry_points["broken"] = broken
    with pytest.raises(ConfigError, match="'broken'.*could not be imported"):
        reg.get("broken")


# ------------------------------------------------------------------------------------------- configs
def test_validate_checks_the_representation_against_the_registry(reg, known_tasks):
    cfg = configs.make_config("quick", "CartpoleBalance", algo="sac", representation="fake")
    assert configs.validate(cfg, "0-1", reg) is cfg
    with pytest.raises(ConfigError, match="algo 'td3' with representation 'fake' does not exist; valid "
                       "combinations: td3\\+none, sac\\+none, sac\\+fake"):
        configs.validate(cfg.replace(algo="td3"), (0,), reg)
    with pytest.raises(ConfigError, match="representation = 'spr' is invalid: must be one of none, fake"):
        configs.validate(cfg.replace(representation="spr"), (0,), reg)
    with pytest.raises(ConfigError, match="unknown task 'Cartpole'.*Did you mean CartpoleBalance"):
        configs.make_config("quick", "Cartpole")


def test_spr_augmentation_std_is_checked_and_older_run_folders_keep_resuming(tmp_path, reg, known_tasks):
    """`spr_augmentation_std` (σ of SPR's augmentation, paper App. B.1) must be a finite number >= 0; a run
    folder written before the field existed trained with its default (then a module constant), so it
    holds the same run as a config at that default, and a different run than one at another σ."""
    cfg = configs.make_config("quick", "CartpoleBalance", algo="sac", representation="fake")
    for bad in (-0.05, float("nan"), True):
        with pytest.raises(ConfigError, match=f"spr_augmentation_std = {bad!r} is invalid"):
            configs.validate(cfg.replace(spr_augmentation_std=bad), (0,), reg)
    run = RunFolder(tmp_path / "old")
    # written before spr_augmentation_std and the PPO fields existed
    old = {k: v for k, v in cfg.to_dict().items()
           if k != "spr_augmentation_std" and k not in configs.PPO_FIELDS}
    run.write_config({"config": old, "seeds": [0]})
    assert configs.ADDED_FIELDS == {"spr_augmentation_std": 0.05, "shared_adam": True,
                                    "aux_steps_per_sgd_step": 1, "rollout_length": 128,
                                    "update_epochs": 3, "minibatch_size": 4096, "clip_eps": 0.2,
                                    "entropy_coef": 0.01, "value_coef": 0.5, "max_grad_norm": 0.5,
                                    "td_lambda": 0.95, "critic": "q", "advantage_refresh": "rollout",
                                    "shared_torso": False, "logsumexp_penalty": 0.1,
                                    "contrastive_loss": "fwd", "flow_feature_norm": "none", "fpo_samples": 8,
                                    "fpo_flow_steps": 10, "fpo_value_samples": 8, "fpo_log_ratio_clip": 20.0,
                                    "physics": "mjx", "seed_loop": "vmap"}
    assert cfg.spr_augmentation_std == 0.05
    assert run.check_compatible(cfg.to_dict(), (0,)) is True
    with pytest.raises(RunFolderMismatch, match="spr_augmentation_std: 0.05 \\(folder\\) vs 0.1 \\(now\\)"):
        run.check_compatible(cfg.replace(spr_augmentation_std=0.1).to_dict(), (0,))


def test_aux_steps_per_sgd_step_is_checked_and_older_run_folders_keep_resuming(tmp_path, reg, known_tasks):
    """`aux_steps_per_sgd_step` (representation steps per SGD step, paper Figure 9 left): an int >= 1; above
    1 only for td3/sac with a representation that has a loss of its own (`aux_groups`), the message naming
    those; a run folder written before the field trained with one such step, so it resumes at 1 only."""
    flow = type("FlowRep", (), {"name": "flow", "label": "Flow", "supported_algos": ("td3", "sac"),
                                "aux_groups": ("psi", "zeta")})
    reg.register(flow)
    cfg = configs.make_config("quick", "CartpoleBalance", algo="sac", representation="flow")
    assert cfg.aux_steps_per_sgd_step == 1 == configs.ADDED_FIELDS["aux_steps_per_sgd_step"]
    for k in (2, 8):
        assert configs.validate(cfg.replace(aux_steps_per_sgd_step=k), (0,), reg).aux_steps_per_sgd_step == k
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ConfigError, match=f"aux_steps_per_sgd_step = {bad!r} is invalid: must be an int "
                           f">= 1"):
            configs.validate(cfg.replace(aux_steps_per_sgd_step=bad), (0,), reg)
    for rep in ("none", "fake"):   # no aux_groups: nothing to repeat
        with pytest.raises(ConfigError, match=f"aux_steps_per_sgd_step = 2 is invalid: must be 1 with "
                           f"representation '{rep}', which has no loss of its own to repeat; representations "
                           f"that take more: flow$"):
            configs.validate(cfg.replace(representation=rep, aux_steps_per_sgd_step=2), (0,), reg)
    assert configs.parse_overrides(["aux_steps_per_sgd_step=4"]) == {"aux_steps_per_sgd_step": 4}
    assert cfg.sf2_config(3, 1).aux_steps_per_sgd_step == 1
    with pytest.raises(ConfigError, match="SF2Config.aux_steps_per_sgd_step = 0 is invalid"):
        cfg.replace(aux_steps_per_sgd_step=0).sf2_config(3, 1)
    run = RunFolder(tmp_path / "old")
    old = {k: v for k, v in cfg.to_dict().items() if k != "aux_steps_per_sgd_step"}
    run.write_config({"config": old, "seeds": [0]})
    assert run.check_compatible(cfg.to_dict(), (0,)) is True
    with pytest.raises(RunFolderMismatch, match="aux_steps_per_sgd_step: 1 \\(folder\\) vs 2 \\(now\\)"):
        run.check_compatible(cfg.replace(aux_steps_per_sgd_step=2).to_dict(), (0,))


def test_physics_is_mjx_except_ant_goals_spring(reg, monkeypatch):
    """`physics`: the CRL presets give ant-goal Brax's spring pipeline (JaxGCRL's), every other family MJX
    (MinAtar: unread); "spring" on any other task, or an unknown pipeline, is refused naming the choices."""
    monkeypatch.setattr(tasks, "playground_tasks", lambda: {"CheetahRun": "playground"})
    monkeypatch.setattr(tasks, "check_installed", lambda task: None)   # pgx need not be installed here
    for preset in ("paper", "quick"):
        assert configs.make_config(preset, "ant-goal", algo="crl", representation="none").physics == "spring"
        assert configs.make_config(preset, "CheetahRun", algo="td3").physics == "mjx"
        assert configs.make_config(preset, "minatar-breakout", algo="ppo", representation="none").physics \
            == "mjx"
    assert configs.TrainConfig.physics == configs.ADDED_FIELDS["physics"] == "mjx"   # older folders read so
    cfg = configs.make_config("quick", "CheetahRun", algo="sac", representation="fake")
    assert configs.validate(cfg, (0,), reg) is cfg
    for task, algo in (("CheetahRun", "sac"), ("minatar-breakout", "ppo")):
        with pytest.raises(ConfigError, match=f"physics = 'spring' is invalid: only ant-goal has the spring "
                           f"pipeline; task '{task}' takes physics = 'mjx' \\(valid for ant-goal: mjx, "
                           f"spring\\)"):
            configs.validate(cfg.replace(task=task, algo=algo, physics="spring"), (0,), reg)
    with pytest.raises(ConfigError, match="physics = 'generalized' is invalid: must be one of mjx, spring"):
        configs.validate(cfg.replace(physics="generalized"), (0,), reg)
    assert configs.parse_overrides(["physics=mjx"]) == {"physics": "mjx"}


def test_seed_loop_is_vmap_unless_the_onpolicy_trainer_takes_map(tmp_path, reg, monkeypatch):
    """`seed_loop`: "vmap" in every preset and in a run folder written before the field (its seeds were
    vmapped); "map" valid for the on-policy algos only; anything else refused naming the choices; a folder
    resumes under either loop, but not under another value of a field that changes the run."""
    monkeypatch.setattr(tasks, "check_installed", lambda task: None)   # pgx need not be installed here
    monkeypatch.setattr(tasks, "playground_tasks", lambda: {"CartpoleBalance": "playground"})
    ppo = configs.make_config("quick", "minatar-breakout", algo="ppo", representation="none")
    sac = configs.make_config("quick", "CartpoleBalance", algo="sac", representation="fake")
    assert ppo.seed_loop == sac.seed_loop == configs.ADDED_FIELDS["seed_loop"] == "vmap"
    assert configs.validate(ppo.replace(seed_loop="map"), (0,), _ppo_reg()).seed_loop == "map"
    assert configs.parse_overrides(["seed_loop=map"]) == {"seed_loop": "map"}
    for cfg, r in ((ppo, _ppo_reg()), (sac, reg)):
        with pytest.raises(ConfigError, match="seed_loop = 'pmap' is invalid: must be one of vmap, map"):
            configs.validate(cfg.replace(seed_loop="pmap"), (0,), r)
    with pytest.raises(ConfigError, match="seed_loop = 'map' is invalid: only the on-policy trainer \\(algo "
                       "ppo, fpo\\) runs its seeds by jax.lax.map; algo 'sac' takes 'vmap'"):
        configs.validate(sac.replace(seed_loop="map"), (0,), reg)
    run = RunFolder(tmp_path / "old")
    run.write_config({"config": {k: v for k, v in ppo.to_dict().items() if k != "seed_loop"}, "seeds": [0]})
    assert run.check_compatible(ppo.to_dict(), (0,)) is True
    # how the seeds run is no part of what the run computes (configs.EXECUTION_FIELDS): either resumes it
    assert configs.EXECUTION_FIELDS == ("seed_loop",)
    assert run.check_compatible(ppo.replace(seed_loop="map").to_dict(), (0,)) is True
    with pytest.raises(RunFolderMismatch,
                       match="differences: clip_eps: 0.2 \\(folder\\) vs 0.3 \\(now\\)\\. Use another"):
        run.check_compatible(ppo.replace(seed_loop="map", clip_eps=0.3).to_dict(), (0,))


def test_crl_sf2_shares_phis_adam_state_between_infonce_and_flow(monkeypatch):
    """CRL+SF²'s φ steps InfoNCE and the flow loss with one Adam state in both presets (docs/crl.md, "the SF²
    losses": with a state of its own the flow's bootstrap term diverges on spring); a folder trained with its
    own state keeps it, and one written before the field (the shared state) resumes as it is."""
    monkeypatch.setattr(tasks, "check_installed", lambda task: None)
    for preset in ("paper", "quick"):
        assert configs.make_config(preset, "ant-goal", algo="crl", representation="sf2").shared_adam is True
    now = configs.make_config("paper", "ant-goal", algo="crl", representation="sf2")
    own = now.replace(shared_adam=False).to_dict()
    assert configs.superseded_values(own, now.to_dict()) == {"shared_adam": False}
    before = {k: v for k, v in now.to_dict().items() if k != "shared_adam"}
    assert configs.superseded_values({**before, "shared_adam": configs.ADDED_FIELDS["shared_adam"]},
                                     now.to_dict()) == {}


def test_crl_sf2_feeds_its_flow_the_direction_of_phi(monkeypatch):
    """CRL+SF²'s flow takes φ/‖φ‖ in both presets (`REPRESENTATION_VALUES`; docs/crl.md) and CRL, which has no
    flow, keeps "none"; a folder trained with φ as it is keeps "none", one written before the field too."""
    monkeypatch.setattr(tasks, "check_installed", lambda task: None)
    for preset in ("paper", "quick"):
        sf2 = configs.make_config(preset, "ant-goal", algo="crl", representation="sf2")
        assert sf2.flow_feature_norm == "l2"
        assert configs.make_config(preset, "ant-goal", algo="crl", representation="none").flow_feature_norm \
            == "none"
    now = configs.make_config("paper", "ant-goal", algo="crl", representation="sf2")
    raw = now.replace(flow_feature_norm="none").to_dict()
    assert configs.superseded_values(raw, now.to_dict()) == {"flow_feature_norm": "none"}
    before = {k: v for k, v in now.to_dict().items() if k != "flow_feature_norm"}
    added = configs.ADDED_FIELDS["flow_feature_norm"]
    assert configs.superseded_values({**before, "flow_feature_norm": added}, now.to_dict()) \
        == {"flow_feature_norm": "none"}
    # an override back to φ as it is stays what the user asked for
    assert configs.make_config("paper", "ant-goal", algo="crl", representation="sf2",
                               overrides={"flow_feature_norm": "none"}).flow_feature_norm == "none"


def test_crl_sf2_takes_the_narrow_zeta_in_the_paper_preset(monkeypatch):
    """The `paper` preset's CRL+SF² has ζ (128, 64) (`REPRESENTATION_VALUES`: its paired study did not find
    the encoders' 256 × 256 better; docs/decisions/crl-sf2-zeta-width.md), CRL and `quick` keep theirs; a
    folder trained with 256 × 256 keeps it (config.json holds lists), any other width is no older value."""
    monkeypatch.setattr(tasks, "check_installed", lambda task: None)
    now = configs.make_config("paper", "ant-goal", algo="crl", representation="sf2")
    assert now.zeta_hidden_sizes == (128, 64)
    assert configs.make_config("paper", "ant-goal", algo="crl", representation="none").zeta_hidden_sizes \
        == configs.CRL_VALUES["paper"]["zeta_hidden_sizes"] == (256, 256)
    assert configs.make_config("quick", "ant-goal", algo="crl", representation="sf2").zeta_hidden_sizes \
        == configs.CRL_VALUES["quick"]["zeta_hidden_sizes"]
    wide = now.replace(zeta_hidden_sizes=(256, 256)).to_dict()
    assert wide["zeta_hidden_sizes"] == [256, 256]
    assert configs.superseded_values(wide, now.to_dict()) == {"zeta_hidden_sizes": [256, 256]}
    other = now.replace(zeta_hidden_sizes=(128, 128)).to_dict()
    assert configs.superseded_values(other, now.to_dict()) == {}
    assert configs.make_config("paper", "ant-goal", algo="crl", representation="sf2",
                               overrides={"zeta_hidden_sizes": "256,256"}).zeta_hidden_sizes == (256, 256)


def _ppo_reg():
    """A registry whose `none` takes ppo (the on-policy trainer's representations are the cores')."""
    r = registry.Registry("nothing-installed-under-this-group", baselines=())
    r.register(type("NoRep", (), {"name": "none", "label": "", "supported_algos": ("ppo",)}))
    return r


def test_ppo_paper_preset_is_pgx_example_with_the_papers_discount(known_tasks):
    """`paper` for a MinAtar game (docs/minatar.md): pgx's PPO (4096 envs × 128 steps, 3 epochs of
    minibatches of 4096, Adam 3e-4 with ε 1e-5, grad clip 0.5, clip 0.2, entropy 0.01, value 0.5, λ 0.95),
    γ = γ_su = 0.9, 20M env steps in 39 updates with an evaluation of 128 greedy episodes (capped at
    10,000 steps) after each, ψ's own Adam state; the off-policy presets keep their values."""
    cfg = configs.make_config("paper", "minatar-breakout", algo="ppo", representation="none")
    got = {k: getattr(cfg, k) for k in (
        "num_envs", "rollout_length", "update_epochs", "minibatch_size", "learning_rate", "adam_eps",
        "max_grad_norm", "clip_eps", "entropy_coef", "value_coef", "td_lambda", "discount", "gamma_su",
        "num_timesteps", "num_evals", "num_eval_envs", "deterministic_eval", "episode_length", "shared_adam",
        "critic", "feature_size", "hidden_sizes", "zeta_hidden_sizes", "action_repeat")}
    assert got == dict(num_envs=4096, rollout_length=128, update_epochs=3, minibatch_size=4096,
                       learning_rate=3e-4, adam_eps=1e-5, max_grad_norm=0.5, clip_eps=0.2, entropy_coef=0.01,
                       value_coef=0.5, td_lambda=0.95, discount=0.9, gamma_su=0.9, num_timesteps=20_000_000,
                       num_evals=40, num_eval_envs=128, deterministic_eval=True, episode_length=10_000,
                       shared_adam=False, critic="q", feature_size=256, hidden_sizes=(256, 256),
                       zeta_hidden_sizes=(64, 64), action_repeat=1)
    s = configs.schedule(cfg)
    # 524,288 env steps per update, 3 × 128 SGD steps each; ceil(20M / 524,288) = 39 updates, one per epoch
    assert (s.env_steps_per_actor_step, s.sgd_steps_per_actor_step, s.prefill_actor_steps, s.num_epochs,
            s.actor_steps_per_epoch, s.eval_actor_steps) == (524_288, 384, 0, 39, 1, 10_000)
    assert s.total_env_steps == 39 * 524_288
    for preset in ("paper", "quick"):
        off = configs.make_config(preset, "PendulumSwingup", algo="sac")
        assert off.episode_length == 1000 and {k: getattr(off, k) for k in configs.PPO_FIELDS} == {
            k: configs.ADDED_FIELDS[k] for k in configs.PPO_FIELDS}
        assert configs.schedule(off).sgd_steps_per_actor_step == off.grad_updates_per_step


def test_ppo_quick_preset_and_its_schedule():
    cfg = configs.make_config("quick", "minatar-breakout", algo="ppo", representation="none")
    assert {k: getattr(cfg, k) for k in configs.PPO_VALUES["quick"]} == configs.PPO_VALUES["quick"]
    s = configs.schedule(cfg)
    batch = cfg.num_envs * cfg.rollout_length
    assert s.env_steps_per_actor_step == batch and s.prefill_actor_steps == 0
    assert s.sgd_steps_per_actor_step == cfg.update_epochs * batch // cfg.minibatch_size
    assert s.num_epochs == cfg.num_evals - 1 and s.total_env_steps >= cfg.num_timesteps
    assert s.env_steps_after(s.num_epochs) == s.total_env_steps


@pytest.mark.parametrize("timesteps,evals,expected", [
    (20_000_000, 40, (39, 1)),        # the paper preset: an evaluation after each of 39 updates
    (5_000_000, 40, (10, 1)),         # 10 updates: 10 epochs, not 39 epochs of one update each (20.4M)
    (50 * 524_288, 40, (25, 2)),      # 50 updates: 25 epochs of 2, not 39 of 2 (78 updates)
    (11 * 524_288, 11, (6, 2)),       # 11 updates over at most 10 epochs: 6 of 2 (one update more)
])
def test_ppo_schedule_keeps_the_budget(timesteps, evals, expected):
    """With updates of 524,288 env steps `num_evals` is an upper bound: the epochs split the updates
    evenly and the budget is rounded up by less than one epoch's updates."""
    cfg = configs.TrainConfig(task="minatar-breakout", algo="ppo", num_envs=4096, rollout_length=128,
                              num_evals=evals, num_timesteps=timesteps)
    s = configs.schedule(cfg)
    updates = -(-timesteps // 524_288)
    assert (s.num_epochs, s.actor_steps_per_epoch) == expected
    assert updates <= s.total_env_steps // 524_288 < updates + s.actor_steps_per_epoch


@pytest.mark.parametrize("changes,text", [
    (dict(minibatch_size=300), "minibatch_size = 300 is invalid: must divide the rollout's num_envs × "
                               "rollout_length = 32 × 32 = 1024 transitions"),
    (dict(minibatch_size=2048), "minibatch_size = 2048 is invalid: must divide"),
    (dict(rollout_length=0), "rollout_length = 0 is invalid: must be an int >= 1"),
    (dict(update_epochs=1.5), "update_epochs = 1.5 is invalid: must be an int >= 1"),
    (dict(clip_eps=0.0), "clip_eps = 0.0 is invalid: must satisfy 0 < clip_eps <= 1"),
    (dict(td_lambda=1.5), "td_lambda = 1.5 is invalid: must satisfy 0 <= td_lambda <= 1"),
    (dict(entropy_coef=-0.01), "entropy_coef = -0.01 is invalid: must be a finite number >= 0"),
    (dict(value_coef=0), "value_coef = 0 is invalid: must be a finite number > 0"),
    (dict(max_grad_norm=float("inf")), "max_grad_norm = inf is invalid: must be a finite number > 0"),
    (dict(critic="a"), "critic = 'a' is invalid: must be 'q' (Q(s, a) with λ-returns: PPO-Q) or 'v'"),
    (dict(action_repeat=2), "action_repeat = 2 is invalid: must be 1"),
], ids=lambda v: str(v)[:40])
def test_ppo_fields_are_checked_before_anything_is_built(changes, text, monkeypatch):
    # this package's tests run without pgx (tox's `common` env): test_tasks.py tests the installation check
    monkeypatch.setattr(configs.tasks, "check_installed", lambda task: None)
    cfg = configs.make_config("quick", "minatar-breakout", algo="ppo", representation="none",
                              overrides=changes)
    with pytest.raises(ConfigError) as err:
        configs.validate(cfg, (0,), _ppo_reg())
    assert f"config field {text}" in str(err.value), str(err.value)
    assert configs.validate(configs.make_config("quick", "minatar-breakout", algo="ppo",
                                                representation="none"), (0,), _ppo_reg())


def test_an_override_the_algo_never_reads_is_refused_naming_its_readers(known_tasks, monkeypatch):
    """`--set clip_eps=0.1` on TD3, `batch_size` on PPO, `fpo_samples` on PPO and the like: each refused,
    naming the algos that read the field and the algo's own such fields. The same fields on the algos that
    read them pass; so do overrides that leave such a field's value as it was (a whole config passed back as
    flags), and the presets' values (the replay sizes are set for every algo)."""
    monkeypatch.setattr(configs.tasks, "check_installed", lambda task: None)
    refused = [("CartpoleBalance", "td3", "clip_eps", 0.1, "ppo, fpo"),
               ("minatar-breakout", "ppo", "batch_size", 64, "td3, sac, crl"),
               ("minatar-breakout", "ppo", "fpo_samples", 2, "fpo"),
               ("CartpoleBalance", "sac", "noise_clip", 0.1, "td3"),
               ("ant-goal", "crl", "rollout_length", 8, "ppo, fpo"),
               ("CartpoleBalance", "td3", "init_log_alpha", -2.0, "sac, crl")]
    for task, algo, name, value, readers in refused:
        with pytest.raises(ConfigError) as err:
            configs.make_config("quick", task, algo=algo, representation="none", overrides={name: str(value)})
        text = str(err.value)
        assert (f"config field {name} = {value!r} would change nothing but the run's config.json: "
                f"only --algo {readers} read it, not --algo {algo}") in text, text
        own = sorted(f for f, by in configs.READ_BY.items() if algo in by)
        assert text.endswith(f"--algo {algo}'s: {', '.join(own)})"), text
        unchanged = configs.make_config("quick", task, algo=algo, representation="none")
        assert configs.make_config("quick", task, algo=algo, representation="none",
                                   overrides={name: getattr(unchanged, name)}) == unchanged
    accepted = [("CartpoleBalance", "td3", dict(noise_clip=0.4, batch_size=64, policy_delay=3)),
                ("CartpoleBalance", "sac", dict(init_log_alpha=-1.0, policy_delay=1)),
                ("minatar-breakout", "ppo", dict(clip_eps=0.1, seed_loop="map")),
                ("CartpoleBalance", "fpo", dict(fpo_samples=4, clip_eps=0.1)),
                ("ant-goal", "crl", dict(batch_size=32, logsumexp_penalty=0.0, init_log_alpha=-1.0))]
    for task, algo, overrides in accepted:
        cfg = configs.make_config("quick", task, algo=algo, representation="none", overrides=overrides)
        assert {name: getattr(cfg, name) for name in overrides} == overrides


def test_parsing_follows_the_field_types():
    assert configs.parse_overrides(["batch_size=1_024", "hidden_sizes=(32, 16)", "layer_norm=off",
                                    "tau=0.5", "integrator= euler"]) == dict(
        batch_size=1024, hidden_sizes=(32, 16), layer_norm=False, tau=0.5, integrator="euler")
    with pytest.raises(ConfigError, match="did you mean 'batch_size'"):
        configs.parse_value("batch-size", "3")
    with pytest.raises(ConfigError, match="batch_size = '1.5' is invalid: expected an integer"):
        configs.parse_value("batch_size", "1.5")
    assert configs.parse_seeds("0-2,9") == (0, 1, 2, 9) and configs.parse_seeds([4, 2]) == (4, 2)
    cfg = configs.TrainConfig(hidden_sizes=(8,))
    assert configs.TrainConfig.from_dict(json.loads(cfg.to_json())) == cfg
    with pytest.raises(ConfigError, match="unknown config fields \\['nope'\\]"):
        configs.TrainConfig.from_dict({"nope": 1})


def test_a_subclass_adds_fields_that_parse_and_round_trip():
    """How sf2_torch adds its run fields: a frozen subclass, passed as `config_class`."""
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class WithDevice(configs.TrainConfig):
        device: str = "auto"

    assert configs.parse_overrides(["device=cpu"], WithDevice) == {"device": "cpu"}
    with pytest.raises(ConfigError, match="unknown config field 'device'"):
        configs.parse_overrides(["device=cpu"])
    cfg = WithDevice(device="cpu")
    assert type(cfg.replace(batch_size=3)) is WithDevice and WithDevice.from_dict(cfg.to_dict()) == cfg


def test_schedule_counts_env_steps_after_action_repeat():
    cfg = configs.TrainConfig(num_timesteps=1000, num_envs=4, action_repeat=2, num_evals=3,
                              min_replay_size=10)
    s = configs.schedule(cfg)
    # 8 env steps per actor step; ceil(10 / 4) = 3 prefill actor steps; 125 actor steps in 2 epochs of 63
    assert (s.env_steps_per_actor_step, s.prefill_actor_steps, s.num_epochs, s.actor_steps_per_epoch) == (
        8, 3, 2, 63)
    assert s.total_env_steps == 2 * 63 * 8 and s.grad_steps_before(5) == 2


# ------------------------------------------------------------------------------------------- run folder
def test_run_folder_rows_survive_a_torn_line_and_clear_removes_only_the_run(tmp_path):
    run = RunFolder(tmp_path / "r")
    assert run.check_compatible({"a": 1}, (0,)) is False
    run.write_config({"config": {"a": 1}, "seeds": [0]})
    run.append_rows([{"epoch": 0, "seed": 0}, {"epoch": 1, "seed": 0}])
    with open(run.metrics_path, "a") as f:
        f.write('{"epoch": 2, "se')                           # a kill mid-write
    assert [r["epoch"] for r in run.read_rows()] == [0, 1]
    assert [r["epoch"] for r in run.truncate_rows(0)] == [0]
    with pytest.raises(RunFolderMismatch, match="a: 1 \\(folder\\) vs 2 \\(now\\)"):
        run.check_compatible({"a": 2}, (0,))
    (run.path / "notes.txt").write_text("mine")
    run.checkpoint_dir.mkdir()
    run.clear()
    assert sorted(p.name for p in run.path.iterdir()) == ["notes.txt"]


# ------------------------------------------------------------------------------------------- host loop
def test_diverged_message_names_the_first_bad_loss():
    cfg = configs.TrainConfig(num_timesteps=1000, num_envs=4, num_evals=3, min_replay_size=8,
                              grad_updates_per_step=2)
    sched = configs.schedule(cfg)                 # 2 prefill actor steps, 125 per epoch
    first_bad = {"actor_loss": np.array([-1, 7]), "critic_loss": np.array([-1, 7]),
                 "flow_loss": np.array([9, -1])}
    msg = hostloop.diverged_message(first_bad, sched, 1, (5, 6), cfg, None,
                                    order=("critic_loss", "flow_loss", "actor_loss"))
    # index 7 = actor step 3, update 1: gradient step (3 − 2) · 2 + 1 = 3, env step 4 · 4 = 16;
    # flow_loss's index 9 is gradient step 5, later
    assert msg.startswith("training diverged: loss 'critic_loss' became NaN/inf at gradient step 3 "
                          "(env step 16, epoch 1, seed 6); also non-finite in the same epoch: "
                          "actor_loss (seed 6), flow_loss (seed 5)")
    assert "no checkpoint was written yet" in msg
    assert hostloop.diverged_message({"x": np.array([-1])}, sched, 1, (0,), cfg, 0) is None
    assert hostloop.row_metrics({"sgd_steps": np.array([0]), "x": np.array([1.0])}, 0) == {"sgd_steps": 0}


def test_rows_write_float32_metrics_in_their_shortest_form_without_loss():
    """A float32 metric is written in at most 9 significant digits and reads back as the same float32; a
    float64 one is unchanged (the JSON text of a row is what metrics.jsonl holds)."""
    rng = np.random.default_rng(0)
    values = np.concatenate([rng.normal(size=200) * 10.0 ** rng.integers(-12, 12, size=200),
                             [19.251487731933594, 1e-45, 3.4e38, -0.0, 0.1]]).astype(np.float32)
    for x in values:
        y = hostloop.compact(x)
        assert np.float32(y) == x and json.loads(json.dumps(y)) == y
        digits = json.dumps(y).lstrip("-").split("e")[0].replace(".", "").strip("0")
        assert len(digits) <= 9, (x, json.dumps(y))
    assert json.dumps(hostloop.compact(np.float32(19.251487731933594))) == "19.251488"
    assert np.isnan(hostloop.compact(np.float32("nan")))
    assert hostloop.compact(np.float32("inf")) == float("inf")
    assert hostloop.compact(0.1) == 0.1 and hostloop.compact(np.float64(1 / 3)) == 1 / 3
    returns = rng.normal(size=8).astype(np.float32) * 100
    means = {"sgd_steps": np.array([4.0, 4.0], np.float32), "loss": np.array([0.1, 2 / 3], np.float32)}
    row = hostloop.make_row(1, 7, 100, returns, hostloop.row_metrics(means, 1), None, 0.5, 1.0,
                            eval_metrics=lambda r: {"success": float(np.mean(r > 0))})
    assert np.float32(row["eval_return"]) == np.mean(returns) and row["loss"] == 0.6666667
    assert np.float32(row["eval_return_std"]) == np.std(returns)
    assert row["success"] == float(np.mean(returns > 0)) and row["sgd_steps"] == 4
    # a name a reader would take for damage (RunFolder.read_rows) is refused when the row is made
    with pytest.raises(ConfigError, match=r"metric names must be identifiers .* found \['loss/p'\]"):
        hostloop.make_row(1, 7, 100, returns, {"loss/p": 1.0}, None, 0.5, 1.0)


# ------------------------------------------------------------------------------------------- plots
def _write_run(path, label, steps, returns_per_seed):
    run = RunFolder(path)
    run.write_config({"config": {"task": "T", "algo": "td3", "representation": "r"}, "seeds": [0],
                      "label": label})
    run.append_rows([{"epoch": e, "seed": s, "env_steps": x, "eval_return": ret[e]}
                     for s, ret in enumerate(returns_per_seed) for e, x in enumerate(steps)])
    return run.path


def test_final_table_pools_folders_of_one_method_and_refuses_disjoint_points(tmp_path):
    a = _write_run(tmp_path / "a", "TD3+X", [0, 10, 20], [[0.0, 1.0, 2.0], [0.0, 1.0, 4.0]])
    b = _write_run(tmp_path / "b", "TD3+X", [0, 10, 20], [[0.0, 1.0, 6.0]])
    (row,) = plotting.final_table([a, b])
    assert (row["method"], row["seeds"], row["env_steps"], row["final_return"]) == ("TD3+X", 3, 20, 4.0)
    assert row["per_seed"] == [2.0, 4.0, 6.0]
    # bootstrap means of (2, 4, 6) are 2 and 6 each with probability 1/27 = 3.7% > 2.5%: the 95%
    # percentile interval is exactly the seeds' range
    assert (row["ci_low"], row["ci_high"]) == (2.0, 6.0)
    c = _write_run(tmp_path / "c", "TD3+X", [0, 15, 30], [[0.0, 1.0, 2.0]])
    with pytest.raises(ValueError, match="do not share their evaluation points"):
        plotting.final_table([a, c])
    assert plotting.method_label("sac", "none") == "SAC" and plotting.method_label("td3", "sim") == "TD3+sim"
    assert cli.expand_runs([tmp_path]) == [a, b, c]
    # a damaged metrics file is named, never a run missing from the table
    (b / "metrics.jsonl").write_text((b / "metrics.jsonl").read_text().replace("\n", "\nnot a row\n", 1))
    with pytest.raises(RunFolderError, match=r"b/metrics.jsonl line 2 is not a metrics row"):
        plotting.final_table([a, b])


def test_final_table_without_rliable_has_the_same_interval(tmp_path, monkeypatch, capsys):
    """rliable belongs to sf2-studies, not to a lean GPU host; a finished training's table and curve band
    do not need it (`stats.stratified_bootstrap` draws its resamples): the same interval with and without
    it, and no warning."""
    a = _write_run(tmp_path / "a", "TD3+X", [0, 10, 20], [[0.0, 1.0, 2.0], [0.0, 1.0, 4.0], [0.0, 1.0, 6.0]])
    (want,) = plotting.final_table([a])
    monkeypatch.setitem(sys.modules, "rliable", None)  # `import rliable` raises ImportError
    (row,) = plotting.final_table([a])
    assert (row["final_return"], row["seeds"]) == (4.0, 3)
    assert want["ci_low"] < 4.0 < want["ci_high"]
    assert (row["ci_low"], row["ci_high"]) == (want["ci_low"], want["ci_high"])
    assert plotting.band_label(3) == "95% bootstrap CI of the mean (n=3)"
    assert "n=2 < 3" in plotting.band_label(2)
    cli.print_table([row])
    out, err = capsys.readouterr()
    assert f"[{row['ci_low']:.1f}, {row['ci_high']:.1f}]" in out and "warning" not in err


# ------------------------------------------------------------------------------------------- the loop
class _FakeSession:
    """Two seeds; epoch e's evaluation returns 10·e; `bad_epoch` makes seed 1's loss non-finite."""

    def __init__(self, bad_epoch=None):
        self.bad_epoch, self.log = bad_epoch, []

    def start(self):
        self.log.append("start")

    def train_epoch(self, epoch):
        self.log.append(f"train {epoch}")
        first_bad = {"loss": np.array([-1, 0 if epoch == self.bad_epoch else -1])}
        return {"sgd_steps": np.full(2, 4), "loss": np.full(2, float(epoch))}, first_bad

    def evaluate(self, epoch):
        return np.full((2, 3), 10.0 * epoch)

    def save(self, epoch, env_steps):
        self.log.append(f"save {epoch}")

    def loss_order(self):
        return ("loss",)

    def finish(self):
        self.log.append("finish")


def _loop(session, run, last, **kw):
    cfg = configs.TrainConfig(num_timesteps=96, num_envs=4, num_evals=4, min_replay_size=4,
                              checkpoint_every=2)
    rows = run.truncate_rows(-1 if last is None else last)     # the rows a resume from `last` keeps
    walltime = max((r.get("walltime", 0.0) for r in rows), default=0.0)
    return hostloop.run_epochs(session, cfg=cfg, sched=configs.schedule(cfg), seeds=(3, 4), run=run,
                               title="t", rows=rows, start=0 if last is None else last + 1, last=last,
                               walltime=walltime, progress=False, plot=False, **kw)


def _strip(rows):
    return [{k: v for k, v in r.items() if k not in hostloop.WALL_FIELDS} for r in rows]


def test_run_epochs_order_resume_and_nan_guard(tmp_path):
    events = []
    full = _FakeSession()
    rows = _loop(full, RunFolder(tmp_path / "full"), None, hook=lambda e, n: events.append(f"{e} {n}"))
    # 3 epochs of 8 actor steps (96 env steps / 4 envs over num_evals − 1 = 3 epochs); checkpoints at
    # 0, every 2nd epoch and the last
    assert full.log == ["start", "save 0", "train 1", "train 2", "save 2", "train 3", "save 3", "finish"]
    assert events == ["evaluate 0", "rows 0", "save 0", "checkpoint 0",
                      "train 1", "evaluate 1", "rows 1",
                      "train 2", "evaluate 2", "rows 2", "save 2", "checkpoint 2",
                      "train 3", "evaluate 3", "rows 3", "save 3", "checkpoint 3"]
    assert [(r["epoch"], r["seed"], r["env_steps"], r["eval_return"]) for r in rows] == [
        (e, s, 32 * e, 10.0 * e) for e in range(4) for s in (3, 4)]
    assert rows[2]["loss"] == 1.0 and rows[2]["sgd_steps"] == 4 and "loss" not in rows[0]

    killed = RunFolder(tmp_path / "killed")                   # killed after epoch 3's rows, before its save
    _loop(_FakeSession(), killed, None, stop_after_epoch=2)
    killed.append_rows([{"epoch": 3, "seed": 3}])
    again = _FakeSession()
    assert _strip(_loop(again, killed, 2)) == _strip(rows) and again.log == ["train 3", "save 3", "finish"]
    assert _strip(killed.read_rows()) == _strip(rows)

    # epoch 2's first SGD step: actor step 8, one prefill actor step before it, 8 updates per actor
    # step: gradient step (8 − 1) · 8 = 56, env step 9 · 4 = 36
    nan = RunFolder(tmp_path / "nan")
    with pytest.raises(hostloop.TrainingDiverged, match="loss 'loss' became NaN/inf at gradient step 56 "
                       "\\(env step 36, epoch 2, seed 4\\).*the last good checkpoint \\(epoch 0\\) is kept"):
        _loop(_FakeSession(bad_epoch=2), nan, None)
    assert [r["epoch"] for r in nan.read_rows()] == [0, 0, 1, 1]


def test_bootstrap_interval_of_the_mean():
    """The band (rliable's percentile bootstrap, sf2_common.agents.stats): inside the seeds' range, zero
    width for equal seeds, for many seeds close to the normal-theory interval mean ± 1.96·s/√n (within 10%
    of its width); none (NaN) below 3 seeds, where it would not be informative."""
    pytest.importorskip("rliable", reason="comes with sf2-studies: pip install packages/sf2-studies")
    mean, lo, hi = plotting.mean_ci([[1.0, 5.0], [3.0, 5.0]])
    np.testing.assert_array_equal(mean, [2.0, 5.0])
    assert np.isnan(lo).all() and np.isnan(hi).all()
    mean, lo, hi = plotting.mean_ci([[1.0, 5.0], [3.0, 5.0], [2.0, 5.0]])
    assert 1.0 <= lo[0] < mean[0] < hi[0] <= 3.0 and lo[1] == hi[1] == 5.0
    v = np.random.default_rng(1).normal(size=(200, 1))
    mean, lo, hi = plotting.mean_ci(v)
    half = 1.96 * v.std(ddof=1) / np.sqrt(len(v))
    assert lo[0] >= v.min() and hi[0] <= v.max()
    assert (hi[0] - lo[0]) / (2 * half) == pytest.approx(1.0, abs=0.1)
    assert (lo[0] + hi[0]) / 2 == pytest.approx(mean[0], abs=0.1 * half)
    one = plotting.mean_ci([[7.0, 8.0]])
    assert np.array_equal(one[0], [7.0, 8.0]) and np.isnan(one[1]).all() and np.isnan(one[2]).all()


def test_hardware_names_the_accelerators_or_the_cpu(monkeypatch):
    """config.json's `hardware` (hostloop.hardware): each model once, counted when several; the CPU's
    model name when the program uses no accelerator."""
    assert hostloop.hardware(["NVIDIA H100 80GB HBM3"]) == "NVIDIA H100 80GB HBM3"
    assert hostloop.hardware(iter(["NVIDIA H200", "NVIDIA H200"])) == "2 x NVIDIA H200"
    assert hostloop.hardware(["A", "B", "A"]) == "2 x A, B"
    monkeypatch.setattr(hostloop, "cpu_model", lambda: "Test CPU 9000")
    assert hostloop.hardware([]) == "CPU (Test CPU 9000)"


def test_numerics_environment_keeps_the_variables_that_change_the_numbers():
    """config.json's `environment`: only the NUMERICS_ENV variables, only when set to something; train.log's
    line names them, or says that none is set."""
    env = {"XLA_FLAGS": "--xla_gpu_deterministic_ops=true", "HOME": "/root", "NVIDIA_TF32_OVERRIDE": "0",
           "CUBLAS_WORKSPACE_CONFIG": ""}
    assert hostloop.numerics_environment(env) == {"XLA_FLAGS": "--xla_gpu_deterministic_ops=true",
                                                  "NVIDIA_TF32_OVERRIDE": "0"}
    assert hostloop.numerics_environment({"HOME": "/root"}) == {}
    assert hostloop.environment_line({"XLA_FLAGS": "--xla_gpu_deterministic_ops=true"}) == \
        "environment: XLA_FLAGS='--xla_gpu_deterministic_ops=true'"
    assert hostloop.environment_line({}) == \
        "environment: none of XLA_FLAGS, NVIDIA_TF32_OVERRIDE, CUBLAS_WORKSPACE_CONFIG set"


def test_folders_of_one_label_with_different_configs_are_different_methods(tmp_path):
    a = _write_run(tmp_path / "a", "SAC", [0, 10], [[0.0, 1.0]])
    b = _write_run(tmp_path / "b", "SAC", [0, 10], [[0.0, 3.0]])
    conf = RunFolder(b).read_config()
    conf["config"]["adam_eps"] = 1e-5
    RunFolder(b).write_config(conf)
    rows = {r["method"]: r["final_return"] for r in plotting.final_table([a, b])}
    assert rows == {"SAC (adam_eps=None)": 1.0, "SAC (adam_eps=1e-05)": 3.0}
    # a field one folder predates is the value its run trained with (configs.ADDED_FIELDS): one method
    conf["config"].update(adam_eps=None, physics="mjx")
    RunFolder(b).write_config(conf)
    assert {r["method"] for r in plotting.final_table([a, b])} == {"SAC"}
