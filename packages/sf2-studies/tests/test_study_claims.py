"""A study file's `[[claims]]` (sf2_studies.claims): parsed with errors that name the valid choices,
checked with verdicts on scores whose outcome is derived by hand, the difference interval and probability
of improvement against rliable's own functions, and a study folder that takes claims added later."""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest

pytest.importorskip("rliable", reason="sf2-studies' dependencies: pip install packages/sf2-studies")

from rliable import library, metrics  # noqa: E402
from sf2_studies import claims, stats  # noqa: E402
from sf2_studies.folder import StudyFolder  # noqa: E402
from sf2_studies.spec import StudyError, loads  # noqa: E402

STUDY = """
name = "claimed"
seeds = "0-4"
tasks = ["T1", "T2"]
[[methods]]
label = "TD3"
name = "td3"
algo = "td3"
representation = "none"
[[methods]]
label = "TD3+SF²"
name = "td3-sf2"
algo = "td3"
representation = "sf2"
"""
CLAIM = """
[[claims]]
text = "SF² above TD3"
method = "TD3+SF²"
above = ["td3"]
"""


def _rows(scores: dict) -> list[dict]:
    """{(task, method label): {seed: normalized AUC}} → report rows."""
    return [{"task": t, "method": m, "seed": s, "normalized_auc": v}
            for (t, m), by in scores.items() for s, v in by.items()]


def test_claims_parse_and_bad_entries_name_the_choices(tmp_path):
    second = CLAIM.replace('above = ["td3"]',
                           'above = "TD3"\nper_task = true\nstatistic = "Mean"\ntasks = ["T2"]')
    study = loads(STUDY + CLAIM + second, tmp_path / "s.toml")
    one, two = study.claims
    assert (one.method, one.above, one.tasks, one.statistic, one.per_task) == (
        "td3-sf2", ("td3",), ("T1", "T2"), "IQM", False)            # label → name, tasks "all", defaults
    assert (two.above, two.tasks, two.statistic, two.per_task) == (("td3",), ("T2",), "Mean", True)
    bad = {
        'method = "TD3+SF²"': ('method = "sac"', "method = 'sac' is not a method of the study; valid: td3, "
                                                  "td3-sf2"),
        'above = ["td3"]': ('above = ["td3-sf2"]', "above names the claim's own method 'td3-sf2'"),
        'text = "SF² above TD3"': ('text = ""', "text: the claim in words"),
    }
    for old, (new, message) in bad.items():
        with pytest.raises(StudyError, match=message.replace("(", r"\(").replace(")", r"\)")):
            loads(STUDY + CLAIM.replace(old, new), tmp_path / "s.toml")
    for extra, message in (('statistic = "Max"', "statistic = 'Max' is not one of IQM, Median, Mean"),
                           ('tasks = ["T3"]',
                            r"tasks = \['T3'\] is invalid: \"all\" or a list of the study's "
                            r"tasks \(T1, T2\)"),
                           ("per_task = 1", "per_task = 1 is invalid: true or false"),
                           ("against = 1", "unknown key\\(s\\) against; valid: text, method, above")):
        with pytest.raises(StudyError, match=r"claims\[0\]: " + message):
            loads(STUDY + CLAIM + extra + "\n", tmp_path / "s.toml")


def test_difference_interval_and_probability_are_rliables():
    """SF²'s scores are TD3's plus 0.5 on every seed and task: the IQM difference is 0.5 exactly, the
    bootstrap interval is rliable's own on the pair under the same seed, and P(SF² > TD3) = 1 (every
    SF² score above every TD3 score: U = n_x · n_y)."""
    rng = np.random.default_rng(1)
    td3 = rng.random((5, 2)) * 0.4
    sf2 = td3 + 0.5
    point, lo, hi = stats.difference_interval(sf2, td3, "IQM", resamples=800)
    assert point == pytest.approx(0.5)

    def fn(a, b):
        return np.array([metrics.aggregate_iqm(a) - metrics.aggregate_iqm(b)])

    state = np.random.get_state()
    np.random.seed(stats.SEED)
    _, want = library.get_interval_estimates({"d": (sf2, td3)}, fn, reps=800)
    np.random.set_state(state)
    assert (lo, hi) == (float(want["d"][0][0]), float(want["d"][1][0]))
    assert lo < 0.5 < hi
    assert stats.probability_of_improvement(sf2, td3) == 1.0
    assert stats.probability_of_improvement(td3, td3) == 0.5      # rliable: equal columns count 1/2
    # fewer than MIN_SEEDS seeds: the point, no interval
    assert stats.difference_interval(sf2[:2], td3[:2])[1:] == (None, None)


def test_verdicts_from_scores_derived_by_hand(tmp_path, monkeypatch):
    monkeypatch.setattr(stats, "RESAMPLES", 500)   # the verdicts below hold for any resample
    study = loads(STUDY + CLAIM, tmp_path / "s.toml")
    claim = study.claims[0]
    seeds = range(5)

    def verdict(sf2, td3, tasks=("T1", "T2")):
        scores = {}
        for t in tasks:
            scores[(t, "TD3+SF²")] = {s: sf2(s) for s in seeds}
            scores[(t, "TD3")] = {s: td3(s) for s in seeds}
        return claims.evaluate(claim, study, _rows(scores))

    # SF² 0.8–0.84 against TD3 0.1–0.14 on both tasks: any resample's IQM difference is in [0.66, 0.74]
    v, (c,) = verdict(lambda s: 0.8 + 0.01 * s, lambda s: 0.1 + 0.01 * s)
    assert v == "supported" and c.verdict == "supported" and c.difference == pytest.approx(0.7)
    assert 0.66 <= c.lower <= c.upper <= 0.74 and c.p_improvement == 1.0
    assert (c.tasks, c.missing, c.seeds, c.scope) == (("T1", "T2"), (), (0, 1, 2, 3, 4), "all 2 tasks")
    v, (c,) = verdict(lambda s: 0.1 + 0.01 * s, lambda s: 0.8 + 0.01 * s)
    assert v == "contradicted" and c.upper < 0
    # the same scores: difference 0, an interval around it
    v, (c,) = verdict(lambda s: 0.1 * s, lambda s: 0.1 * s)
    assert v == "not resolved" and c.difference == 0.0 and c.lower < 0 < c.upper
    # TD3 missing on T2: numbers over T1 only, and no verdict on the two-task claim
    v, (c,) = verdict(lambda s: 0.8, lambda s: 0.1, tasks=("T1",))
    assert v == "cannot decide" and (c.tasks, c.missing) == (("T1",), ("T2",))
    assert c.difference == pytest.approx(0.7) and c.lower is not None
    # two seeds: no interval, cannot decide
    seeds = range(2)
    v, (c,) = verdict(lambda s: 0.8, lambda s: 0.1)
    assert v == "cannot decide" and c.lower is None and c.difference == pytest.approx(0.7)
    # a claim's verdict from its comparisons'
    def comps(*verdicts):
        return [claims.Comparison("s", "a", "b", (), (), (), None, None, None, None, v) for v in verdicts]

    assert claims.overall(comps("supported", "supported")) == "supported"
    assert claims.overall(comps("supported", "not resolved")) == "not resolved"
    assert claims.overall(comps("supported", "cannot decide", "not resolved")) == "cannot decide"
    assert claims.overall(comps("cannot decide", "contradicted")) == "contradicted"


def test_report_and_a_study_folder_that_takes_claims_later(tmp_path):
    """A folder made from the study file without claims accepts the file with claims added (no run depends
    on them) and its copy follows the file; the report then writes the claims' section and claims.csv. A
    file that changes a run (its seeds) is still refused, the copy unchanged."""
    import json

    from sf2_studies.report import report

    folder = StudyFolder(tmp_path / "study")
    folder.open(loads(STUDY, tmp_path / "s.toml"), "jax", [])
    per_task = (CLAIM.replace('text = "SF² above TD3"', 'text = "on each task"')
                + 'per_task = true\nstatistic = "Mean"\n')
    with_claims = loads(STUDY.replace('name = "claimed"', 'name = "claimed"\ndescription = "now with words"')
                        + CLAIM + per_task, tmp_path / "s.toml")
    folder.open(with_claims, "jax", [])
    assert folder.load_study().claims == with_claims.claims
    with pytest.raises(StudyError, match="differ in seeds"):
        folder.open(loads(STUDY.replace('"0-4"', '"0-5"') + CLAIM, tmp_path / "s.toml"), "jax", [])
    assert folder.load_study().claims == with_claims.claims
    # runs: curves [0, v, v] at env steps 0, 100, 200 (AUC 3v/4); TD3 v = s, SF² v = 10 + s on both tasks
    for task in ("T1", "T2"):
        for name, base in (("td3", 0.0), ("td3-sf2", 10.0)):
            path = folder.run_path(task, name)
            path.mkdir(parents=True)
            (path / "config.json").write_text(json.dumps({"config": {}, "seeds": list(range(5)),
                                                          "schedule": {"num_epochs": 2}}))
            rows = [{"epoch": e, "seed": s, "env_steps": 100 * e, "eval_return": 0.0 if e == 0 else base + s}
                    for e in range(3) for s in range(5)]
            (path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    written = report(folder.path)
    summary = written["summary.md"].read_text()
    # normalized AUC: (base + s) / 14 on both tasks, so SF² − TD3 is 10/14 on every seed
    assert "**Claim 1** — SF² above TD3" in summary
    assert "Verdict: **supported** (supported 1 of 1 comparison)." in summary
    line = next(x for x in summary.splitlines() if x.startswith("| all 2 tasks | TD3+SF² − TD3 |"))
    assert f"| all | 0-4 | {10 / 14:+.3f} [" in line and line.endswith("| 1.00 | supported |")
    # per task, the same difference in returns: AUC 3(10 + s)/4 − 3s/4 = 7.5 on every seed (10/14 of the
    # task's AUC range 3 · 14 / 4 = 10.5); the aggregate claim's table has no such column
    assert "Δ Mean AUC (returns)" in summary and "Δ IQM AUC (returns)" not in summary
    assert "**Δ AUC (returns)**, for a comparison on one task" in summary
    line = next(x for x in summary.splitlines() if x.startswith("| T2 | TD3+SF² − TD3 |"))
    assert f"| all | 0-4 | {10 / 14:+.3f} [" in line and line.endswith("| +7.50 | 1.00 | supported |")
    aggregate, *each = list(csv.DictReader(open(written["claims.csv"])))
    assert aggregate["verdict"] == "supported" and float(aggregate["difference"]) == pytest.approx(10 / 14)
    assert aggregate["difference_auc"] == "" and len(each) == 2
    assert all(float(r["difference_auc"]) == pytest.approx(7.5) for r in each)


def test_a_bound_that_rounds_to_zero_keeps_its_sign():
    """A verdict rests on the sign of a bound: an upper bound of −0.00045 (contradicted) must not print as
    −0.000 (results/fig7-sac's CartpoleSwingupSparse, SAC+SF² − SAC)."""
    assert [claims._num(x) for x in (-0.00045, 0.0003, 0.0, 0.0005, -0.1234, None)] == [
        "-4.5e-04", "+3.0e-04", "+0.000", "+0.001", "-0.123", "—"]
    assert [claims._returns(x) for x in (22.98, -1.434, 0.0933, 1.0, 567.5, None)] == [
        "+23.0", "-1.43", "+0.0933", "+1.00", "+567.5", "—"]


def test_observation_noise_claims_compare_each_level(tmp_path, monkeypatch):
    """Fig. 9 right: `score = "obs_noise"` compares the AUC over the noisy checkpoints at each [evaluation]
    level. SF² 100–104 against TD3 10–14 without noise; under noise 0.2 both 50–54: supported at 0, not
    resolved at 0.2 (equal scores), so the claim is not resolved."""
    monkeypatch.setattr(stats, "RESAMPLES", 500)
    text = (STUDY.replace('tasks = ["T1", "T2"]', 'tasks = ["T1"]') + "[evaluation]\nobs_noise = [0.0, 0.2]\n"
            + CLAIM + 'score = "obs_noise"\n')
    study = loads(text, tmp_path / "s.toml")
    noise_rows = [{"task": "T1", "method": m, "seed": s, "noise": level, "auc": base + s}
                  for s in range(5) for level, bases in ((0.0, {"TD3+SF²": 100, "TD3": 10}),
                                                         (0.2, {"TD3+SF²": 50, "TD3": 50}))
                  for m, base in bases.items()]
    verdict, (clean, noisy) = claims.evaluate(study.claims[0], study, [], noise_rows)
    assert (clean.scope, noisy.scope) == ("noise 0", "noise 0.2")
    assert clean.verdict == "supported" and clean.difference == pytest.approx(90.0)
    assert noisy.verdict == "not resolved" and noisy.difference == 0.0 and verdict == "not resolved"
    # no [evaluation], or raw AUCs of several tasks pooled: refused
    with pytest.raises(StudyError, match=r"score = \"obs_noise\" needs the study's \[evaluation\] table"):
        loads(STUDY + CLAIM + 'score = "obs_noise"\n', tmp_path / "s.toml")
    with pytest.raises(StudyError, match="over several tasks needs per_task = true"):
        loads(STUDY + "[evaluation]\nobs_noise = [0.0]\n" + CLAIM + 'score = "obs_noise"\n',
              tmp_path / "s.toml")


def test_projected_half_width_at_the_study_seeds_by_hand(tmp_path):
    """A comparison over 4 of 16 seeds: its interval's half-width × √(4/16) = half of it; none with every
    seed or without an interval; the summary's column says whether the difference lies beyond it."""
    study = loads(STUDY.replace('seeds = "0-4"', 'seeds = "0-15"') + CLAIM, tmp_path / "s.toml")
    c = claims.Comparison("all 2 tasks", "TD3+SF²", "TD3", ("T1", "T2"), (), (0, 1, 2, 3), -0.015, -0.115,
                          0.085, 0.41, "not resolved")
    assert claims.projected_half_width(c, 16) == pytest.approx(0.1 * 0.5)
    assert claims.projected_half_width(c, 4) is None
    assert claims.projected_half_width(dataclasses.replace(c, lower=None, upper=None), 16) is None
    wide = dataclasses.replace(c, difference=0.08, projected=0.05, study_seeds=16)
    near = dataclasses.replace(c, projected=0.05, study_seeds=16)
    md = "\n".join(claims.markdown([(study.claims[0], "not resolved", [wide, near])]))
    assert "| P(claimed > other) | verdict | at 16 seeds (projected) |" in md
    assert "| +0.080 [-0.115, +0.085] | 0.41 | not resolved | ±0.050, Δ beyond |" in md
    assert "| -0.015 [-0.115, +0.085] | 0.41 | not resolved | ±0.050, Δ within |" in md
    # evaluate() fills it in: 5 seeds of the study's 16 on both tasks
    scores = {(t, m): {s: (0.1 if m == "TD3" else 0.0) * s for s in range(5)}
              for t in ("T1", "T2") for m in ("TD3", "TD3+SF²")}
    (c,) = claims.evaluate(study.claims[0], study, _rows(scores))[1]
    assert c.study_seeds == 16
    assert c.projected == pytest.approx((c.upper - c.lower) / 2 * (5 / 16) ** 0.5)


EQUIVALENCE = """
[[claims]]
text = "SF² learns like TD3"
method = "td3-sf2"
equivalent_to = ["td3"]
margin = {margin}
statistic = "Mean"
tasks = ["T1"]
"""


def test_an_equivalence_claim_is_two_one_sided_tests_within_its_margin(tmp_path):
    """SF² scores 0.5 on each of 3 seeds, TD3 scores (0, 0.3, 0.6). A bootstrap resample of TD3's seeds is 3
    draws from them, 27 equally likely: their sum in units of 0.3 is 0..6 with counts 1, 3, 6, 7, 6, 3, 1,
    so TD3's mean is 0 with probability 1/27 (3.7%), at most 0.1 with 4/27 (14.8%), 0.6 with 1/27 and at
    least 0.5 with 4/27. Its 5th and 95th percentiles are 0.1 and 0.5, so the 90% interval of SF² − TD3 is
    [0.0, 0.4] around 0.2 (the 95% one, from the 2.5th and 97.5th percentiles 0 and 0.6, is [−0.1, 0.5]):
    equivalent within ±0.5, not shown equivalent within ±0.3."""
    scores = {("T1", "TD3+SF²"): {0: 0.5, 1: 0.5, 2: 0.5}, ("T1", "TD3"): {0: 0.0, 1: 0.3, 2: 0.6},
              ("T2", "TD3+SF²"): {0: 0.5}, ("T2", "TD3"): {0: 0.5}}
    for margin, verdict in ((0.5, "equivalent"), (0.3, "not shown equivalent")):
        study = loads(STUDY.replace('seeds = "0-4"', 'seeds = "0-2"') + EQUIVALENCE.format(margin=margin),
                      tmp_path / "s.toml")
        (claim,) = study.claims
        assert (claim.equivalence, claim.margin, claim.confidence) == (True, margin, 0.90)
        got, (c,) = claims.evaluate(claim, study, _rows(scores))
        assert (got, c.verdict) == (verdict, verdict)
        assert c.difference == pytest.approx(0.2)
        assert (c.lower, c.upper) == (pytest.approx(0.0, abs=1e-12), pytest.approx(0.4))
        lines = claims.markdown(claims.check(study, _rows(scores)))
        assert f"Verdict: **{verdict}** within ±{margin:g} " in "\n".join(lines)
        assert "Δ Mean [90% CI]" in "\n".join(lines)
        (row,) = claims.csv_rows(claims.check(study, _rows(scores)))
        assert (row["margin"], row["confidence"], row["verdict"]) == (margin, 0.90, verdict)
    superiority = CLAIM.replace('above = ["td3"]', 'above = ["td3"]\nstatistic = "Mean"\ntasks = ["T1"]')
    study = loads(STUDY.replace('seeds = "0-4"', 'seeds = "0-2"') + superiority, tmp_path / "a.toml")
    (above,) = claims.evaluate(study.claims[0], study, _rows(scores))[1]
    assert (above.lower, above.upper) == (pytest.approx(-0.1), pytest.approx(0.5))


@pytest.mark.parametrize("entry,message", [
    ('above = ["td3"]\nequivalent_to = ["td3"]', "give either above"),
    ('equivalent_to = ["td3"]', "margin = None is invalid: an equivalence claim needs a margin > 0"),
    ('equivalent_to = ["td3"]\nmargin = -0.1', "margin = -0.1 is invalid"),
    ('above = ["td3"]\nmargin = 0.1', "margin belongs to an equivalence claim"),
    ('equivalent_to = ["td3-sf2"]\nmargin = 0.1', "equivalent_to names the claim's own method 'td3-sf2'"),
])
def test_bad_equivalence_claims_name_the_problem(tmp_path, entry, message):
    text = STUDY + '\n[[claims]]\ntext = "x"\nmethod = "td3-sf2"\n' + entry + "\n"
    with pytest.raises(StudyError, match=message.replace("(", r"\(").replace(")", r"\)")):
        loads(text, tmp_path / "s.toml")
