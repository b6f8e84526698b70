"""CSV, markdown and PNG outputs of a bench run (and re-rendering them from the CSV).

CSV: one row per timed case, with the per-round times (`times_ms`, ';'-separated) so every ratio can be
recomputed. Ratios are paired: per round r, ratio_r = t_a[r] / t_b[r] (the two cases were timed in the
same round, seconds apart), and the median over rounds is reported with its quartiles.
"""

from __future__ import annotations

import csv
import json
import math
import statistics
from pathlib import Path

from .sizes import SIZES, TASKS
from .timing import paired_ratio

COLUMNS = [
    "framework", "algo", "rep", "task", "obs_size", "action_size", "size", "batch_size", "steps",
    "integrator", "median_ms", "q25_ms", "q75_ms", "min_ms", "repeats", "n_per_block", "compile_s",
    "flops", "flops_source", "bytes", "achieved_tflops", "finite", "impl", "times_ms",
]
FW_LABEL = {"jax": "JAX (jit)", "jax-scan": "JAX (jit, lax.scan of 8)", "torch": "torch eager",
            "torch-graphs": "torch eager + CUDA graphs", "torch-compile": "torch compiled",
            "torch-cudagraphs": "torch compiled + CUDA graphs"}
FW_ORDER = ("jax", "jax-scan", "torch", "torch-graphs", "torch-compile", "torch-cudagraphs")
TORCH_FW = ("torch", "torch-graphs", "torch-compile", "torch-cudagraphs")
# The design targets of the update, set for the `paper` size on an H200 (TD3, midpoint).
TARGETS = {"sf2_over_vanilla": 1.3, "per_step_pct": 3.0, "torch_over_jax": 1.5}


# ------------------------------------------------------------------------------------------------ csv
def write_csv(rows: list[dict], path: Path) -> None:
    """Write a run's rows.

    Args:
        rows: one dict per timed case (the keys of `COLUMNS`).
        path: the CSV file (updates.csv).
    """
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
        w.writeheader()
        for row in rows:
            w.writerow({k: _fmt_csv(row.get(k, "")) for k in COLUMNS})


def _fmt_csv(v):
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return ";".join(f"{x:.6g}" for x in v)
    return v


def print_rows(rows: list[dict], fields: tuple[str, ...], markdown: bool) -> None:
    """Print rows on stdout.

    Args:
        rows: dicts holding `fields`.
        fields: the columns of the Markdown table.
        markdown: a Markdown table of `fields`; otherwise one JSON object per line.
    """
    if markdown:
        print("| " + " | ".join(fields) + " |\n|" + "---|" * len(fields))
        for r in rows:
            print("| " + " | ".join(str(r[k]) for k in fields) + " |")
    else:
        for r in rows:
            print(json.dumps(r))


def read_csv(path: Path) -> list[dict]:
    """Read a run's rows back.

    Args:
        path: an updates.csv written by `write_csv`.

    Returns:
        The rows, numbers parsed and `times_ms` as a list.
    """
    rows = []
    with open(path) as f:
        for row in csv.DictReader(f):
            for k in ("obs_size", "action_size", "batch_size", "steps", "repeats", "n_per_block"):
                row[k] = int(row[k]) if row.get(k) not in (None, "") else 0
            for k in ("median_ms", "q25_ms", "q75_ms", "min_ms", "compile_s", "flops", "bytes",
                      "achieved_tflops"):
                row[k] = float(row[k]) if row.get(k) not in (None, "") else float("nan")
            row["times_ms"] = [float(x) for x in row["times_ms"].split(";")] if row.get("times_ms") else []
            rows.append(row)
    return rows


# ------------------------------------------------------------------------------------------- helpers
def _index(rows):
    return {(r["framework"], r["algo"], r["rep"], r["task"], r["size"], int(r["steps"]), r["integrator"]): r
            for r in rows}


def _ms(x: float) -> str:
    if x is None or math.isnan(x):
        return "–"
    return f"{x:.3f}" if x < 10 else f"{x:.1f}" if x < 1000 else f"{x:.0f}"


def _cell(row) -> str:
    if row is None:
        return "–"
    med = row["median_ms"]
    spread = (row["q75_ms"] - row["q25_ms"]) / 2 / med * 100 if med else float("nan")
    return f"{_ms(row['median_ms'])} ±{spread:.0f}%"


def _ratio(a, b) -> tuple[float, float, float]:
    if a is None or b is None:
        return float("nan"), float("nan"), float("nan")
    if a["times_ms"] and b["times_ms"] and len(a["times_ms"]) == len(b["times_ms"]):
        return paired_ratio(a["times_ms"], b["times_ms"])
    return a["median_ms"] / b["median_ms"], float("nan"), float("nan")


def _rfmt(r) -> str:
    m, lo, hi = r
    if math.isnan(m):
        return "–"
    return f"{m:.2f}×" if math.isnan(lo) else f"{m:.2f}× [{lo:.2f}–{hi:.2f}]"


def per_step_pct(idx, fw, algo, task, size, integrator, rep="sf2") -> float:
    """Cost of one more denoising step: the least-squares slope of the median time against T.

    Args:
        idx: rows by key (framework, algo, rep, task, size, steps, integrator).
        fw, algo, task, size, integrator: the cases' key.
        rep: the representation ("sf2" or a variant).

    Returns:
        The slope in % of the T = 1 time, NaN with fewer than two T or no T = 1.
    """
    pts = [(k[5], r["median_ms"]) for k, r in idx.items()
           if k[:5] == (fw, algo, rep, task, size) and k[6] == integrator]
    pts.sort()
    t1 = dict(pts).get(1)
    if len(pts) < 2 or not t1:
        return float("nan")
    xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    mx, my = statistics.fmean(xs), statistics.fmean(ys)
    slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)
    return slope / t1 * 100


def _groups(rows):
    tasks = list(dict.fromkeys(r["task"] for r in rows))
    algos = list(dict.fromkeys(r["algo"] for r in rows))
    fws = [f for f in FW_ORDER if any(r["framework"] == f for r in rows)]
    fws += [f for f in dict.fromkeys(r["framework"] for r in rows) if f not in fws]
    sizes = list(dict.fromkeys(r["size"] for r in rows))
    steps = sorted({int(r["steps"]) for r in rows if r["rep"] == "sf2"})
    integrators = [i for i in ("midpoint", "euler") if any(r["integrator"] == i for r in rows)]
    reps = list(dict.fromkeys(r["rep"] for r in rows if r["rep"] not in ("none", "sf2")
                              and not r["rep"].startswith("sf2-")))
    return tasks, algos, fws, sizes, steps, integrators, reps


def _variants(rows):
    return list(dict.fromkeys(r["rep"] for r in rows if r["rep"].startswith("sf2-")))


# ------------------------------------------------------------------------------------------ markdown
def markdown(rows: list[dict], machine: dict, extra: str = "") -> str:
    """Render a run's tables: times, ratios, representations, torch/JAX, FLOPs, design targets.

    Args:
        rows: the run's rows.
        machine: its machine.json.
        extra: markdown appended at the end (the flow-step table).

    Returns:
        updates.md's text.
    """
    idx = _index(rows)
    tasks, algos, fws, sizes, steps, integrators, reps = _groups(rows)
    out = [f"# SF² update-time bench: {machine.get('name', '')}", ""]
    out += ["Command:", "", "```", machine.get("command", ""), "```", ""]
    out += _machine_lines(machine)
    out += ["Protocol: one full SGD update (critic, flow, actor, targets) per call; compilation and "
            f"{machine.get('warmup', '?')} warm-up updates excluded; {machine.get('repeats', '?')} "
            "interleaved "
            "rounds, each timing a block of n updates between device synchronizations; cells are the median "
            "ms per update ± half the inter-quartile range. Ratios are medians of per-round paired ratios "
            "[quartiles].", ""]
    for size in sizes:
        s = SIZES.get(size, {})
        out.append(f"## Update time, size `{size}` (B = {s.get('batch_size')}, F = {s.get('feature_size')}, "
                   f"hidden {s.get('hidden_sizes')}, ζ hidden {s.get('zeta_hidden_sizes')})")
        out.append("")
        for task in tasks:
            if not any(r["task"] == task and r["size"] == size for r in rows):
                continue
            D, A = TASKS[task]
            out.append(f"### {task} (D = {D}, A = {A}) — ms per update")
            out.append("")
            head = ["algo", "framework", "vanilla"] + [f"{r}" for r in reps]
            for integ in integrators:
                head += [f"SF² {integ[:3]} T={T}" for T in steps]
            out.append("| " + " | ".join(head) + " |")
            out.append("|" + "---|" * len(head))
            for algo in algos:
                for fw in fws:
                    van = idx.get((fw, algo, "none", task, size, 0, ""))
                    cells = [algo, FW_LABEL.get(fw, fw), _cell(van)]
                    cells += [_cell(idx.get((fw, algo, rep, task, size, 0, ""))) for rep in reps]
                    for integ in integrators:
                        cells += [_cell(idx.get((fw, algo, "sf2", task, size, T, integ))) for T in steps]
                    if any(c != "–" for c in cells[2:]):
                        out.append("| " + " | ".join(cells) + " |")
            out.append("")
        out += _ratio_section(idx, tasks, algos, fws, size, steps, integrators)
        out += _baseline_section(idx, tasks, algos, fws, size, reps)
        out += _variant_section(idx, rows, tasks, algos, size, steps)
        out += _torch_jax_section(idx, rows, size)
        out += _flops_section(rows, size, machine)
        out += _targets_section(idx, tasks, fws, size, steps, integrators)
    if extra:
        out += [extra, ""]
    return "\n".join(out)


def _machine_lines(m: dict) -> list[str]:
    v = m.get("versions", {})
    lines = [
        f"- machine: {m.get('cpu', '?')} ({m.get('cpu_count', '?')} logical CPUs); "
        f"GPU: {m.get('gpu', 'none')}"
        + (f" ({m['nvidia_smi']})" if m.get("nvidia_smi") not in (None, "", "n/a") else ""),
        f"- load average at start: {m.get('load_average', 'n/a')}; date {m.get('date', '?')}; "
        f"git {m.get('git_commit', '?')}",
        "- versions: " + ", ".join(f"{k} {val}" for k, val in v.items()) + f"; python {m.get('python', '?')}",
        f"- precision: JAX `jax_default_matmul_precision={m.get('jax_default_matmul_precision', '?')}` "
        f"(backend {m.get('jax_backend', '?')}); torch allow_tf32 "
        f"matmul={m.get('torch_allow_tf32_matmul', '?')}"
        f" cudnn={m.get('torch_allow_tf32_cudnn', '?')}, float32_matmul_precision="
        f"{m.get('torch_float32_matmul_precision', '?')}, threads {m.get('torch_threads', '?')}; all float32",
    ]
    if m.get("torch_impl"):
        lines.append(f"- torch step: {m['torch_impl']}")
    if m.get("peak"):
        lines.append("- measured ceilings (one large fp32 matmul at the same precision): "
                     + ", ".join(f"{k} {val:.2f} TFLOP/s" for k, val in m["peak"].items()))
    return lines + [""]


def _ratio_section(idx, tasks, algos, fws, size, steps, integrators) -> list[str]:
    if not steps:
        return []
    tmax = max(steps)
    out = [f"### Ratios, size `{size}` (SF² with the midpoint integrator unless named)", "",
           f"| task | algo | framework | SF² T=1 / vanilla | SF² T={tmax} / vanilla | T={tmax} / T=1 | "
           "per extra step, % of T=1 (midpoint) | (euler) |", "|---|---|---|---|---|---|---|---|"]
    for task in tasks:
        for algo in algos:
            for fw in fws:
                van = idx.get((fw, algo, "none", task, size, 0, ""))
                t1 = idx.get((fw, algo, "sf2", task, size, 1, "midpoint"))
                tm = idx.get((fw, algo, "sf2", task, size, tmax, "midpoint"))
                if t1 is None and van is None:
                    continue
                pm = per_step_pct(idx, fw, algo, task, size, "midpoint")
                pe = per_step_pct(idx, fw, algo, task, size, "euler")
                out.append(f"| {task} | {algo} | {FW_LABEL.get(fw, fw)} | {_rfmt(_ratio(t1, van))} | "
                           f"{_rfmt(_ratio(tm, van))} | {_rfmt(_ratio(tm, t1))} | {_pct(pm)} | {_pct(pe)} |")
    return out + [""]


def _baseline_section(idx, tasks, algos, fws, size, reps) -> list[str]:
    """Each representation without an ODE (the baselines) and SF² (T=1, midpoint) over vanilla, paired."""
    cols = [(rep, 0, "") for rep in reps] + [("sf2", 1, "midpoint")]
    rows = []
    for task in tasks:
        for algo in algos:
            for fw in fws:
                van = idx.get((fw, algo, "none", task, size, 0, ""))
                cells = [_ratio(idx.get((fw, algo, rep, task, size, T, i)), van) for rep, T, i in cols]
                if van is not None and reps and any(not math.isnan(c[0]) for c in cells):
                    rows.append(f"| {task} | {algo} | {FW_LABEL.get(fw, fw)} | "
                                + " | ".join(_rfmt(c) for c in cells) + " |")
    if not rows:
        return []
    return [f"### Representations / vanilla, size `{size}` (paired)", "",
            "| task | algo | framework | " + " | ".join(f"{_case_label(*c)} / vanilla" for c in cols) + " |",
            "|---|---|---|" + "---|" * len(cols), *rows, ""]


def _variant_section(idx, rows, tasks, algos, size, steps) -> list[str]:
    variants = _variants([r for r in rows if r["size"] == size])
    if not variants:
        return []
    out = [f"### SF² variants (JAX, midpoint), size `{size}` — ms per update, and "
           "paired ratios to the cores' SF² step of the same T and to vanilla", "",
           "| task | algo | variant | " + " | ".join(f"T={T}" for T in steps)
           + " | variant / SF² (T=1) | variant (T=1) / vanilla | per extra step |",
           "|---|---|---|" + "---|" * (len(steps) + 3)]
    for task in tasks:
        for algo in algos:
            for jfw in ("jax", "jax-scan"):
                van = idx.get((jfw, algo, "none", task, size, 0, ""))
                base = idx.get((jfw, algo, "sf2", task, size, 1, "midpoint"))
                for v in variants:
                    cells = [_cell(idx.get((jfw, algo, v, task, size, T, "midpoint"))) for T in steps]
                    if all(c == "–" for c in cells):
                        continue
                    v1 = idx.get((jfw, algo, v, task, size, 1, "midpoint"))
                    pm = per_step_pct(idx, jfw, algo, task, size, "midpoint", rep=v)
                    out.append(f"| {task} | {algo} | {v} ({FW_LABEL[jfw]}) | " + " | ".join(cells)
                               + f" | {_rfmt(_ratio(v1, base))} | {_rfmt(_ratio(v1, van))} | {_pct(pm)} |")
    return out + [""]


def _case_label(rep, T, integ) -> str:
    if rep == "none":
        return "vanilla"
    name = "SF²" if rep == "sf2" else rep
    return f"{name} T={T} {integ}" if int(T or 0) > 0 else name


def _pct(x) -> str:
    return "–" if math.isnan(x) else f"{x:+.1f}%"


def _torch_jax_section(idx, rows, size) -> list[str]:
    jaxes = [j for j in ("jax", "jax-scan") if any(k[0] == j and k[4] == size for k in idx)]
    torches = [t for t in TORCH_FW if any(k[0] == t and k[4] == size for k in idx)]
    if not jaxes or not torches:
        return []
    cases = list(dict.fromkeys(k[1:] for k in idx if k[0] in jaxes and k[4] == size
                               and any((t, *k[1:]) in idx for t in torches)))
    if not cases:
        return []
    cols = [(t, j) for t in torches for j in jaxes]
    out = [f"### torch / JAX, size `{size}`", "",
           "| task | algo | case | " + " | ".join(f"{FW_LABEL[t]} / {FW_LABEL[j]}" for t, j in cols) + " |",
           "|---|---|---|" + "---|" * len(cols)]
    for algo, rep, task, _sz, T, integ in cases:
        cells = [_rfmt(_ratio(idx.get((t, algo, rep, task, size, T, integ)),
                              idx.get((j, algo, rep, task, size, T, integ)))) for t, j in cols]
        out.append(f"| {task} | {algo} | {_case_label(rep, T, integ)} | " + " | ".join(cells) + " |")
    return out + [""]


def _flops_section(rows, size, machine) -> list[str]:
    sel = [r for r in rows if r["size"] == size and not math.isnan(r.get("flops", float("nan")))]
    if not sel:
        return []
    peak = machine.get("peak", {})
    out = [f"### FLOPs per update and achieved rate, size `{size}`", "",
           "FLOPs: JAX rows from XLA's HLO `cost_analysis()` of the lowered update (before backend "
           "passes; every op, a dot counts 2·m·n·k); bytes from the compiled executable (after fusion); "
           "torch rows from `torch.utils.flop_counter.FlopCounterMode` on one eager update "
           "of the agents' step (matmuls only). "
           "Achieved = FLOPs / median time"
           + ("; % of the measured fp32 matmul ceiling of the same framework." if peak else "."), "",
           "| task | algo | framework | case | GFLOP | GB accessed (XLA) | achieved TFLOP/s | % of ceiling |",
           "|---|---|---|---|---|---|---|---|"]
    for r in sel:
        case = _case_label(r["rep"], r["steps"], r["integrator"])
        ach = r["flops"] / (r["median_ms"] * 1e-3) / 1e12 if r["median_ms"] else float("nan")
        ceil = peak.get("jax" if r["framework"].startswith("jax") else "torch")
        pct = f"{ach / ceil * 100:.1f}%" if ceil else "–"
        gb = "–" if math.isnan(r.get("bytes", float("nan"))) else f"{r['bytes'] / 1e9:.3f}"
        out.append(f"| {r['task']} | {r['algo']} | {FW_LABEL.get(r['framework'], r['framework'])} | {case} | "
                   f"{r['flops'] / 1e9:.2f} | {gb} | {ach:.3f} | {pct} |")
    return out + [""]


def targets(idx, tasks, fws, size, steps, integrators) -> list[dict]:
    """Evaluate the design targets (`TARGETS`) on this run's TD3 rows.

    Args:
        idx: rows by key.
        tasks, fws, size, steps, integrators: the run's groups.

    Returns:
        One dict per target and task: `target`, `task`, `value`, `met`.
    """
    res = []
    for task in tasks:
        for jfw in ("jax", "jax-scan"):
            lab = FW_LABEL[jfw]
            van = idx.get((jfw, "td3", "none", task, size, 0, ""))
            t1 = idx.get((jfw, "td3", "sf2", task, size, 1, "midpoint"))
            if van and t1:
                m = _ratio(t1, van)[0]
                res.append(dict(target=f"{lab}: SF² (T=1) / vanilla TD3 ≤ 1.3×", task=task, value=f"{m:.2f}×",
                                met=m <= TARGETS["sf2_over_vanilla"]))
            for integ in ("midpoint", "euler"):
                p = per_step_pct(idx, jfw, "td3", task, size, integ)
                if not math.isnan(p):
                    res.append(dict(target=f"{lab}: each extra denoising step ({integ}) ≤ 3% of T=1",
                                    task=task, value=f"{p:+.1f}%", met=p <= TARGETS["per_step_pct"]))
        for fw in ("torch-compile", "torch-cudagraphs"):
            for jfw in ("jax", "jax-scan"):
                worst = None
                for key, r in idx.items():
                    if key[0] == fw and key[1] == "td3" and key[3] == task and key[4] == size:
                        j = idx.get((jfw, *key[1:]))
                        if j:
                            m = _ratio(r, j)[0]
                            worst = m if worst is None else max(worst, m)
                if worst is not None:
                    res.append(dict(target=f"{FW_LABEL[fw]} / {FW_LABEL[jfw]} ≤ 1.5× (worst TD3 case)",
                                    task=task, value=f"{worst:.2f}×", met=worst <= TARGETS["torch_over_jax"]))
    return res


def _targets_section(idx, tasks, fws, size, steps, integrators) -> list[str]:
    res = targets(idx, tasks, fws, size, steps, integrators)
    if not res:
        return []
    out = [f"### Design targets (set for the `paper` size on an H200), size `{size}`", "",
           "| target | task | this run | met |", "|---|---|---|---|"]
    out += [f"| {r['target']} | {r['task']} | {r['value']} | {'yes' if r['met'] else 'no'} |" for r in res]
    return out + [""]


# ------------------------------------------------------------------------------------------------ plot
def plot(rows: list[dict], path: Path, title: str = "") -> None:
    """Plot update time against denoising steps per framework (the paper's Figure 2c).

    One panel per (task, algo, size); midpoint solid, Euler dashed, vanilla dotted.

    Args:
        rows: the run's rows.
        path: the PNG file.
        title: the figure's title.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    idx = _index(rows)
    tasks, algos, fws, sizes, steps, integrators, _ = _groups(rows)
    panels = [(t, a, s) for s in sizes for t in tasks for a in algos
              if any(r["task"] == t and r["algo"] == a and r["size"] == s for r in rows)]
    if not panels:
        return
    ncol = len(panels) if len(panels) <= 2 else 2 if len(panels) <= 4 else 3
    nrow = math.ceil(len(panels) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.4 * nrow), squeeze=False)
    colors = {"jax": "tab:blue", "jax-scan": "tab:purple", "torch": "tab:red",
              "torch-compile": "tab:orange", "torch-cudagraphs": "tab:green"}
    for ax, (task, algo, size) in zip(axes.flat, panels):
        for fw in fws:
            c = colors.get(fw, None)
            for integ, ls, mk in (("midpoint", "-", "o"), ("euler", "--", "s")):
                pts = sorted((k[5], r["median_ms"], r["q25_ms"], r["q75_ms"]) for k, r in idx.items()
                             if k[:5] == (fw, algo, "sf2", task, size) and k[6] == integ)
                if pts:
                    x = [p[0] for p in pts]
                    y = [p[1] for p in pts]
                    err = [[p[1] - p[2] for p in pts], [p[3] - p[1] for p in pts]]
                    ax.errorbar(x, y, yerr=err, color=c, ls=ls, marker=mk, ms=4, capsize=2,
                                label=f"{FW_LABEL.get(fw, fw)} SF² {integ}")
            van = idx.get((fw, algo, "none", task, size, 0, ""))
            if van:
                ax.axhline(van["median_ms"], color=c, ls=":", lw=1.2, label=f"{FW_LABEL.get(fw, fw)} vanilla")
        ax.set_xscale("log", base=2)
        ax.set_xticks(steps or [1])
        ax.set_xticklabels([str(s) for s in steps] or ["1"])
        ax.set_yscale("log")
        ax.set_xlabel("denoising steps T")
        ax.set_ylabel("ms per update")
        D, A = TASKS[task]
        ax.set_title(f"{task} (D={D}, A={A}) {algo.upper()} [{size}]", fontsize=9)
        ax.grid(alpha=0.3, which="both")
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    legend = {}
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(lab, h)
    fig.suptitle(title or "SGD update time versus denoising steps", fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.legend(list(legend.values()), list(legend), loc="center left", bbox_to_anchor=(1.0, 0.5),
               fontsize=8, frameon=False)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


# ------------------------------------------------------------------------------------------ re-render
def render(out_dir: Path) -> None:
    """Re-write updates.md and updates.png from a results folder's updates.csv and machine.json.

    Args:
        out_dir: the results folder (its flow_step.md, if any, is appended).
    """
    rows = read_csv(out_dir / "updates.csv")
    machine = json.loads((out_dir / "machine.json").read_text())
    extra = (out_dir / "flow_step.md").read_text() if (out_dir / "flow_step.md").exists() else ""
    (out_dir / "updates.md").write_text(markdown(rows, machine, extra=_strip_title(extra)))
    plot(rows, out_dir / "updates.png", title=f"SF² update time, {machine.get('name', '')}")


def _strip_title(md: str) -> str:
    return "\n".join(line for line in md.splitlines() if not line.startswith("# "))

