"""Study files: a TOML file declaring tasks × methods × seeds (paper §4.2, Appendix C), parsed and checked
without any framework (`load`), then resolved against a framework's configs (`resolve`) before anything is
compiled. Every problem is a `StudyError` naming the file, the entry and the valid choices.

The format (methods, sweeps, seed groups, [evaluation], [report], [[claims]]) is documented in
docs/study-files.md."""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import sys
from collections.abc import Callable
from pathlib import Path

from sf2_common.agents.configs import EXECUTION_FIELDS
from sf2_common.errors import ConfigError

from .base import StudyError, seeds_text

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10: the backport (a dependency of sf2-common there)
    import tomli as tomllib

__all__ = [
    "StudyError", "Method", "Evaluation", "ReportSettings", "Study", "Run", "load", "loads", "resolve",
    "select_runs", "same_runs", "only_adds", "changed_methods", "seeds_text",
    "slug", "kind", "FIGURES", "FRAMEWORKS", "RUN_NEUTRAL",
]

FRAMEWORKS = ("jax", "torch")
FIGURES = ("aggregate", "curves", "sweeps", "obs_noise")
_TOP = ("name", "description", "framework", "preset", "seeds", "seeds_per_run", "tasks", "budget",
        "overrides", "methods", "sweeps", "evaluation", "report", "claims")
# Keys that change what a report says but no run: a study folder accepts a study file that differs from its
# copy only in these (folder.py, merge.py), so claims and report settings can be added to a running study.
RUN_NEUTRAL = ("description", "report", "claims")
_METHOD = ("label", "name", "algo", "representation", "overrides", "framework")
_SWEEP = ("field", "values", "title", "methods")
_EVALUATION = ("obs_noise", "checkpoints", "episodes", "deterministic")
_REPORT = ("figures", "final_window", "curve_statistic", "sweep_score")
CURVE_STATISTICS = ("mean", "median")   # over seeds at each evaluation (figures.learning_curves)
# a sweep's point: the mean final-window return over seeds (Fig. 2), or the IQM of the normalized AUC (Fig. 9)
SWEEP_SCORES = ("final_return", "iqm_auc")
DEFAULT_FINAL_WINDOW = 50_000   # paper §4.3: "the mean episode return over the final 50k steps"


def slug(label: str) -> str:
    """'TD3+SF² (γ=0.99)' → 'td3-sf2-g0.99': a folder name from a label."""
    text = label.replace("²", "2").replace("γ", "g").replace("τ", "tau").replace("σ", "s").lower()
    text = re.sub(r"[^a-z0-9.]+", "-", text)
    return re.sub(r"-+", "-", text).strip("-.") or "method"


def kind(label: str, family: str) -> str:
    """A method label without its family: 'TD3+SF² (γ=0)' → 'SF² (γ=0)', 'SAC' → 'vanilla' (what a method
    is across families: the figures' colors, `study compare`'s rows)."""
    rest = label[len(family):] if label.startswith(family) else label
    return rest.lstrip("+") or "vanilla"


@dataclasses.dataclass(frozen=True)
class Method:
    label: str
    name: str                          # folder name under runs/<task>/
    algo: str
    representation: str
    overrides: tuple[tuple[str, str], ...]   # (field, value as the CLI's --set takes it)
    sweep: tuple[str, str, str] | None = None  # (field, value, base label) of a sweep's method
    framework: str | None = None       # the core it trains on; None: the one running the study

    @property
    def family(self) -> str:
        """'TD3' or 'SAC': the algorithm family the aggregates are grouped by (paper Fig. 1)."""
        return self.algo.upper()

    @property
    def kind(self) -> str:
        """The label without the family (`kind`)."""
        return kind(self.label, self.family)


@dataclasses.dataclass(frozen=True)
class Evaluation:
    obs_noise: tuple[float, ...]
    checkpoints: int
    episodes: int | None
    deterministic: bool | None


@dataclasses.dataclass(frozen=True)
class ReportSettings:
    figures: tuple[str, ...]
    final_window: int
    sweeps: tuple[tuple[str, str], ...]     # (field, title) in file order
    curve_statistic: str = "mean"           # `CURVE_STATISTICS`
    sweep_score: str = "final_return"       # `SWEEP_SCORES`


@dataclasses.dataclass(frozen=True)
class Study:
    path: Path
    text: str                   # the file's text (the study folder keeps a copy)
    data: dict                  # the parsed TOML
    name: str
    description: str
    framework: str | None
    preset: str
    seeds: tuple[int, ...]
    tasks: tuple[str, ...]
    overrides: tuple[tuple[str, str], ...]
    methods: tuple[Method, ...]
    evaluation: Evaluation | None
    report: ReportSettings
    # None: one run over every seed; an int: consecutive chunks; a tuple of seed tuples: those groups
    seeds_per_run: int | tuple[tuple[int, ...], ...] | None = None
    claims: tuple = ()                    # claims.Claim: the paper's claims the report checks (claims.py)

    def runs_data(self) -> dict:
        """The parsed file without its `RUN_NEUTRAL` keys and without the overrides of
        `configs.EXECUTION_FIELDS` (how a run's program executes; its run folder resumes under either value):
        what decides the runs."""
        def without(table):
            if not isinstance(table, dict) or not isinstance(table.get("overrides"), dict):
                return table
            kept = {k: v for k, v in table["overrides"].items() if k not in EXECUTION_FIELDS}
            rest = {k: v for k, v in table.items() if k != "overrides"}
            return rest | ({"overrides": kept} if kept else {})

        data = without({k: v for k, v in self.data.items() if k not in RUN_NEUTRAL})
        if isinstance(data.get("methods"), list):
            data["methods"] = [without(m) for m in data["methods"]]
        return data

    def seed_groups(self) -> tuple[tuple[int, ...], ...]:
        """The seeds of each run of a (task, method): consecutive chunks of `seeds_per_run` seeds in file
        order, or all seeds in one group without it."""
        if isinstance(self.seeds_per_run, tuple):
            return self.seeds_per_run
        n = self.seeds_per_run or len(self.seeds)
        return tuple(self.seeds[i:i + n] for i in range(0, len(self.seeds), n))

    @property
    def groups_text(self) -> str:
        """How the study groups its seeds, for messages: 'seeds_per_run = 5', 'seed groups 0-4, 5-14'."""
        if self.seeds_per_run is None:
            return "no seeds_per_run: all seeds are one run"
        if isinstance(self.seeds_per_run, tuple):
            return "seed groups " + ", ".join(seeds_text(g) for g in self.seeds_per_run)
        return f"seeds_per_run = {self.seeds_per_run}"

    def group_folder(self, seeds) -> str | None:
        """The run folder of a seed group under runs/<task>/<method>/: 'seeds-0-4' ('seeds-0_2_4' for
        seeds 0, 2, 4); None without `seeds_per_run` (the method's folder is the run's)."""
        return None if self.seeds_per_run is None else seeds_folder(seeds)

    def select_groups(self, seeds=None) -> tuple[tuple[int, ...], ...]:
        """The seed groups wholly inside `seeds` (a `--seeds` text such as "0-4", or a sequence of ints;
        None: every group); `StudyError` naming the groups if none is."""
        groups = self.seed_groups()
        if seeds is None:
            return groups
        from sf2_common.agents.configs import parse_seeds

        try:
            wanted = set(parse_seeds(seeds) if isinstance(seeds, str) else seeds)
        except ConfigError as err:
            raise StudyError(f"--seeds: {err}") from None
        chosen = tuple(g for g in groups if wanted.issuperset(g))
        if not chosen:
            text = seeds if isinstance(seeds, str) else seeds_text(sorted(wanted))
            per = self.groups_text
            names = ", ".join(seeds_text(g) for g in groups)
            raise StudyError(f"--seeds {text}: no seed group of study {self.name!r} ({self.path}) lies "
                             f"wholly inside it ({per}); its groups: {names}")
        return chosen

    def method(self, label_or_name: str) -> Method:
        for m in self.methods:
            if label_or_name in (m.label, m.name):
                return m
        raise StudyError(f"{self.path}: no method {label_or_name!r}; methods: "
                         f"{', '.join(m.name for m in self.methods)}")

    def select(self, tasks=None, methods=None) -> list[tuple[str, Method]]:
        """The (task, method) pairs of the study, filtered by task names and method names or labels
        (None: all); an unknown name is a `StudyError` listing the valid ones."""
        for given, valid, what in ((tasks, self.tasks, "task"),
                                   (methods, [m.name for m in self.methods], "method")):
            for g in given or ():
                if g not in valid and not (what == "method" and any(m.label == g for m in self.methods)):
                    raise StudyError(f"--{what}s: {g!r} is not a {what} of study {self.name!r} "
                                     f"({self.path}); valid: {', '.join(valid)}")
        return [(t, m) for t in self.tasks if not tasks or t in tasks for m in self.methods
                if not methods or m.name in methods or m.label in methods]


@dataclasses.dataclass(frozen=True)
class Run:
    """One training program: a task, the methods it serves (more than one when configs coincide), the
    resolved config (a `TrainConfig` of the framework) and the seeds it trains (a seed group)."""

    task: str
    folder: str              # the method's folder: runs/<task>/<folder>
    methods: tuple[Method, ...]
    config: object
    argv: tuple[str, ...]    # the `train` arguments after `--out DIR`
    seeds: tuple[int, ...]
    group: str | None = None  # the seed group's folder under the method's ('seeds-0-4'), or None
    cli_module: str | None = None   # the CLI its children run; None: the running core's

    @property
    def rel(self) -> str:
        """The run folder relative to runs/<task>/: '<method>' or '<method>/seeds-0-4'."""
        return self.folder if self.group is None else f"{self.folder}/{self.group}"


# ------------------------------------------------------------------------------------------- parsing
def load(path) -> Study:
    """Parse and check the study file `path` (no framework needed). Raises `StudyError`."""
    path = Path(path)
    if not path.is_file():
        raise StudyError(f"study file {path} does not exist")
    return loads(path.read_text(encoding="utf-8"), path)


def loads(text: str, path="<study>") -> Study:
    path = Path(path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise StudyError(f"{path}: not valid TOML: {err}") from None
    where = str(path)

    def fail(entry: str, problem: str):
        raise StudyError(f"{where}: {entry}: {problem}")

    _known(data, _TOP, where, "top level")
    name = data.get("name")
    if not isinstance(name, str) or not name.strip():
        fail("name", "a non-empty string is required, e.g. name = \"fig7-td3\"")
    framework = data.get("framework")
    if framework is not None and framework not in FRAMEWORKS:
        fail("framework", f"{framework!r} is not one of {', '.join(FRAMEWORKS)} (or leave it out: any)")
    preset = data.get("preset", "quick")
    from sf2_common.agents.configs import PRESETS, parse_seeds

    if preset not in PRESETS:
        fail("preset", f"{preset!r} is not one of {', '.join(PRESETS)}")
    try:
        seeds = parse_seeds(data.get("seeds", "0"))
    except ConfigError as err:
        fail("seeds", str(err))
    per_run = _seed_groups(data.get("seeds_per_run"), seeds, fail)
    tasks = data.get("tasks")
    if not isinstance(tasks, list) or not tasks or not all(isinstance(t, str) for t in tasks):
        fail("tasks", "a non-empty list of task names is required, e.g. tasks = [\"CartpoleBalance\"]")
    if len(set(tasks)) != len(tasks):
        fail("tasks", f"{tasks} names a task twice")
    overrides = dict(_overrides(data.get("overrides", {}), where, "overrides"))
    budget = data.get("budget", "preset")
    if budget != "preset":
        if isinstance(budget, bool) or not isinstance(budget, int) or budget < 1:
            fail("budget", f"{budget!r} is invalid: an int number of env steps, or \"preset\"")
        if "num_timesteps" in overrides:
            fail("budget", "given twice (budget and overrides.num_timesteps)")
        overrides["num_timesteps"] = str(budget)

    methods = [_method(m, where, f"methods[{i}]") for i, m in enumerate(_tables(data, "methods", where))]
    sweeps = []
    for i, s in enumerate(_tables(data, "sweeps", where)):
        entry = f"sweeps[{i}]"
        _known(s, _SWEEP, where, entry)
        field = s.get("field")
        if not isinstance(field, str) or not field:
            fail(entry, "field: the config field swept, e.g. field = \"tau_zeta\"")
        values = s.get("values")
        if not isinstance(values, list) or not values:
            fail(entry, "values: a non-empty list, e.g. values = [0.01, 0.1]")
        title = s.get("title", field)
        sweeps.append((field, str(title)))
        bases = s.get("methods")
        if not isinstance(bases, list) or not bases:
            fail(entry, "methods: a non-empty list of methods (label, algo, representation)")
        for j, b in enumerate(bases):
            base = _method(b, where, f"{entry}.methods[{j}]")
            if field in dict(base.overrides):
                fail(f"{entry}.methods[{j}]", f"overrides the swept field {field!r}")
            for v in values:
                value = _value_text(v, where, f"{entry}.values")
                label = f"{base.label} ({field}={value})"
                methods.append(dataclasses.replace(
                    base, label=label, name=f"{base.name}-{slug(field)}-{slug(value)}",
                    overrides=base.overrides + ((field, value),), sweep=(field, value, base.label)))
    if not methods:
        fail("methods", "the study declares no method ([[methods]] or [[sweeps]])")
    for attr in ("label", "name"):
        seen = {}
        for m in methods:
            key = getattr(m, attr)
            if key in seen:
                fail("methods", f"the {attr} {key!r} is used twice ({seen[key]!r} and {m.label!r}); "
                     f"every method needs its own {attr}")
            seen[key] = m.label

    evaluation = _evaluation(data.get("evaluation"), where)
    report = _report(data.get("report", {}), where, sweeps, evaluation)
    from .claims import parse as parse_claims

    claims = parse_claims(data.get("claims"), where, methods, tasks, evaluation)
    return Study(path=path, text=text, data=data, name=name.strip(),
                 description=str(data.get("description", "")), framework=framework, preset=preset,
                 seeds=seeds, tasks=tuple(tasks), overrides=tuple(overrides.items()), methods=tuple(methods),
                 evaluation=evaluation, report=report, seeds_per_run=per_run, claims=claims)


def _seed_groups(value, seeds, fail):
    """`seeds_per_run`: None, an int from 1 to len(seeds), or a list of seed groups (texts such as "0-4" or
    lists of ints) that split `seeds`, each seed in exactly one group; returned as a tuple of tuples."""
    if value is None:
        return None
    if isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= len(seeds):
        return value
    usage = (f"an int from 1 to {len(seeds)} (the number of seeds {seeds_text(seeds)}), e.g. seeds_per_run = "
             f"5, or the groups, e.g. seeds_per_run = [\"0-4\", \"5-14\"]; leave it out to train all seeds "
             f"in one run")
    if not isinstance(value, list) or not value:
        fail("seeds_per_run", f"{value!r} is invalid: {usage}")
    from sf2_common.agents.configs import parse_seeds

    groups = []
    for g in value:
        try:
            groups.append(tuple(parse_seeds(g)))
        except (ConfigError, TypeError, ValueError) as err:
            fail("seeds_per_run", f"group {g!r} is invalid ({err}): {usage}")
    flat = [s for g in groups for s in g]
    if sorted(flat) != sorted(seeds) or len(set(flat)) != len(flat):
        twice = sorted({s for s in flat if flat.count(s) > 1})
        missing = sorted(set(seeds) - set(flat))
        extra = sorted(set(flat) - set(seeds))
        names = ", ".join(seeds_text(g) for g in groups)
        fail("seeds_per_run", f"the groups {names} do not split the study's "
             f"seeds {seeds_text(seeds)} (each seed in one group)"
             + (f"; in two groups: {seeds_text(twice)}" if twice else "")
             + (f"; in no group: {seeds_text(missing)}" if missing else "")
             + (f"; not seeds of the study: {seeds_text(extra)}" if extra else ""))
    return tuple(groups)


def same_runs(old: Study, new: Study, kept_groups, refit=frozenset()) -> list[str]:
    """The keys (`runs_data`) in which `new` declares other runs than `old`, a study folder's copy: [] when
    they are the same study. `new` may add tasks and methods (`_grows`), and rewrite the methods named in
    `refit` (those whose runs in the folder are runs of `new`'s method of that name: `changed_methods`);
    their seed groups may differ when the folder holds no run folder (`kept_groups`, the groups it holds
    run folders of, is empty), or when both group their seeds and every group of `kept_groups` is a group
    of `new` too."""
    mine, theirs = old.runs_data(), new.runs_data()
    keys = sorted(k for k in set(mine) | set(theirs)
                  if mine.get(k) != theirs.get(k) and not _grows(k, mine.get(k), theirs.get(k), refit))
    kept = set(kept_groups)
    if keys == ["seeds_per_run"] and (not kept or (old.seeds_per_run is not None and new.seeds_per_run
                                                   is not None and kept <= set(new.seed_groups()))):
        return []
    return keys


def only_adds(old: Study, new: Study, refit=frozenset()) -> bool:
    """True when `new` declares `old`'s runs plus tasks or methods of its own, nothing else changed (but the
    methods named in `refit`, as in `same_runs`)."""
    mine, theirs = old.runs_data(), new.runs_data()
    keys = [k for k in set(mine) | set(theirs) if mine.get(k) != theirs.get(k)]
    return bool(keys) and all(_grows(k, mine.get(k), theirs.get(k), refit) for k in keys)


def changed_methods(old: Study, new: Study) -> set[str]:
    """The names of `old`'s methods that `new` declares under the same name with another table (a label,
    an override pinning a preset value that has changed since): `refit` candidates."""
    theirs = {_name(m): m for m in new.runs_data().get("methods", [])}
    return {_name(m) for m in old.runs_data().get("methods", [])
            if _name(m) in theirs and theirs[_name(m)] != m}


def _name(table) -> str | None:
    """The name of a method table as `_method` gives it (its `name`, else its label's slug)."""
    if not isinstance(table, dict):
        return None
    return table.get("name", slug(str(table.get("label", "")).strip()))


def _grows(key: str, old, new, refit=frozenset()) -> bool:
    """True when `new` only adds to `old`'s tasks or methods: every task, and every method table exactly as it
    was (or a method of `refit` under its name), is still there, so the runs a folder holds stay runs of the
    study (a method added to a study under way, e.g. an ablation, runs beside the finished ones)."""
    if key == "tasks" and isinstance(old, list) and isinstance(new, list):
        return set(old) <= set(new)
    if key == "methods" and isinstance(old, list) and isinstance(new, list):
        names = {_name(m) for m in new}
        return all(m in new or (_name(m) in refit and _name(m) in names) for m in old)
    return False


def _known(table, valid, where: str, entry: str) -> None:
    if not isinstance(table, dict):
        raise StudyError(f"{where}: {entry}: expected a table, got {table!r}")
    for key in table:
        if key not in valid:
            close = difflib.get_close_matches(key, valid, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise StudyError(f"{where}: {entry}: unknown key {key!r}{hint}; valid keys: {', '.join(valid)}")


def _tables(data: dict, key: str, where: str) -> list:
    value = data.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise StudyError(f"{where}: {key}: expected an array of tables ([[{key}]])")
    return value


def _value_text(value, where: str, entry: str) -> str:
    """A TOML value as the CLI's `--set field=VALUE` takes it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise StudyError(f"{where}: {entry}: {value!r} is not a finite number")
        return repr(value)
    if isinstance(value, str):
        return value
    if isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) for v in value):
        return ",".join(str(v) for v in value)
    raise StudyError(f"{where}: {entry}: {value!r} is not a number, bool, string or list of ints")


def _overrides(table, where: str, entry: str) -> tuple[tuple[str, str], ...]:
    if not isinstance(table, dict):
        raise StudyError(f"{where}: {entry}: expected a table of config fields, e.g. {{ gamma_su = 0.0 }}")
    for key in ("task", "algo", "representation"):
        if key in table:
            raise StudyError(f"{where}: {entry}: {key!r} is not an override: it is the study's "
                             f"{'tasks' if key == 'task' else 'method ' + key}")
    return tuple((k, _value_text(v, where, f"{entry}.{k}")) for k, v in table.items())


def _method(table, where: str, entry: str) -> Method:
    _known(table, _METHOD, where, entry)
    for key in ("label", "algo", "representation"):
        if not isinstance(table.get(key), str) or not table[key].strip():
            raise StudyError(f"{where}: {entry}: {key} is required (a string), e.g. label = \"TD3+SF²\", "
                             f"algo = \"td3\", representation = \"sf2\"")
    label = table["label"].strip()
    name = _name(table)
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]*", name):
        raise StudyError(f"{where}: {entry}: name {name!r} is not a folder name (letters, digits, . _ -)")
    framework = table.get("framework")
    if framework is not None and framework not in FRAMEWORKS:
        raise StudyError(f"{where}: {entry}: framework = {framework!r} is not one of {', '.join(FRAMEWORKS)} "
                         f"(or leave it out: the core that runs the study)")
    return Method(label=label, name=name, algo=table["algo"].strip(),
                  representation=table["representation"].strip(),
                  overrides=_overrides(table.get("overrides", {}), where, f"{entry}.overrides"),
                  framework=framework)


def _evaluation(table, where: str) -> Evaluation | None:
    if table is None:
        return None
    _known(table, _EVALUATION, where, "evaluation")
    noise = table.get("obs_noise")
    if (not isinstance(noise, list) or not noise
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and x >= 0 for x in noise)):
        raise StudyError(f"{where}: evaluation.obs_noise: a non-empty list of noise stds >= 0, e.g. "
                         f"[0.0, 0.05, 0.1, 0.2]")
    checkpoints = table.get("checkpoints", 1)
    episodes = table.get("episodes")
    for key, value in (("checkpoints", checkpoints), ("episodes", episodes)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise StudyError(f"{where}: evaluation.{key} = {value!r} is invalid: an int >= 1")
    deterministic = table.get("deterministic")
    if deterministic is not None and not isinstance(deterministic, bool):
        raise StudyError(f"{where}: evaluation.deterministic = {deterministic!r} is invalid: true or false")
    return Evaluation(tuple(float(x) for x in noise), checkpoints, episodes, deterministic)


def _report(table, where: str, sweeps, evaluation) -> ReportSettings:
    _known(table, _REPORT, where, "report")
    default = ["aggregate", "curves"] + (["sweeps"] if sweeps else []) + (["obs_noise"] if evaluation else [])
    figures = table.get("figures", default)
    if not isinstance(figures, list) or any(f not in FIGURES for f in figures):
        raise StudyError(f"{where}: report.figures = {figures!r} is invalid: a list of {', '.join(FIGURES)}")
    if "sweeps" in figures and not sweeps:
        raise StudyError(f"{where}: report.figures asks for 'sweeps' but the study declares no [[sweeps]]")
    if "obs_noise" in figures and evaluation is None:
        raise StudyError(f"{where}: report.figures asks for 'obs_noise' but the study has no [evaluation]")
    window = table.get("final_window", DEFAULT_FINAL_WINDOW)
    if isinstance(window, bool) or not isinstance(window, int) or window < 0:
        raise StudyError(f"{where}: report.final_window = {window!r} is invalid: an int >= 0 (env steps)")
    statistic = table.get("curve_statistic", "mean")
    if statistic not in CURVE_STATISTICS:
        raise StudyError(f"{where}: report.curve_statistic = {statistic!r} is invalid: one of "
                         f"{', '.join(repr(s) for s in CURVE_STATISTICS)}")
    score = table.get("sweep_score", "final_return")
    if score not in SWEEP_SCORES:
        raise StudyError(f"{where}: report.sweep_score = {score!r} is invalid: one of "
                         f"{', '.join(repr(s) for s in SWEEP_SCORES)}")
    return ReportSettings(tuple(figures), window, tuple(sweeps), statistic, score)


# ------------------------------------------------------------------------------------------- resolution
def resolve(study: Study, make_config: Callable, validate: Callable,
            backend_of: Callable | None = None) -> list[Run]:
    """The runs of `study`: each method's config on each task,
    built with the framework's `make_config(preset, task, algo, representation, overrides)` and checked
    with its `validate(cfg, seeds)`, before anything is compiled; a method with its own `framework` uses
    `backend_of(framework)`'s (a `sf2_common.cli.Backend`) and runs that core's CLI. Methods with identical
    configs on a task share one run (the first one's folder). Raises `StudyError` naming the file and the
    entry."""
    where = study.path
    from sf2_common.agents import tasks as task_table

    for i, task in enumerate(study.tasks):
        try:
            task_table.validate_task(task)
        except ConfigError as err:
            raise StudyError(f"{where}: tasks[{i}]: {err}") from None
    runs: dict[tuple[str, str], Run] = {}   # (task, config) → the run over every seed
    order = []
    for task, method in study.select():
        overrides = dict(study.overrides)
        overrides.update(method.overrides)
        make, check, cli_module = make_config, validate, None
        try:
            if method.framework is not None:
                if backend_of is None:
                    raise ConfigError(f"framework = {method.framework!r} needs the command of a core")
                other = backend_of(method.framework)
                make, check, cli_module = other.make_config, other.validate, other.cli_module
            cfg = make(study.preset, task, method.algo, method.representation, overrides)
            cfg = check(cfg, study.seeds)
        except ConfigError as err:
            raise StudyError(f"{where}: method {method.label!r} on task {task}: {err}") from None
        key = (task, cli_module, _config_key(cfg))
        if key in runs:
            old = runs[key]
            if method.sweep is None and all(m.sweep is None for m in old.methods):
                raise StudyError(f"{where}: methods {old.methods[0].label!r} and {method.label!r} train the "
                                 f"same config on {task}; remove one of them")
            runs[key] = dataclasses.replace(old, methods=old.methods + (method,))
            continue
        argv = ("--task", task, "--algo", method.algo, "--repr", method.representation,
                "--config", study.preset, "--seeds", seeds_text(study.seeds),
                *[a for k, v in overrides.items() for a in ("--set", f"{k}={v}")])
        runs[key] = Run(task=task, folder=method.name, methods=(method,), config=cfg, argv=argv,
                        seeds=study.seeds, cli_module=cli_module)
        order.append(key)
    return [group for k in order for group in _split(study, runs[k])]


def _split(study: Study, run: Run) -> list[Run]:
    """A run over every seed as the runs of the study's seed groups (itself without `seeds_per_run`)."""
    if study.seeds_per_run is None:
        return [run]
    i = run.argv.index("--seeds") + 1
    return [dataclasses.replace(run, seeds=g, group=study.group_folder(g),
                                argv=run.argv[:i] + (seeds_text(g),) + run.argv[i + 1:])
            for g in study.seed_groups()]


def select_runs(study: Study, runs: list[Run], tasks=None, methods=None, seeds=None) -> list[Run]:
    """The runs serving a (task, method) pair of `study.select(tasks, methods)` whose seed group lies
    wholly inside `seeds` (`Study.select_groups`; None: every group)."""
    wanted = {(t, m.name) for t, m in study.select(tasks, methods)}
    groups = set(study.select_groups(seeds))
    return [r for r in runs if any((r.task, m.name) in wanted for m in r.methods) and r.seeds in groups]


def seeds_folder(seeds) -> str:
    """The folder name of a seed group: (0, 1, 2, 3, 4) → 'seeds-0-4', (0, 2, 4) → 'seeds-0_2_4'."""
    return "seeds-" + seeds_text(seeds).replace(",", "_")


def _config_key(cfg) -> str:
    import json

    return json.dumps(cfg.to_dict(), sort_keys=True)
