"""`study compare`: several study folders' aggregates and claim verdicts side by side, as the paper's Fig. 7
shows the TD3 and SAC families together (`sf2-jax study compare results/fig7-td3 results/fig7-sac --out
results/fig7`).

Nothing is pooled across studies: each study's numbers are the ones its own `study report` gives (per-task
min–max normalization over that study's runs, paper §4.2; rliable intervals over its seeds; its claims'
verdicts, sf2_studies/claims.py). This module reads each folder once with `report`'s functions and
writes `summary.md` (one aggregate table per family, one row per comparison with a column per folder, and
per task each method's AUC in returns, the scale that does compare across studies) and
`aggregate.png/svg` (one row of panels per family, `figures.aggregate`). Claims are matched by
their text with the family's name blanked (`claim_key`), comparisons by scope and the two methods without
their family ("SF² (γ=0.99) − vanilla"), so the fig7-td3 and fig7-sac claims meet row by row; a claim or
comparison only one study has shows "—" in the others' columns. A column is named by its folder, so one
study file run twice into two folders (fig7-sac at two Adam ε, results/fig7-sac-eps1e-8) compares too.
"""

from __future__ import annotations

import types
from pathlib import Path

from . import claims, report, stats
from .folder import StudyFolder
from .spec import StudyError

__all__ = ["compare", "claim_key"]


def _read(path, label):
    folder = StudyFolder(path)
    study = folder.load_study()
    data = report.collect(study, folder)
    rows = report.results_rows(study, data)
    table, covers = report.aggregate_table(study, rows)
    checked = claims.check(study, rows, report.obs_noise_rows(data)) if study.claims else []
    return types.SimpleNamespace(name=label, study=study), table, covers, checked, rows


def _labels(paths) -> list[str]:
    """Each folder's column name: its own name, or the path as given where two folders share a name."""
    base = [Path(p).name for p in paths]
    return [b if base.count(b) == 1 else str(p) for b, p in zip(base, paths)]


def _cell(c: claims.Comparison) -> str:
    if c.difference is None:
        return f"— ({c.verdict})"
    ci = "" if c.lower is None else f" [{claims._num(c.lower)}, {claims._num(c.upper)}]"
    p = "" if c.p_improvement is None else f", P {c.p_improvement:.2f}"
    return f"{claims._num(c.difference)}{ci}{p}: {c.verdict}"


def compare(paths, out, command: str | None = None) -> dict[str, Path]:
    """Write summary.md and aggregate.png/svg of the study folders `paths` into `out`; returns {name: path}.
    Every folder is read (and a damaged one refused, naming it) before anything is written."""
    from . import figures

    if len(paths) < 2:
        raise StudyError(f"study compare needs two or more study folders; got {len(paths)}")
    resolved = [Path(p).resolve() for p in paths]
    if len(set(resolved)) < len(resolved):
        raise StudyError(f"study compare: the same study folder twice ({', '.join(map(str, paths))}); "
                         "compare different folders")
    read = [_read(p, label) for p, label in zip(paths, _labels(paths))]
    names = [col.name for col, *_ in read]
    out = Path(out)
    blocking = next((p for p in (out, *out.parents) if p.exists()), None)
    if blocking is not None and not blocking.is_dir():
        raise StudyError(f"compare folder {out}: {blocking} is a file, not a folder; nothing was written")
    out.mkdir(parents=True, exist_ok=True)

    families = [f for _, table, *_ in read for f in table]
    clash = len(set(families)) < len(families)   # the same family in two studies: name the study too
    tables, covers = {}, {}
    md = [f"# Studies compared: {', '.join(_title(col) for col, *_ in read)}", ""]
    if command:
        md += ["Command:", "", "```", command, "```", ""]
    md += ["Each study's numbers as its own `study report` gives them (normalization per task over that "
           "study's runs, intervals over its seeds): nothing is pooled across studies, so compare verdicts "
           "and orders, and returns rather than normalized scores.", "",
           "## Aggregate normalized AUC per family (paper Fig. 1 / 7)", ""]
    for (col, table, cover, *_), path in zip(read, paths):
        md += [f"From `{col.name}` ({path}):", ""]
        for c in cover.values():
            md += report._md_coverage(col.study, c)
        md += report._md_aggregate(table, {f: len(c.tasks) for f, c in cover.items()})
        for family, entries in table.items():
            key = f"{family} ({col.name})" if clash else family
            tables[key] = entries
            covers[key] = cover[family]
    written = {}
    if tables:
        tasks = tuple(dict.fromkeys(t for col, *_ in read for t in col.study.tasks))
        shown = types.SimpleNamespace(name=" + ".join(names), tasks=tasks)
        written.update(figures.aggregate(tables, out / "aggregate", shown, covers))
        md += ["![aggregate](aggregate.png)", ""]
    md += _md_claims(read)
    md += _md_per_task(read)
    (out / "summary.md").write_text("\n".join(md))
    written["summary.md"] = out / "summary.md"
    return written


def _title(col) -> str:
    """A column's name for the heading, with its study's name where the folder is named otherwise."""
    return f"`{col.name}`" + (f" (study `{col.study.name}`)" if col.study.name != col.name else "")


def claim_key(text: str, families) -> str:
    """A claim's text with its study's family names blanked, so that fig7-td3's "over vanilla TD3" and
    fig7-sac's "over vanilla SAC" are the same claim and unrelated claims are not."""
    for family in sorted(families, key=len, reverse=True):
        text = text.replace(family, "<family>")
    return text


def _md_claims(read) -> list[str]:
    """One table per claim (`claim_key`): a row per (scope, method kind, other kind), a column per folder."""
    names = [col.name for col, *_ in read]
    groups: dict[str, dict[str, tuple]] = {}
    for col, *_, checked, _ in read:
        kinds = {m.label: m.kind for m in col.study.methods}
        families = {m.family for m in col.study.methods}
        for entry in checked:
            groups.setdefault(claim_key(entry[0].text, families), {})[col.name] = (entry, kinds)
    if not groups:
        return []
    lines = ["## The paper's claims, study by study", "",
             "Each cell: Δ of the claim's statistic (claimed − other) [95% bootstrap CI], rliable's "
             "P(claimed > other), and the verdict, as each study's report/summary.md gives them; \"—\" "
             "where a study has no such comparison. Claims are matched by their text, the family's name "
             "aside.", ""]
    for i, by_study in enumerate(groups.values(), 1):
        texts = {n: entry[0].text for n, (entry, _) in by_study.items()}
        first = next(iter(texts.values()))
        other_texts = [f"(In `{n}`: {t})" for n, t in texts.items() if t != first]
        lines += [f"**Claim {i}** — {first}", ""] + other_texts + [""] * bool(other_texts)
        lines += ["Verdicts: " + "; ".join(f"`{n}` **{entry[1]}**" for n, (entry, _) in by_study.items())
                  + ".", "", "| scope | comparison | " + " | ".join(f"`{n}`" for n in names) + " |",
                  "|---|---|" + "---|" * len(names)]
        cells: dict[tuple, dict[str, str]] = {}
        for n, (entry, kinds) in by_study.items():
            for c in entry[2]:
                key = (c.scope, kinds.get(c.method, c.method), kinds.get(c.other, c.other))
                cells.setdefault(key, {})[n] = _cell(c)
        for (scope, method, other), by in cells.items():
            lines.append(f"| {scope} | {method} − {other} | "
                         + " | ".join(by.get(n, "—") for n in names) + " |")
        lines.append("")
    return lines


def _md_per_task(read) -> list[str]:
    """Per task and method (without its family), each study's mean AUC in returns [95% CI] over its
    finished seeds: the numbers that compare across studies (normalized ones do not)."""
    names = [col.name for col, *_ in read]
    cells: dict[tuple, dict[str, str]] = {}
    for col, *_, rows in read:
        for task in col.study.tasks:
            for m in col.study.methods:
                aucs = [r["auc"] for r in rows if r["task"] == task and r["method"] == m.label]
                if aucs:
                    res = stats.mean_interval(aucs)
                    cell = f"{report._with_ci(res[0][0], *report._lohi(res))} ({len(aucs)})"
                    cells.setdefault((task, m.kind), {})[col.name] = cell
    if not cells:
        return []
    lines = ["## Per task: AUC in returns, mean [95% CI] (seeds)", "",
             "The AUC is the mean evaluation return over training (report/summary.md's definition); unlike "
             "the normalized AUC it is on the same scale in every study.", "",
             "| task | method | " + " | ".join(f"`{n}`" for n in names) + " |",
             "|---|---|" + "---|" * len(names)]
    for (task, method), by in cells.items():
        lines.append(f"| {task} | {method} | " + " | ".join(by.get(n, "—") for n in names) + " |")
    return lines + [""]
