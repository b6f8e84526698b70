"""The paper's claims checked against a study's runs: a study file's `[[claims]]` entries (parsed into
`Study.claims`) and their verdicts in `study report` (summary.md "The paper's claims", claims.csv).

Each comparison is the difference of a statistic of the normalized AUC (method − other) with its 95%
bootstrap interval (rliable) and P(method > other); supported (interval above 0), contradicted (below),
not resolved (holds 0), cannot decide (a task lacks finished seeds, or fewer than `MIN_SEEDS`). An
equivalence claim (`equivalent_to`, `margin`) is two one-sided tests at 5% each: equivalent when the 90%
interval lies inside (−margin, +margin), else not shown equivalent. The fields, the rules and the
projected half-width are documented in docs/study-files.md "Claims"."""

from __future__ import annotations

import dataclasses

from . import stats
from .base import StudyError, seeds_text

__all__ = ["Claim", "Comparison", "parse", "evaluate", "check", "markdown", "csv_rows", "VERDICTS",
           "CSV_FIELDS"]

VERDICTS = ("supported", "contradicted", "not resolved", "equivalent", "not shown equivalent",
            "cannot decide")
CSV_FIELDS = ("claim", "scope", "method", "other", "score", "statistic", "tasks", "missing_tasks", "seeds",
              "difference", "lower", "upper", "p_improvement", "verdict", "projected_half_width",
              "difference_auc", "margin", "confidence")
_KEYS = ("text", "method", "above", "equivalent_to", "margin", "tasks", "statistic", "per_task", "score")
EQUIVALENCE_CONFIDENCE = 0.90   # two one-sided tests at 5% each ⇔ the 90% interval inside the margin
SCORES = ("normalized_auc", "obs_noise")


@dataclasses.dataclass(frozen=True)
class Claim:
    text: str
    method: str                  # method name (folder name)
    above: tuple[str, ...]       # method names
    tasks: tuple[str, ...]
    statistic: str               # a key of stats.STATISTICS
    per_task: bool
    score: str = "normalized_auc"   # or "obs_noise" (SCORES)
    margin: float | None = None     # an equivalence claim: `above` then holds `equivalent_to`'s methods

    @property
    def equivalence(self) -> bool:
        return self.margin is not None

    @property
    def confidence(self) -> float:
        return EQUIVALENCE_CONFIDENCE if self.equivalence else stats.CONFIDENCE

    def scores_what(self) -> str:
        return ("normalized AUC" if self.score == "normalized_auc" else
                "AUC over the checkpoints evaluated under observation noise")


@dataclasses.dataclass(frozen=True)
class Comparison:
    scope: str                   # "all 7 tasks" or the task of a per-task claim
    method: str                  # labels
    other: str
    tasks: tuple[str, ...]       # the tasks the numbers are over
    missing: tuple[str, ...]     # the comparison's tasks without finished seeds of both methods
    seeds: tuple[int, ...]
    difference: float | None
    lower: float | None
    upper: float | None
    p_improvement: float | None
    verdict: str
    projected: float | None = None   # the interval's half-width projected to the study's seeds (docstring)
    difference_auc: float | None = None   # the same difference of the AUC in return units (docstring)
    study_seeds: int = 0             # N, the study's number of seeds


# ------------------------------------------------------------------------------------------- parsing
def parse(entries, where: str, methods, tasks, evaluation=None) -> tuple[Claim, ...]:
    """The study file's `claims` (a list of tables) → `Claim`s; `StudyError` naming the entry and the
    valid choices for anything else. `methods`: the study's `Method`s; `tasks`: its tasks; `evaluation`:
    its [evaluation] (spec.Evaluation or None)."""
    if entries is None:
        return ()
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise StudyError(f"{where}: claims: write each claim as a [[claims]] table")
    names = {}
    for m in methods:
        names[m.name] = names[m.label] = m.name
    valid = ", ".join(m.name for m in methods)
    out = []
    for i, e in enumerate(entries):
        entry = f"claims[{i}]"

        def fail(problem: str, entry=entry):
            raise StudyError(f"{where}: {entry}: {problem}")

        unknown = sorted(set(e) - set(_KEYS))
        if unknown:
            fail(f"unknown key(s) {', '.join(unknown)}; valid: {', '.join(_KEYS)}")
        text = e.get("text")
        if not isinstance(text, str) or not text.strip():
            fail("text: the claim in words, with where the paper makes it, is required")
        method = e.get("method")
        if method not in names:
            fail(f"method = {method!r} is not a method of the study; valid: {valid}")
        if ("above" in e) == ("equivalent_to" in e):
            fail("give either above (the methods the claim says it beats) or equivalent_to (the methods it "
                 "is claimed to learn like, with a margin)")
        key = "above" if "above" in e else "equivalent_to"
        above = e[key]
        if isinstance(above, str):
            above = [above]
        if not isinstance(above, list) or not above:
            fail(f"{key}: a list of the study's methods, e.g. {key} = [\"td3-none\"]")
        for a in above:
            if a not in names:
                fail(f"{key} names {a!r}, not a method of the study; valid: {valid}")
            if names[a] == names[method]:
                fail(f"{key} names the claim's own method {a!r}")
        margin = e.get("margin")
        if key == "above" and margin is not None:
            fail("margin belongs to an equivalence claim (equivalent_to)")
        if key == "equivalent_to" and (isinstance(margin, bool) or not isinstance(margin, (int, float))
                                       or not 0 < margin < float("inf")):
            fail(f"margin = {margin!r} is invalid: an equivalence claim needs a margin > 0 on the claim's "
                 f"score, fixed before the runs (e.g. margin = 0.1 of the normalized AUC)")
        claim_tasks = e.get("tasks", "all")
        if claim_tasks == "all":
            claim_tasks = list(tasks)
        if (not isinstance(claim_tasks, list) or not claim_tasks
                or any(t not in tasks for t in claim_tasks)):
            fail(f"tasks = {claim_tasks!r} is invalid: \"all\" or a list of the study's tasks "
                 f"({', '.join(tasks)})")
        statistic = e.get("statistic", "IQM")
        if statistic not in stats.STATISTICS:
            fail(f"statistic = {statistic!r} is not one of {', '.join(stats.STATISTICS)}")
        per_task = e.get("per_task", False)
        if not isinstance(per_task, bool):
            fail(f"per_task = {per_task!r} is invalid: true or false")
        score = e.get("score", "normalized_auc")
        if score not in SCORES:
            fail(f"score = {score!r} is not one of {', '.join(SCORES)}")
        if score == "obs_noise" and evaluation is None:
            fail("score = \"obs_noise\" needs the study's [evaluation] table (its obs_noise levels)")
        if score == "obs_noise" and len(claim_tasks) > 1 and not per_task:
            fail("score = \"obs_noise\" over several tasks needs per_task = true (the AUC over checkpoints "
                 "is in each task's return units)")
        out.append(Claim(text.strip(), names[method], tuple(dict.fromkeys(names[a] for a in above)),
                         tuple(t for t in tasks if t in claim_tasks), statistic, per_task, score,
                         None if margin is None else float(margin)))
    return tuple(out)


# ------------------------------------------------------------------------------------------- verdicts
def _compare(scope: str, method: str, other: str, tasks, rows, statistic: str,
             margin: float | None = None) -> Comparison:
    def scores(label):
        return {t: {r["seed"]: r["score"] for r in rows if r["method"] == label and r["task"] == t}
                for t in tasks}

    mine, theirs = scores(method), scores(other)
    have = [t for t in tasks if mine[t] and theirs[t]]
    missing = tuple(t for t in tasks if t not in have)
    sets = [set(mine[t]) & set(theirs[t]) for t in have]
    seeds = tuple(sorted(set.intersection(*sets))) if sets else ()
    if not seeds:
        return Comparison(scope, method, other, tuple(have), missing, (), None, None, None, None,
                          "cannot decide")
    x = [[mine[t][s] for t in have] for s in seeds]
    y = [[theirs[t][s] for t in have] for s in seeds]
    confidence = stats.CONFIDENCE if margin is None else EQUIVALENCE_CONFIDENCE
    point, lo, hi = stats.difference_interval(x, y, statistic, resamples=stats.RESAMPLES,
                                              confidence=confidence)
    p = stats.probability_of_improvement(x, y)
    if missing or lo is None:
        verdict = "cannot decide"
    elif margin is not None:
        verdict = "equivalent" if -margin < lo and hi < margin else "not shown equivalent"
    elif lo > 0:
        verdict = "supported"
    elif hi < 0:
        verdict = "contradicted"
    else:
        verdict = "not resolved"
    return Comparison(scope, method, other, tuple(have), missing, seeds, point, lo, hi, p, verdict)


def overall(comparisons, equivalence: bool = False) -> str:
    """A claim's verdict from its comparisons' (module docstring): contradicted if one is, else cannot
    decide if one cannot, else supported if all are, else not resolved; an equivalence claim: cannot decide
    if one cannot, else equivalent if all are, else not shown equivalent."""
    verdicts = [c.verdict for c in comparisons]
    if equivalence:
        if "cannot decide" in verdicts:
            return "cannot decide"
        return "equivalent" if all(v == "equivalent" for v in verdicts) else "not shown equivalent"
    for v in ("contradicted", "cannot decide"):
        if v in verdicts:
            return v
    return "supported" if all(v == "supported" for v in verdicts) else "not resolved"


def evaluate(claim: Claim, study, rows: list[dict], noise_rows=()) -> tuple[str, list[Comparison]]:
    """(verdict, comparisons) of one claim on the report's rows: `rows` (report.results_rows: task, method
    label, seed, normalized_auc) or, for `score = "obs_noise"`, `noise_rows` (report.obs_noise_rows:
    task, method, seed, noise, auc)."""
    label = {m.name: m.label for m in study.methods}
    n = len(study.tasks)
    whole = f"all {n} tasks" if len(claim.tasks) == n else f"{len(claim.tasks)} tasks"
    if claim.score == "normalized_auc":
        scored = [{**r, "score": r["normalized_auc"]} for r in rows]
        scopes = ([(t, (t,), scored) for t in claim.tasks] if claim.per_task else
                  [(whole, claim.tasks, scored)])
    else:
        scopes = []
        for level in study.evaluation.obs_noise:
            at = [{**r, "score": r["auc"]} for r in noise_rows if r["noise"] == level]
            scopes += ([(f"{t} · noise {level:g}", (t,), at) for t in claim.tasks] if claim.per_task else
                       [(f"noise {level:g}", claim.tasks, at)])
    comparisons = [_compare(scope, label[claim.method], label[other], tasks, scored, claim.statistic,
                            claim.margin)
                   for scope, tasks, scored in scopes for other in claim.above]
    comparisons = [dataclasses.replace(c, projected=projected_half_width(c, len(study.seeds)),
                                       study_seeds=len(study.seeds),
                                       difference_auc=difference_auc(c, claim, rows)) for c in comparisons]
    return overall(comparisons, claim.equivalence), comparisons


def difference_auc(c: Comparison, claim: Claim, rows: list[dict]) -> float | None:
    """`c`'s difference in return units (module docstring): the claim's statistic of the seeds' AUC
    (report.results_rows' "auc", before normalization) of the claimed method minus the other's, over `c`'s
    seeds; None unless `c` is a normalized-AUC comparison on one task (`per_task`, or a claim of one task)
    with an AUC for every seed."""
    one = claim.per_task or len(claim.tasks) == 1
    if claim.score != "normalized_auc" or not one or len(c.tasks) != 1 or not c.seeds:
        return None
    (task,) = c.tasks

    def auc(label):
        got = {r["seed"]: r.get("auc") for r in rows if r["method"] == label and r["task"] == task}
        return [[got.get(s)] for s in c.seeds]

    x, y = auc(c.method), auc(c.other)
    if any(v[0] is None for v in x + y):
        return None
    return stats.difference(x, y, claim.statistic)


def projected_half_width(c: Comparison, n_study: int) -> float | None:
    """The half-width of `c`'s interval scaled from its seeds to the study's `n_study` (module docstring);
    None without an interval or where `c` already has every seed."""
    n = len(c.seeds)
    if c.lower is None or c.upper is None or n >= n_study:
        return None
    return (c.upper - c.lower) / 2 * (n / n_study) ** 0.5


def check(study, rows: list[dict], noise_rows=()) -> list[tuple[Claim, str, list[Comparison]]]:
    """Every claim of the study with its verdict and comparisons (`evaluate`), computed once for the report's
    `markdown` and `csv_rows`."""
    return [(claim, *evaluate(claim, study, rows, noise_rows)) for claim in study.claims]


# ------------------------------------------------------------------------------------------- output
def _num(x) -> str:
    """Signed, 3 decimals; a nonzero number that would print as ±0.000 gets 2 significant digits instead,
    so that an interval bound that decides a verdict (e.g. an upper bound of −0.00045: contradicted) shows
    its sign."""
    if x is None:
        return "—"
    return f"{x:+.1e}" if x and abs(x) < 5e-4 else f"{x:+.3f}"


def _returns(x) -> str:
    """A difference in return units: one decimal from 10 on, else 3 significant digits."""
    return "—" if x is None else f"{x:+.1f}" if abs(x) >= 10 else f"{x:+#.3g}"


def markdown(checked) -> list[str]:
    """summary.md's section from `check`'s result: per claim its verdict and a table of its comparisons."""
    lines = ["## The paper's claims (the study file's [[claims]])", "",
             "Each comparison: the difference of the statistic of the scores (claimed method − other; "
             "the normalized AUC unless a claim says otherwise) over the seeds both finished on every task, "
             f"its 95% bootstrap interval (rliable, {stats.RESAMPLES} resamples, each method's seeds "
             "resampled within each task), and rliable's "
             "probability of improvement P(claimed > other). **supported**: the interval lies above 0; "
             "**contradicted**: below 0; **not resolved**: it holds 0; **cannot decide**: a task lacks "
             f"finished seeds of one of the two (numbers then over the tasks that have them), or fewer than "
             f"{stats.MIN_SEEDS} seeds. With 5 seeds a nominal 95% interval covers the truth only about 84% "
             "of the time (docs/decisions/intervals.md). **At N seeds (projected)**, N the study's seeds, "
             "where a comparison has fewer: its interval's half-width × √(seeds / N), what it would "
             "narrow to if the remaining seeds spread as these do; \"Δ beyond\" means the difference is "
             "larger than it (the rest of the seeds may resolve it), \"Δ within\" smaller (they likely "
             "will not). A planning figure, not a test (sf2_studies/claims.py)."
             + (" **Equivalence claims** (two one-sided tests at 5% each): the 90% interval of the "
                "difference inside (−margin, +margin), the margin fixed in the study file before the runs: "
                "**equivalent**; else **not shown equivalent**." if any(c.equivalence for c, *_ in checked)
                else "")
             + (" **Δ AUC (returns)**, for a comparison on one task: the same statistic's difference of the "
                "AUC before normalization (the mean return over training). The normalization is per task and "
                "affine, so the verdict is the same; it shows how large a normalized difference is in "
                "returns: on a task where every run scored little, min–max scaling spreads small differences "
                "over [0, 1]." if any(c.difference_auc is not None for *_, comps in checked for c in comps)
                else ""), ""]
    for i, (claim, verdict, comps) in enumerate(checked, 1):
        counts = ", ".join(f"{v} {n}" for v in VERDICTS if (n := sum(c.verdict == v for c in comps)))
        plural = "s" * (len(comps) > 1)
        within = f" within ±{claim.margin:g}" if claim.equivalence else ""
        lines += [f"**Claim {i}** — {claim.text}", "",
                  f"Verdict: **{verdict}**{within} ({counts} of {len(comps)} comparison{plural}).", ""]
        shown = [c for c in comps if c.seeds]
        project = max((c.study_seeds for c in shown if c.projected is not None), default=0)
        raw = any(c.difference_auc is not None for c in shown)
        if shown:
            lines += [f"Scores: {claim.scores_what()}.", "",
                      f"| scope | comparison | tasks with both | seeds | Δ {claim.statistic} "
                      f"[{claim.confidence:.0%} CI] | "
                      + (f"Δ {claim.statistic} AUC (returns) | " if raw else "")
                      + "P(claimed > other) | verdict |"
                      + (f" at {project} seeds (projected) |" if project else ""),
                      "|---|---|---|---|---|---|---|" + "---|" * raw + ("---|" if project else "")]
        for c in shown:
            tasks = f"{len(c.tasks)} of {len(c.tasks) + len(c.missing)} ({', '.join(c.tasks)})" if c.missing \
                else "all"
            ci = "" if c.lower is None else f" [{_num(c.lower)}, {_num(c.upper)}]"
            p = "—" if c.p_improvement is None else f"{c.p_improvement:.2f}"
            projection = f" {_projection(c)} |" if project else ""
            returns = f"{_returns(c.difference_auc)} | " if raw else ""
            lines.append(f"| {c.scope} | {c.method} − {c.other} | {tasks} | {seeds_text(c.seeds)} | "
                         f"{_num(c.difference)}{ci} | {returns}{p} | {c.verdict} |{projection}")
        empty = [c for c in comps if not c.seeds]
        if empty:
            whole = [s for s in dict.fromkeys(c.scope for c in comps)
                     if all(not c.seeds for c in comps if c.scope == s)]
            some = [f"{c.scope}: {c.method} − {c.other}" for c in empty if c.scope not in whole]
            lines += ["", "No seeds finished by both methods yet (cannot decide): "
                      + "; ".join(whole + some) + "."]
        lines.append("")
    return lines


def _projection(c: Comparison) -> str:
    if c.projected is None:
        return "—"
    return f"±{c.projected:.3f}, Δ {'beyond' if abs(c.difference) > c.projected else 'within'}"


def csv_rows(checked) -> list[dict]:
    """One row per comparison of every claim (`CSV_FIELDS`) from `check`'s result."""
    out = []
    for i, (claim, _, comps) in enumerate(checked, 1):
        for c in comps:
            out.append({"claim": i, "scope": c.scope, "method": c.method, "other": c.other,
                        "score": claim.score, "statistic": claim.statistic, "tasks": ";".join(c.tasks),
                        "missing_tasks": ";".join(c.missing), "seeds": seeds_text(c.seeds) if c.seeds else "",
                        "difference": c.difference, "lower": c.lower, "upper": c.upper,
                        "p_improvement": c.p_improvement, "verdict": c.verdict,
                        "projected_half_width": c.projected, "difference_auc": c.difference_auc,
                        "margin": claim.margin, "confidence": claim.confidence})
    return out
