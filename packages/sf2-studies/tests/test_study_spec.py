"""Study files (sf2_studies.spec) and study folders (folder.py) without a framework: the shipped
files parse, bad input names the file, the entry and the valid choices, and a study folder made from
another study file is refused with nothing changed."""

from __future__ import annotations

from pathlib import Path

import pytest
from sf2_studies import spec
from sf2_studies.folder import StudyFolder
from sf2_studies.spec import StudyError

STUDIES = Path(__file__).resolve().parents[3] / "studies"

BASE = """
name = "t"
seeds = "0-2"
tasks = ["CartpoleBalance"]
[[methods]]
label = "TD3"
algo = "td3"
representation = "none"
"""


def _load(tmp_path, text, name="s.toml"):
    path = tmp_path / name
    path.write_text(text)
    return spec.load(path)


def _error(tmp_path, text) -> str:
    with pytest.raises(StudyError) as info:
        _load(tmp_path, text)
    msg = str(info.value)
    assert str(tmp_path / "s.toml") in msg   # every message names the file
    return msg


@pytest.mark.parametrize("path", sorted(STUDIES.glob("*.toml")), ids=lambda p: p.stem)
def test_shipped_study_files_parse(path):
    study = spec.load(path)
    assert study.name == path.stem
    labels = [m.label for m in study.methods]
    assert len(set(labels)) == len(labels)


def test_paper_studies_declare_the_protocol():
    fig7 = spec.load(STUDIES / "fig7-td3.toml")
    assert fig7.seeds == tuple(range(15)) and len(fig7.tasks) == 7
    assert fig7.seed_groups() == (tuple(range(5)), tuple(range(5, 15)))     # seeds_per_run = ["0-4", "5-14"]
    assert dict(fig7.overrides)["num_timesteps"] == "1000000"
    assert [m.label for m in fig7.methods] == ["TD3", "TD3+SF² (γ=0.99)", "TD3+SF² (γ=0)", "TD3+Sim",
                                               "TD3+SimLap", "TD3+SPR"]
    assert dict(fig7.method("td3-sf2-g0").overrides) == {"gamma_su": "0.0"}
    fig9 = spec.load(STUDIES / "fig9-obs-noise.toml")
    assert fig9.seeds == tuple(range(6)) and fig9.evaluation.obs_noise == (0.0, 0.05, 0.1, 0.2)
    assert {m.family for m in fig9.methods} == {"TD3", "SAC"}
    fig9_left = spec.load(STUDIES / "fig9-left.toml")   # flow steps per SGD step, k = 1 the paper's
    assert dict(fig9_left.overrides)["num_timesteps"] == "1000000" and fig9_left.seeds == tuple(range(10))
    assert fig9_left.report.sweep_score == "iqm_auc"   # the figure's y: IQM of the normalized AUC
    assert {(m.algo, m.representation, m.sweep[:2]) for m in fig9_left.methods} == {
        (a, "sf2", ("aux_steps_per_sgd_step", str(k))) for a in ("td3", "sac") for k in (1, 2, 4, 8)}
    assert {(c.method, c.above) for c in fig9_left.claims} >= {
        (f"{a}-sf2-aux-steps-per-sgd-step-8", (f"{a}-sf2-aux-steps-per-sgd-step-1",)) for a in ("td3", "sac")}
    fig5 = spec.load(STUDIES / "fig5-spr-noise.toml")   # SPR over its augmentation std; 0.05 is the paper's
    assert fig5.tasks == ("AcrobotSwingup",) and {m.representation for m in fig5.methods} == {"spr"}
    assert {m.sweep[:2] for m in fig5.methods} >= {("spr_augmentation_std", "0.0"), ("spr_augmentation_std",
                                                                                       "0.05")}


def test_sweeps_expand_into_methods(tmp_path):
    study = _load(tmp_path, BASE + """
[[sweeps]]
field = "tau_zeta"
values = [0.01, 0.1]
methods = [{ label = "SAC+SF²", algo = "sac", representation = "sf2" }]
""")
    swept = [m for m in study.methods if m.sweep]
    assert [m.label for m in swept] == ["SAC+SF² (tau_zeta=0.01)", "SAC+SF² (tau_zeta=0.1)"]
    assert [m.name for m in swept] == ["sac-sf2-tau-zeta-0.01", "sac-sf2-tau-zeta-0.1"]
    assert dict(swept[1].overrides) == {"tau_zeta": "0.1"}
    assert study.report.figures == ("aggregate", "curves", "sweeps")
    assert study.text == (tmp_path / "s.toml").read_text()   # the study folder keeps this copy


def test_budget_and_override_values_become_cli_text(tmp_path):
    study = _load(tmp_path, BASE.replace('tasks', 'budget = 5_000\ntasks') + """
overrides = { hidden_sizes = [16, 16], deterministic_eval = true, tau = 1e-3 }
""")
    assert dict(study.overrides) == {"num_timesteps": "5000"}
    assert dict(study.methods[0].overrides) == {"hidden_sizes": "16,16", "deterministic_eval": "true",
                                                "tau": "0.001"}


@pytest.mark.parametrize("text, expected", [
    ("bogus = 1\n" + BASE, ["top level: unknown key 'bogus'", "valid keys: name,"]),
    (BASE.replace("seeds", "seed"), ["unknown key 'seed'", "did you mean 'seeds'"]),
    (BASE.replace('"0-2"', '"2-0"'), ["seeds: seeds '2-0' are invalid"]),
    (BASE.replace('name = "t"', ""), ["name: a non-empty string is required"]),
    ('preset = "huge"\n' + BASE, ["preset: 'huge' is not one of paper, quick"]),
    ('framework = "tf"\n' + BASE, ["framework: 'tf' is not one of jax, torch"]),
    (BASE + '[[methods]]\nlabel = "TD3"\nalgo = "td3"\nrepresentation = "sf2"\n',
     ["the label 'TD3' is used twice", "every method needs its own label"]),
    (BASE + '[[methods]]\nlabel = "TD3 again"\nname = "td3"\nalgo = "td3"\nrepresentation = "sf2"\n',
     ["the name 'td3' is used twice"]),
    (BASE + '[[methods]]\nlabel = "X"\nalgo = "td3"\n', ["methods[1]: representation is required"]),
    (BASE + '[[methods]]\nlabel = "X"\nalgo = "td3"\nrepresentation = "sf2"\nrepr = "sf2"\n',
     ["methods[1]: unknown key 'repr'", "valid keys: label, name, algo, representation, overrides"]),
    (BASE + '[[methods]]\nlabel = "X"\nalgo = "td3"\nrepresentation = "sf2"\noverrides = { task = "A" }\n',
     ["methods[1].overrides: 'task' is not an override"]),
    (BASE + "[evaluation]\nobs_noise = [-0.1]\n", ["evaluation.obs_noise"]),
    (BASE + "[evaluation]\nobs_noise = [0.1]\nepisodes = 0\n", ["evaluation.episodes = 0 is invalid"]),
    (BASE + '[report]\nfigures = ["sweeps"]\n', ["asks for 'sweeps'", "no [[sweeps]]"]),
    (BASE + '[report]\nsweep_score = "auc"\n', ["report.sweep_score = 'auc' is invalid",
                                                   "'final_return', 'iqm_auc'"]),
    ("budget = -3\n" + BASE, ["budget: -3 is invalid"]),
    ("name = [", ["not valid TOML"]),
])
def test_bad_study_files(tmp_path, text, expected):
    msg = _error(tmp_path, text)
    for part in expected:
        assert part in msg, msg


def test_select_names_the_valid_choices(tmp_path):
    study = _load(tmp_path, BASE)
    assert [(t, m.name) for t, m in study.select(methods=["TD3"])] == [("CartpoleBalance", "td3")]
    with pytest.raises(StudyError, match="'HopperHop' is not a task of study 't'.*valid: CartpoleBalance"):
        study.select(tasks=["HopperHop"])
    with pytest.raises(StudyError, match="'sac' is not a method.*valid: td3"):
        study.select(methods=["sac"])


def test_folder_of_another_study_file_is_refused_untouched(tmp_path):
    first = _load(tmp_path, BASE, "a.toml")
    other = _load(tmp_path, BASE.replace('"0-2"', '"0-4"'), "b.toml")
    folder = StudyFolder(tmp_path / "study")
    folder.open(first, "jax", [], command="sf2-jax study run a.toml --out study")
    (folder.path / "runs" / "x").mkdir(parents=True)
    before = sorted((p.relative_to(folder.path), p.read_bytes() if p.is_file() else None)
                    for p in folder.path.rglob("*"))
    with pytest.raises(StudyError) as info:
        folder.open(other, "jax", [])
    msg = str(info.value)
    assert str(tmp_path / "a.toml") not in msg   # the folder's own copy is named, and the new file
    assert str(folder.study_path) in msg and str(tmp_path / "b.toml") in msg and "differ in seeds" in msg
    with pytest.raises(StudyError, match="holds runs of sf2-jax"):
        folder.open(first, "torch", [])
    after = sorted((p.relative_to(folder.path), p.read_bytes() if p.is_file() else None)
                   for p in folder.path.rglob("*"))
    assert after == before
    # the same file again (e.g. with a comment added) continues the folder
    folder.open(_load(tmp_path, "# a comment\n" + BASE, "c.toml"), "jax", [], command="again")
    assert [c["command"] for c in folder.read_state()["commands"]] == [
        "sf2-jax study run a.toml --out study", "again"]


def test_folder_takes_added_tasks_and_methods_but_no_changed_ones(tmp_path):
    """A study under way may gain a task or a method (an ablation run beside the finished runs): the folder's
    copy follows the file. A method changed or removed, or a task removed, is another study; a method given
    an override of an execution field only (`seed_loop`) is the same one."""
    folder = StudyFolder(tmp_path / "study")
    folder.open(_load(tmp_path, BASE, "a.toml"), "jax", [])
    added = BASE.replace('["CartpoleBalance"]', '["CartpoleBalance", "AcrobotSwingup"]') + (
        '[[methods]]\nlabel = "TD3+SF²"\nalgo = "td3"\nrepresentation = "sf2"\n')
    folder.open(_load(tmp_path, added, "b.toml"), "jax", [])
    assert folder.load_study().data == _load(tmp_path, added, "b.toml").data
    changed = added.replace('representation = "none"', 'representation = "none"\noverrides = { tau = 0.01 }')
    for text, key in ((BASE, "methods, tasks"), (changed, "methods"),
                      (added.replace('"CartpoleBalance", ', ""), "tasks"),
                      (changed.replace("tau = 0.01", 'tau = 0.01, seed_loop = "map"'), "methods")):
        with pytest.raises(StudyError, match=f"differ in {key}\\."):
            folder.open(_load(tmp_path, text, "c.toml"), "jax", [])
    assert folder.load_study().data == _load(tmp_path, added, "b.toml").data
    # how a method's seeds run (configs.EXECUTION_FIELDS) is not what its runs compute: the copy follows
    executed = added.replace('representation = "none"',
                             'representation = "none"\noverrides = { seed_loop = "map" }')
    folder.open(_load(tmp_path, executed, "d.toml"), "jax", [])
    assert folder.load_study().data == _load(tmp_path, executed, "d.toml").data


def test_non_empty_folder_without_a_study_is_refused(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "precious.txt").write_text("x")
    with pytest.raises(StudyError, match="not empty and holds no study"):
        StudyFolder(tmp_path / "out").check(_load(tmp_path, BASE), "jax")


def test_a_study_takes_a_users_environment_by_import_path(tmp_path, monkeypatch):
    """`tasks` entries are what `--task` takes: an import path resolves (its module imported, the env not
    built: the core's validate builds it) into a run of that task; one that does not import names the file
    and the entry."""
    import sys
    import types

    from sf2_common.agents import configs

    module = types.ModuleType("study_user_envs")
    module.make_env = lambda: None
    monkeypatch.setitem(sys.modules, "study_user_envs", module)
    study = _load(tmp_path, BASE.replace('["CartpoleBalance"]', '["study_user_envs:make_env"]'))
    runs = spec.resolve(study, configs.make_config, lambda cfg, seeds: cfg)
    assert [(r.task, r.config.task, r.argv[:2]) for r in runs] == [
        ("study_user_envs:make_env", "study_user_envs:make_env", ("--task", "study_user_envs:make_env"))]
    bad = _load(tmp_path, BASE.replace('["CartpoleBalance"]', '["study_user_envs:missing"]'), "bad.toml")
    with pytest.raises(StudyError) as err:
        spec.resolve(bad, configs.make_config, lambda cfg, seeds: cfg)
    assert str(err.value) == (f"{tmp_path / 'bad.toml'}: tasks[0]: task 'study_user_envs:missing': module "
                              f"'study_user_envs' has no attribute 'missing'")
