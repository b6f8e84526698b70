"""`TrainConfig`: everything one training run needs, the `paper` and `quick` presets (data: `PRESETS`,
why: docs/decisions/presets.md), CLI overrides, the `Schedule`, and validation that fails before any
compilation naming the field, the value and what is valid. Each core's `agents.configs` binds
`make_config` and `validate` to its own `TrainConfig` (torch: a subclass) and registry. The SF² fields are
`SF2Config`'s minus the task's sizes; `--algo ppo` adds PPO's (`PPO_VALUES`, docs/minatar.md).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import typing
from dataclasses import dataclass, fields

from sf2_common.config import INTEGRATORS, SF2Config
from sf2_common.errors import ConfigError

from . import tasks

__all__ = [
    "TrainConfig", "PRESETS", "ALGOS", "SF2_FIELDS", "make_config", "parse_overrides", "parse_value",
    "parse_seeds", "validate", "Schedule", "schedule", "ConfigError", "bad_field", "LEARNER_PRECISIONS",
    "ADDED_FIELDS", "PAPER_ADAM_EPS", "SUPERSEDED", "superseded_values", "TASK_VALUES", "FAMILY_VALUES",
    "REPRESENTATION_VALUES", "ONPOLICY_ALGOS", "CRITICS", "ADVANTAGE_REFRESH", "PPO_FIELDS", "PPO_VALUES",
    "FPO_FIELDS", "FPO_VALUES", "PHYSICS", "SEED_LOOPS", "EXECUTION_FIELDS", "READ_BY",
]

ALGOS = ("td3", "sac", "ppo", "fpo", "crl")
ONPOLICY_ALGOS = ("ppo", "fpo")   # the on-policy trainer's (sf2_jax.agents.onpolicy); the others off-policy
CRITICS = ("q", "v")        # PPO's critic: Q(s, a) with λ-returns (PPO-Q), or V(s) with GAE (PPO)
# `physics`: the simulator pipeline; "spring" (Brax's, JaxGCRL's for `ant`) only for ant-goal (docs/crl.md)
PHYSICS = ("mjx", "spring")
# `seed_loop`: how the on-policy trainer's program runs the seeds, batched by `jax.vmap` or one after another
# by `jax.lax.map` (sf2_jax.agents.trainer._seed_map); its evaluation and the other trainers (and torch's)
# always vmap
SEED_LOOPS = ("vmap", "map")
# Fields that set how a run's program executes, not what it computes (the same numbers up to float rounding,
# tested): a run folder resumes under either value and keeps the one it started with in its config.json
EXECUTION_FIELDS = ("seed_loop",)
# `learner_precision` → JAX's matmul precision (torch: TF32, bf16 autocast); docs/core-contract.md
LEARNER_PRECISIONS = {"highest": "highest", "tensorfloat32": "tensorfloat32", "bfloat16": "BF16_BF16_F32"}
_SF2_DEFAULTS = {f.name: f.default for f in fields(SF2Config)}
# Fields added after run folders were written, with the value every older run trained with (and PPO's below)
ADDED_FIELDS = {name: _SF2_DEFAULTS[name] for name in ("spr_augmentation_std", "shared_adam",
                                                        "aux_steps_per_sgd_step")}
SF2_FIELDS = tuple(name for name in _SF2_DEFAULTS if name not in ("obs_size", "action_size"))
PPO_FIELDS = ("rollout_length", "update_epochs", "minibatch_size", "clip_eps", "entropy_coef", "value_coef",
              "max_grad_norm", "td_lambda", "critic", "advantage_refresh", "shared_torso")
ADVANTAGE_REFRESH = ("rollout", "pass")   # advantages from the rollout-time critic, or the current one
FPO_FIELDS = ("fpo_samples", "fpo_flow_steps", "fpo_value_samples", "fpo_log_ratio_clip")
# Fields that only some algos' trainers read, field -> those algos (every other field is read by every algo,
# or depends on the representation; `seed_loop` and `shared_torso` have checks of their own): an override
# that changes one for another algo is refused (`make_config`)
READ_BY = {
    **dict.fromkeys((f for f in PPO_FIELDS if f != "shared_torso"), ONPOLICY_ALGOS),
    **dict.fromkeys(FPO_FIELDS, ("fpo",)),
    **dict.fromkeys(("logsumexp_penalty", "contrastive_loss", "flow_feature_norm"), ("crl",)),
    **dict.fromkeys(("batch_size", "grad_updates_per_step", "min_replay_size", "max_replay_size"),
                    ("td3", "sac", "crl")),
    **dict.fromkeys(("exploration_noise", "noise_clip", "smoothing_noise"), ("td3",)),
    "policy_delay": ("td3", "sac"),
    **dict.fromkeys(("alpha_learning_rate", "target_entropy_scale", "init_log_alpha"), ("sac", "crl")),
}
# Adam's ε as the authors' trainers build it (SAC: optax's default; the temperature's is 1e-8 always)
PAPER_ADAM_EPS = {"td3": 1e-5, "sac": 1e-8, "ppo": 1e-5, "fpo": 1e-8}
# Preset values changed since run folders were written, (algo, field) -> (old, new): such folders keep theirs
SUPERSEDED = {("sac", "adam_eps"): (1e-5, PAPER_ADAM_EPS["sac"]),
              ("fpo", "advantage_refresh"): ("rollout", "pass"), ("crl", "shared_adam"): (False, True),
              ("crl", "flow_feature_norm"): ("none", "l2"),
              ("crl", "zeta_hidden_sizes"): ((256, 256), (128, 64))}
# Each preset's values, then its per-task, per-family and per-representation values, then the overrides
# (decisions/presets.md)
PRESETS = {
    "paper": dict(checkpoint_every=10, learner_precision="tensorfloat32"),
    "quick": dict(num_timesteps=80_000, num_envs=16, num_evals=9, num_eval_envs=10, deterministic_eval=True,
                  batch_size=128, grad_updates_per_step=8, min_replay_size=4096, max_replay_size=100_000,
                  feature_size=32, hidden_sizes=(64, 64), q_hidden_size=64, zeta_hidden_sizes=(64, 64),
                  embedding_size=16, tau=0.02),
}
# PPO's values per preset (`--algo ppo`): `paper` is pgx's MinAtar PPO example with the paper's γ = 0.9 and
# docs/minatar.md's networks; `quick` learns Breakout on a CPU in minutes
PPO_VALUES = {
    "paper": dict(num_envs=4096, rollout_length=128, update_epochs=3, minibatch_size=4096, learning_rate=3e-4,
                  clip_eps=0.2, entropy_coef=0.01, value_coef=0.5, max_grad_norm=0.5, td_lambda=0.95,
                  discount=0.9, gamma_su=0.9, num_evals=40, num_eval_envs=128, deterministic_eval=True,
                  shared_adam=False,
                  feature_size=256, hidden_sizes=(256, 256), q_hidden_size=256, zeta_hidden_sizes=(64, 64)),
    "quick": dict(num_timesteps=200_000, num_envs=32, rollout_length=32, update_epochs=2, minibatch_size=256,
                  learning_rate=1e-3, num_evals=11, num_eval_envs=64, discount=0.9, gamma_su=0.9,
                  shared_adam=False, feature_size=32, hidden_sizes=(64,), q_hidden_size=64,
                  zeta_hidden_sizes=(16,), embedding_size=8),
}
# FPO's values per preset (`--algo fpo`, Playground; docs/fpo.md): `paper` is the authors' FpoConfig (Brax's
# DM Control PPO settings; their 60M env steps as their loop runs them, 61 whole updates, an evaluation after
# each), no gradient clipping in effect;
# `quick` learns CartpoleBalance on a CPU in minutes
FPO_VALUES = {
    "paper": dict(num_timesteps=59_965_440, num_envs=2048, rollout_length=480, update_epochs=16,
                  minibatch_size=30_720, learning_rate=3e-4, clip_eps=0.05, entropy_coef=0.0, value_coef=0.5,
                  max_grad_norm=1e9, td_lambda=0.95, discount=0.995, reward_scaling=10.0, gamma_su=0.99,
                  num_evals=62, num_eval_envs=128, deterministic_eval=False, shared_adam=False,
                  normalize_observations=True, fpo_samples=8, fpo_flow_steps=10, fpo_value_samples=8,
                  fpo_log_ratio_clip=20.0, advantage_refresh="pass"),
    "quick": dict(num_timesteps=786_432, num_envs=64, rollout_length=32, update_epochs=8, minibatch_size=256,
                  learning_rate=1e-4, clip_eps=0.05, entropy_coef=0.0, value_coef=0.5, max_grad_norm=1e9,
                  td_lambda=0.95, discount=0.99, reward_scaling=10.0, gamma_su=0.99, num_evals=7,
                  num_eval_envs=16, deterministic_eval=True, shared_adam=False, fpo_samples=8,
                  fpo_flow_steps=10, fpo_value_samples=4, fpo_log_ratio_clip=20.0),
}
TASK_VALUES = {"paper": {"num_timesteps": tasks.paper_budget, "action_repeat": tasks.paper_action_repeat,
                         "episode_length": tasks.episode_length},
               "quick": {"action_repeat": tasks.paper_action_repeat, "episode_length": tasks.episode_length}}


def _by_algo(preset: str) -> dict:
    """{field: {algo: value}} of the on-policy algos' values of `preset`."""
    tables = {"ppo": PPO_VALUES[preset], "fpo": FPO_VALUES[preset]}
    names = dict.fromkeys(name for table in tables.values() for name in table)
    return {name: {algo: t[name] for algo, t in tables.items() if name in t} for name in names}


FAMILY_VALUES = {"paper": {"adam_eps": PAPER_ADAM_EPS, **_by_algo("paper")}, "quick": _by_algo("quick")}


@dataclass(frozen=True)
class TrainConfig:
    """One training run (all seeds share it). Frozen and hashable: it keys the compiled-program cache."""

    # what to train
    task: str = "CartpoleBalance"
    algo: str = "td3"
    representation: str = "sf2"
    # budget and environment (env steps count every physics step after action repeat, as Brax does)
    num_timesteps: int = 5_000_000
    episode_length: int = 1000
    action_repeat: int = 1
    # the simulator pipeline: MJX for the Playground tasks; ant-goal also "spring", JaxGCRL's (`PHYSICS`);
    # MinAtar and users' environments have no such choice and never read it
    physics: str = "mjx"
    num_envs: int = 128
    num_evals: int = 100          # evaluations including the one of the initial policy (Brax semantics)
    num_eval_envs: int = 128      # one episode per eval env
    deterministic_eval: bool = False
    # replay and updates
    batch_size: int = 512
    grad_updates_per_step: int = 8
    min_replay_size: int = 8192   # prefill with uniform random actions
    max_replay_size: int = 4_194_304
    normalize_observations: bool = True
    # on-policy updates (--algo ppo; docs/minatar.md): `rollout_length` steps of every env, then
    # `update_epochs` passes over them in minibatches of `minibatch_size` transitions
    rollout_length: int = 128
    update_epochs: int = 3
    minibatch_size: int = 4096
    clip_eps: float = 0.2         # PPO's ratio clip (and the V critic's value clip)
    entropy_coef: float = 0.01
    value_coef: float = 0.5       # the critic loss's weight
    max_grad_norm: float = 0.5    # each loss's gradient clipped to this global norm over what it trains
    td_lambda: float = 0.95       # λ of the critic's λ-returns and of the advantages
    critic: str = "q"             # "q": Q(s, a) and λ-returns (PPO-Q, SF²); "v": V(s) and GAE (PPO)
    advantage_refresh: str = "rollout"   # advantages from the rollout-time critic, or the current one
    shared_torso: bool = False    # pgx's one network: a torso under both heads, one loss, Adam state and clip
    seed_loop: str = "vmap"       # the on-policy program's seeds: "vmap" batched, "map" in turn (SEED_LOOPS)
    logsumexp_penalty: float = 0.1   # CRL's InfoNCE log-sum-exp penalty (--algo crl; docs/crl.md)
    contrastive_loss: str = "fwd"    # CRL's InfoNCE: "fwd" a row's goals, "bwd" a goal's state-actions, "sym"
    flow_feature_norm: str = "none"  # CRL+SF²: φ as SF²'s flow takes it, "none" or "l2" (φ/‖φ‖; docs/crl.md)
    # FPO (--algo fpo; docs/fpo.md): (ε, τ) pairs per action, Euler steps per action, actions per V_Q(s)
    fpo_samples: int = 8
    fpo_flow_steps: int = 10
    fpo_value_samples: int = 8
    fpo_log_ratio_clip: float = 20.0  # |mean ℓ_old − mean ℓ_new| bound before the exponential (inf: none)
    # networks and losses: the fields of SF2Config
    feature_size: int = _SF2_DEFAULTS["feature_size"]
    hidden_sizes: tuple[int, ...] = _SF2_DEFAULTS["hidden_sizes"]
    q_hidden_size: int = _SF2_DEFAULTS["q_hidden_size"]
    zeta_hidden_sizes: tuple[int, ...] = _SF2_DEFAULTS["zeta_hidden_sizes"]
    embedding_size: int = _SF2_DEFAULTS["embedding_size"]
    layer_norm: bool = _SF2_DEFAULTS["layer_norm"]
    gamma_su: float = _SF2_DEFAULTS["gamma_su"]
    denoising_steps: int = _SF2_DEFAULTS["denoising_steps"]
    integrator: str = _SF2_DEFAULTS["integrator"]
    contract_zeta: bool = _SF2_DEFAULTS["contract_zeta"]
    discount: float = _SF2_DEFAULTS["discount"]
    reward_scaling: float = _SF2_DEFAULTS["reward_scaling"]
    tau: float = _SF2_DEFAULTS["tau"]
    tau_zeta: float = _SF2_DEFAULTS["tau_zeta"]
    learning_rate: float = _SF2_DEFAULTS["learning_rate"]
    alpha_learning_rate: float = _SF2_DEFAULTS["alpha_learning_rate"]
    adam_eps: float = _SF2_DEFAULTS["adam_eps"]
    shared_adam: bool = _SF2_DEFAULTS["shared_adam"]   # ψ: one Adam state, TD and flow steps (authors')
    aux_steps_per_sgd_step: int = _SF2_DEFAULTS["aux_steps_per_sgd_step"]   # representation steps / SGD step
    smoothing_noise: float = _SF2_DEFAULTS["smoothing_noise"]
    noise_clip: float = _SF2_DEFAULTS["noise_clip"]
    exploration_noise: float = _SF2_DEFAULTS["exploration_noise"]
    policy_delay: int = _SF2_DEFAULTS["policy_delay"]
    min_std: float = _SF2_DEFAULTS["min_std"]
    target_entropy_scale: float = _SF2_DEFAULTS["target_entropy_scale"]
    init_log_alpha: float = _SF2_DEFAULTS["init_log_alpha"]
    normalizer_std_min: float = _SF2_DEFAULTS["normalizer_std_min"]
    normalizer_std_max: float = _SF2_DEFAULTS["normalizer_std_max"]
    spr_augmentation_std: float = _SF2_DEFAULTS["spr_augmentation_std"]   # σ of SPR's augmentation (App. B.1)
    # run management
    checkpoint_every: int = 1     # evaluations between checkpoints (the last one is always saved)
    keep_checkpoints: int = 2
    # the learner's matmuls (`LEARNER_PRECISIONS`; paper: tensorfloat32); the physics stays fp32 highest
    learner_precision: str = "highest"

    def sf2_config(self, obs_size: int, action_size: int) -> SF2Config:
        """The core's `SF2Config` of this run for a task with these sizes (validated)."""
        return SF2Config(obs_size=obs_size, action_size=action_size,
                         **{name: getattr(self, name) for name in SF2_FIELDS})

    def replace(self, **changes) -> TrainConfig:
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v)
                for f in fields(self)}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        d = dict(d)
        if "matmul_precision" in d and "learner_precision" not in d:   # a run folder's older name
            legacy = d.pop("matmul_precision")
            d["learner_precision"] = {"high": "tensorfloat32", "float32": "highest",
                                      "default": "bfloat16"}.get(legacy, legacy)
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(d) - set(known))
        if unknown:
            raise ConfigError(f"unknown config fields {unknown}; valid fields: {sorted(known)}")
        return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()})


ADDED_FIELDS.update({f.name: f.default for f in fields(TrainConfig) if f.name in PPO_FIELDS + FPO_FIELDS})
ADDED_FIELDS["logsumexp_penalty"] = TrainConfig.logsumexp_penalty
ADDED_FIELDS["contrastive_loss"] = TrainConfig.contrastive_loss
ADDED_FIELDS["flow_feature_norm"] = TrainConfig.flow_feature_norm
ADDED_FIELDS["physics"] = "mjx"   # every run before the field trained on MJX (ant-goal's CRL runs too)
ADDED_FIELDS["seed_loop"] = "vmap"   # every run before the field vmapped its seeds
# CRL's values per preset (`--algo crl`, ant-goal; docs/crl.md): `paper` is JaxGCRL's CRL on `ant` (its
# train.sh: 512 envs, 10M steps, 50 evaluations, the backward InfoNCE; its CRL defaults) with ζ as wide as
# the encoders (CRL+SF²'s own, narrower: REPRESENTATION_VALUES) and φ's one Adam state for its InfoNCE and
# flow steps (SF²'s authors'; with a state
# of its own the flow's bootstrap term diverges on spring: docs/crl.md); `quick` shows the critic learning on
# a CPU in about a minute
CRL_VALUES = {
    "paper": dict(num_envs=512, batch_size=256, grad_updates_per_step=32, min_replay_size=512_000,
                  max_replay_size=5_120_000, learning_rate=3e-4, alpha_learning_rate=3e-4, adam_eps=1e-8,
                  discount=0.99, feature_size=64, hidden_sizes=(256, 256), logsumexp_penalty=0.1,
                  contrastive_loss="bwd", target_entropy_scale=0.5, init_log_alpha=0.0, num_evals=51,
                  num_eval_envs=256, deterministic_eval=True, normalize_observations=False,
                  zeta_hidden_sizes=(256, 256), physics="spring", shared_adam=True),
    "quick": dict(num_timesteps=8_000, episode_length=100, num_envs=8, batch_size=64, grad_updates_per_step=4,
                  min_replay_size=400, max_replay_size=8_000, learning_rate=3e-4, alpha_learning_rate=3e-4,
                  adam_eps=1e-8, discount=0.99, feature_size=16, hidden_sizes=(64, 64), logsumexp_penalty=0.1,
                  target_entropy_scale=0.5, init_log_alpha=0.0, num_evals=3, num_eval_envs=4,
                  deterministic_eval=True, normalize_observations=False, zeta_hidden_sizes=(32,),
                  embedding_size=8, physics="spring", shared_adam=True),
}
for _preset, _values in CRL_VALUES.items():   # FAMILY_VALUES[preset][field]["crl"], copying the shared dicts
    for _name, _value in _values.items():
        FAMILY_VALUES[_preset][_name] = {**FAMILY_VALUES[_preset].get(_name, {}), "crl": _value}
# Each preset's values of one (algo, representation), over the algo's: CRL+SF²'s flow is fed φ/‖φ‖ (fed φ
# itself, its bootstrap term runs away late on spring: docs/decisions/crl-sf2-late-divergence.md), and in
# `paper` its ζ is (128, 64), not as wide as CRL's encoders (docs/decisions/crl-sf2-zeta-width.md)
REPRESENTATION_VALUES = {"paper": {("crl", "sf2"): dict(flow_feature_norm="l2", zeta_hidden_sizes=(128, 64))},
                         "quick": {("crl", "sf2"): dict(flow_feature_norm="l2")}}


# ------------------------------------------------------------------------------------------- presets
def superseded_values(folder: dict, now: dict) -> dict:
    """The fields of `SUPERSEDED` in which a run folder's config `folder` holds the old value and the
    config `now` the new one: {field: the folder's value}. Both are `TrainConfig.to_dict()` forms."""
    def plain(value):   # to_dict's lists for the tuples SUPERSEDED names
        return list(value) if isinstance(value, tuple) else value
    return {field: folder[field] for (algo, field), (old, new) in SUPERSEDED.items()
            if now.get("algo") == algo == folder.get("algo") and plain(folder.get(field)) == plain(old)
            and plain(now.get(field)) == plain(new)}


def make_config(preset: str, task: str, algo: str = "td3", representation: str = "sf2",
                overrides: dict | None = None, *, config_class: type[TrainConfig] = TrainConfig):
    """The `preset` for `task` with `overrides` (field → typed value or string) applied, as a `config_class`;
    `ConfigError` for an unknown preset, task or field (`validate` checks the rest)."""
    if preset not in PRESETS:
        raise ConfigError(f"unknown config preset {preset!r}; valid presets: {', '.join(PRESETS)}")
    tasks.validate_task(task)
    tasks.check_algo(task, algo)   # a task of another trainer's kind: refused before any preset value
    values = dict(task=task, algo=algo, representation=representation, **PRESETS[preset])
    values.update({name: value_of(task) for name, value_of in TASK_VALUES.get(preset, {}).items()})
    values.update({name: by_algo[algo] for name, by_algo in FAMILY_VALUES.get(preset, {}).items()
                   if algo in by_algo})
    values.update(REPRESENTATION_VALUES.get(preset, {}).get((algo, representation), {}))
    defaults = {f.name: f.default for f in fields(config_class)}
    for name, value in (overrides or {}).items():
        value = parse_value(name, value, config_class) if isinstance(value, str) else value
        _check_read(name, value, values.get(name, defaults.get(name)), algo)
        values[name] = value
    return config_class.from_dict(values)


def _check_read(name: str, value, before, algo: str) -> None:
    """`ConfigError` for an override that changes (from `before`) a field `algo`'s trainer never reads
    (`READ_BY`); the same value, as a whole config passed back as flags holds, passes."""
    readers = READ_BY.get(name)
    if readers is None or algo not in ALGOS or algo in readers or value == before:
        return
    own = sorted(f for f, by in READ_BY.items() if algo in by)
    raise ConfigError(f"config field {name} = {value!r} would change nothing but the run's config.json: "
                      f"only --algo {', '.join(readers)} read it, not --algo {algo}; drop it (the fields "
                      f"that only some algos read, --algo {algo}'s: {', '.join(own) or 'none'})")


# ------------------------------------------------------------------------------------------- parsing
_BOOLS = dict.fromkeys(("1", "true", "yes", "on"), True) | dict.fromkeys(("0", "false", "no", "off"), False)


@functools.cache
def _hints(config_class: type) -> dict:
    return typing.get_type_hints(config_class)


def parse_value(name: str, text: str, config_class: type[TrainConfig] = TrainConfig):
    """`text` parsed by the type (int, float, bool, str, tuple) of the field `name` of `config_class`."""
    hints = _hints(config_class)
    if name not in hints:
        close = [n for n in hints if name.replace("-", "_") == n]
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ConfigError(f"unknown config field {name!r}{hint}; valid fields: {', '.join(sorted(hints))}")
    kind = hints[name]
    text = text.strip()
    try:
        if kind is bool:
            if text.lower() not in _BOOLS:
                raise ValueError("expected true/false")
            return _BOOLS[text.lower()]
        if kind is int:
            value = float(text.replace("_", ""))
            if not value.is_integer():
                raise ValueError("expected an integer")
            return int(value)
        if kind is float:
            return float(text)
        if kind is str:
            return text
        # tuple[int, ...]: "128,128" or "(128, 128)" or "[128]"
        items = [t for t in text.strip("()[] ").replace(" ", "").split(",") if t]
        return tuple(int(t) for t in items)
    except ValueError as err:
        raise ConfigError(f"config field {name} = {text!r} is invalid: {err} ({_type_name(kind)})") from None


def _type_name(kind) -> str:
    return {int: "an int", float: "a float", bool: "a bool", str: "a string"}.get(
        kind, "comma-separated ints, e.g. 256,256")


def parse_overrides(items, config_class: type[TrainConfig] = TrainConfig) -> dict:
    """['field=value', ...] → {field: typed value} (the fields of `config_class`)."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise ConfigError(f"override {item!r} is invalid: expected field=value, e.g. batch_size=256")
        name, text = item.split("=", 1)
        name = name.strip().replace("-", "_")
        out[name] = parse_value(name, text, config_class)
    return out


def parse_seeds(text) -> tuple[int, ...]:
    """'0-3' → (0, 1, 2, 3); '0,2,5' → (0, 2, 5); '7' → (7,); mixtures like '0-2,9' work too."""
    if isinstance(text, int):
        text = str(text)
    if not isinstance(text, str):
        seeds = tuple(text)
    else:
        seeds = []
        for part in text.replace(" ", "").split(","):
            if not part:
                continue
            try:
                lo, hi = map(int, part.split("-", 1) if "-" in part[1:] else (part, part))
                if hi < lo:
                    raise ValueError
            except ValueError:
                raise ConfigError(f"seeds {text!r} are invalid: use '0-3', '0,2,5' or '7' "
                                  f"(non-negative ints)") from None
            seeds.extend(range(lo, hi + 1))
        seeds = tuple(seeds)
    if not seeds:
        raise ConfigError("seeds: at least one seed is needed, e.g. --seeds 0-3")
    if any((not isinstance(s, int)) or s < 0 or s >= 2**31 for s in seeds):
        raise ConfigError(f"seeds {seeds} are invalid: each must be an int in [0, 2**31)")
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"seeds {seeds} contain duplicates")
    return seeds


# ------------------------------------------------------------------------------------------- schedule
@dataclass(frozen=True)
class Schedule:
    """How the budget splits into epochs: `num_epochs` epochs of `actor_steps_per_epoch` actor steps, each
    stepping all `num_envs` envs once (`action_repeat` physics steps each). The first `prefill_actor_steps`
    act uniformly at random without SGD; every later one is followed by `grad_updates_per_step` SGD steps.
    An evaluation comes before the first epoch and after each. Env steps count after action repeat (as
    Brax does) and include the prefill; the total is num_timesteps rounded up to whole epochs.

    `--algo ppo`: an actor step is one update (`rollout_length` steps of all envs, then `update_epochs` ×
    num_envs · rollout_length / minibatch_size SGD steps), no prefill; `num_evals` is an upper bound: the
    updates split evenly into epochs, so the budget is rounded up by less than one epoch's updates."""

    env_steps_per_actor_step: int   # num_envs · action_repeat
    prefill_actor_steps: int        # ceil(min_replay_size / num_envs)
    prefill_env_steps: int
    num_epochs: int                 # max(num_evals − 1, 1)
    actor_steps_per_epoch: int
    env_steps_per_epoch: int
    total_env_steps: int            # ≥ num_timesteps
    eval_actor_steps: int           # ceil(episode_length / action_repeat): one evaluation episode
    sgd_steps_per_actor_step: int   # grad_updates_per_step (ppo: update_epochs × minibatches)

    def env_steps_after(self, epoch: int) -> int:
        """Env steps done once epoch `epoch` ends (0: none)."""
        return epoch * self.env_steps_per_epoch

    def grad_steps_before(self, actor_step: int) -> int:
        """SGD steps done before the global actor step `actor_step` (0-based)."""
        return max(0, actor_step - self.prefill_actor_steps)


def schedule(cfg: TrainConfig) -> Schedule:
    """The `Schedule` of `cfg` (its docstring); `--algo ppo`'s actor step is one on-policy update."""
    onpolicy = cfg.algo in ONPOLICY_ALGOS
    per = cfg.num_envs * (cfg.rollout_length if onpolicy else cfg.action_repeat)
    prefill = 0 if onpolicy else -(-cfg.min_replay_size // cfg.num_envs)
    epochs = max(cfg.num_evals - 1, 1)
    total_actor = -(-cfg.num_timesteps // per)
    steps = -(-total_actor // epochs)
    if onpolicy:   # updates are large: fewer epochs rather than a budget rounded up by up to an epoch each
        epochs = -(-total_actor // -(-total_actor // min(epochs, total_actor)))
        steps = -(-total_actor // epochs)
    sgd = (cfg.update_epochs * max(cfg.num_envs * cfg.rollout_length // cfg.minibatch_size, 1) if onpolicy
           else cfg.grad_updates_per_step)
    return Schedule(per, prefill, prefill * per, epochs, steps, steps * per, epochs * steps * per,
                    -(-cfg.episode_length // cfg.action_repeat), sgd)


# ------------------------------------------------------------------------------------------- validation
def bad_field(field: str, value, valid: str):
    """Raise the `ConfigError` "config field FIELD = VALUE is invalid: VALID"."""
    raise ConfigError(f"config field {field} = {value!r} is invalid: {valid}")


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def validate(cfg: TrainConfig, seeds, registry) -> TrainConfig:
    """`cfg` after every check that needs no program (`ConfigError`); `registry` is the framework's
    representation `Registry` (the representation must exist there and support the algorithm)."""
    tasks.validate_task(cfg.task)
    tasks.check_algo(cfg.task, cfg.algo)   # the task-kind hook: MinAtar takes `ppo`, Playground td3/sac
    tasks.check_installed(cfg.task)
    tasks.check_env(cfg.task)              # a user's environment: built and its observations checked
    if cfg.algo not in ALGOS:
        bad_field("algo", cfg.algo, f"must be one of {', '.join(ALGOS)}")
    _validate_physics(cfg)
    _validate_shared_torso(cfg)
    _validate_seed_loop(cfg)
    known = registry.names()
    if cfg.representation not in known:
        bad_field("representation", cfg.representation, registry.valid_text())
    rep_cls = registry.get(cfg.representation)
    trained = [a for a in ALGOS if any(a in _algos(registry, r) for r in known)]
    if cfg.algo not in trained:
        bad_field("algo", cfg.algo, f"this core trains {', '.join(trained)} (sf2-jax trains every algo)")
    if cfg.algo not in rep_cls.supported_algos:
        combos = ", ".join(f"{a}+{r}" for r in known for a in _algos(registry, r))
        raise ConfigError(f"algo {cfg.algo!r} with representation {cfg.representation!r} does not exist; "
                          f"valid combinations: {combos}")
    _validate_aux_steps(cfg, registry, rep_cls)
    for name in ("num_timesteps", "episode_length", "action_repeat", "num_envs", "num_evals",
                 "num_eval_envs", "batch_size", "grad_updates_per_step", "max_replay_size",
                 "checkpoint_every", "keep_checkpoints"):
        v = getattr(cfg, name)
        if not _is_int(v) or v < 1:
            bad_field(name, v, "must be an int >= 1")
    if not _is_int(cfg.min_replay_size) or cfg.min_replay_size < 0:
        bad_field("min_replay_size", cfg.min_replay_size, "must be an int >= 0")
    for name in ("deterministic_eval", "normalize_observations"):
        if not isinstance(getattr(cfg, name), bool):
            bad_field(name, getattr(cfg, name), "must be a bool")
    if cfg.action_repeat > cfg.episode_length:
        bad_field("action_repeat", cfg.action_repeat, f"must be <= episode_length ({cfg.episode_length})")
    if cfg.algo in ONPOLICY_ALGOS:
        _validate_onpolicy(cfg)
    elif cfg.max_replay_size < cfg.num_envs:
        bad_field("max_replay_size", cfg.max_replay_size, f"must hold one step of all envs (>= num_envs = "
                  f"{cfg.num_envs})")
    elif cfg.min_replay_size > cfg.max_replay_size:
        bad_field("min_replay_size", cfg.min_replay_size,
                  f"must be <= max_replay_size ({cfg.max_replay_size})")
    if cfg.learner_precision not in LEARNER_PRECISIONS:
        bad_field("learner_precision", cfg.learner_precision,
                  f"must be one of {', '.join(LEARNER_PRECISIONS)}")
    for name in ("reward_scaling", "exploration_noise", "smoothing_noise", "noise_clip",
                 "spr_augmentation_std"):
        v = getattr(cfg, name)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or v < 0:
            bad_field(name, v, "must be a finite number >= 0")
    if cfg.integrator not in INTEGRATORS:
        bad_field("integrator", cfg.integrator, f"must be one of {INTEGRATORS}")
    sched = schedule(cfg)
    if sched.prefill_env_steps >= cfg.num_timesteps:
        raise ConfigError(
            f"num_timesteps = {cfg.num_timesteps} does not exceed the prefill: min_replay_size = "
            f"{cfg.min_replay_size} with num_envs = {cfg.num_envs} and action_repeat = {cfg.action_repeat} "
            f"takes {sched.prefill_env_steps} env steps before any training; raise num_timesteps or lower "
            f"min_replay_size")
    parse_seeds(seeds)
    cfg.sf2_config(1, 1)  # network and loss fields: SF2Config's own validation (placeholder sizes)
    return cfg


def _validate_physics(cfg: TrainConfig) -> None:
    """`physics`: one of `PHYSICS`; "spring" only for ant-goal, the one task whose pipeline is chosen."""
    if cfg.physics not in PHYSICS:
        bad_field("physics", cfg.physics, f"must be one of {', '.join(PHYSICS)} (mjx: MuJoCo's MJX; spring: "
                  f"Brax's spring pipeline, ant-goal only)")
    if cfg.physics == "spring" and cfg.task != "ant-goal":
        bad_field("physics", cfg.physics, f"only ant-goal has the spring pipeline; task {cfg.task!r} takes "
                  f"physics = 'mjx' (valid for ant-goal: {', '.join(PHYSICS)})")


def _validate_aux_steps(cfg: TrainConfig, registry, rep_cls) -> None:
    """`aux_steps_per_sgd_step`: an int >= 1; above 1 only for the off-policy step (td3, sac) of a
    representation with a loss of its own (`aux_groups`), the steps it repeats."""
    k = cfg.aux_steps_per_sgd_step
    if not _is_int(k) or k < 1:
        bad_field("aux_steps_per_sgd_step", k, "must be an int >= 1")
    if k == 1:
        return
    if cfg.algo not in ("td3", "sac"):
        bad_field("aux_steps_per_sgd_step", k, f"must be 1 with algo {cfg.algo!r}: only the off-policy SGD "
                  f"step (algo td3 or sac) repeats the representation's step")
    if not getattr(rep_cls, "aux_groups", ()):
        valid = [r for r in registry.names() if _has_aux_loss(registry, r)]
        bad_field("aux_steps_per_sgd_step", k, f"must be 1 with representation {cfg.representation!r}, "
                  f"which has no loss of its own to repeat; representations that take more: "
                  f"{', '.join(valid) or 'none installed'}")


def _has_aux_loss(registry, name: str) -> bool:
    """Whether representation `name` has a loss of its own (`aux_groups`); False when it cannot be
    imported."""
    try:
        return bool(getattr(registry.get(name), "aux_groups", ()))
    except ConfigError:
        return False


def _validate_shared_torso(cfg: TrainConfig) -> None:
    """`shared_torso`: a bool; True (pgx's example's one network and joint step) only for PPO's V critic
    without a representation."""
    if not isinstance(cfg.shared_torso, bool):
        bad_field("shared_torso", cfg.shared_torso, "must be a bool")
    if cfg.shared_torso and (cfg.algo, cfg.critic, cfg.representation) != ("ppo", "v", "none"):
        bad_field("shared_torso", cfg.shared_torso, f"pgx's shared torso exists for algo 'ppo' with critic "
                  f"'v' and representation 'none' only, found algo {cfg.algo!r}, critic {cfg.critic!r}, "
                  f"representation {cfg.representation!r} (valid: --algo ppo --repr none --set critic=v)")


def _validate_seed_loop(cfg: TrainConfig) -> None:
    """`seed_loop`: one of `SEED_LOOPS`; "map" only for the on-policy trainer (algo ppo, fpo), the one that
    reads it."""
    if cfg.seed_loop not in SEED_LOOPS:
        bad_field("seed_loop", cfg.seed_loop, f"must be one of {', '.join(SEED_LOOPS)} (vmap: the seeds "
                  f"batched in one program; map: one after another, jax.lax.map)")
    if cfg.seed_loop != "vmap" and cfg.algo not in ONPOLICY_ALGOS:
        onpolicy = ", ".join(ONPOLICY_ALGOS)
        bad_field("seed_loop", cfg.seed_loop, f"only the on-policy trainer (algo {onpolicy}) runs its seeds "
                  f"by jax.lax.map; algo {cfg.algo!r} takes 'vmap' (valid for {onpolicy}: "
                  f"{', '.join(SEED_LOOPS)})")


def _validate_onpolicy(cfg: TrainConfig) -> None:
    """The PPO and FPO fields (`--algo ppo`, `fpo`): sizes, rates, the critic, and minibatches that split the
    rollout."""
    for name in ("rollout_length", "update_epochs", "minibatch_size", *FPO_FIELDS[:3]):
        v = getattr(cfg, name)
        if not _is_int(v) or v < 1:
            bad_field(name, v, "must be an int >= 1")
    if cfg.action_repeat != 1:
        bad_field("action_repeat", cfg.action_repeat, "must be 1: the on-policy trainer steps each game once "
                  "per action")
    batch = cfg.num_envs * cfg.rollout_length
    if batch % cfg.minibatch_size:
        bad_field("minibatch_size", cfg.minibatch_size, f"must divide the rollout's num_envs × "
                  f"rollout_length = {cfg.num_envs} × {cfg.rollout_length} = {batch} transitions")
    for name, low, high, text in (("clip_eps", 0, 1, "0 < clip_eps <= 1"),
                                  ("td_lambda", None, 1, "0 <= td_lambda <= 1"),
                                  ("entropy_coef", None, math.inf, "a finite number >= 0"),
                                  ("value_coef", 0, math.inf, "a finite number > 0"),
                                  ("max_grad_norm", 0, math.inf, "a finite number > 0")):
        v = getattr(cfg, name)
        ok = (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v <= high
              and (v >= 0 if low is None else v > low))
        if not ok:
            bad_field(name, v, f"must be {text}" if text[0].isalpha() else f"must satisfy {text}")
    c = cfg.fpo_log_ratio_clip
    if not isinstance(c, (int, float)) or isinstance(c, bool) or math.isnan(c) or c <= 0:
        bad_field("fpo_log_ratio_clip", c, "must be a number > 0 (inf: no bound)")
    if cfg.critic not in CRITICS:
        bad_field("critic", cfg.critic, "must be 'q' (Q(s, a) with λ-returns: PPO-Q) or 'v' (V(s) with GAE: "
                  "PPO)")
    if cfg.advantage_refresh not in ADVANTAGE_REFRESH:
        bad_field("advantage_refresh", cfg.advantage_refresh, f"must be one of {ADVANTAGE_REFRESH} "
                  f"(advantages from the rollout-time critic, or from the current critic at every pass)")


def _algos(registry, name: str) -> tuple[str, ...]:
    """The algorithms representation `name` supports (none when it cannot be imported)."""
    try:
        return registry.get(name).supported_algos
    except ConfigError:
        return ()
