"""The representation registry of one framework: `--repr NAME` → the `Representation` class. A
representation is selectable when it was `register`ed in this process (the core's `none` and `sf2`, a
test's variants) or when an installed distribution declares it as an entry point of the group
`sf2.representations.jax` or `sf2.representations.torch` (sf2-baselines does). `names()` lists entry
points without importing them; `get(name)` imports one when asked; an unknown name is a `ConfigError`
listing the valid names and, without sf2-baselines, how to install it."""

from __future__ import annotations

from importlib import metadata

from sf2_common.errors import ConfigError

__all__ = ["Registry", "GROUP", "BASELINES", "INSTALL_BASELINES", "check_aux_every", "check_aux_steps"]

GROUP = "sf2.representations.{framework}"   # the entry-point group of a framework
BASELINES = ("sim", "simlap", "spr")        # the paper's baselines, provided by sf2-baselines
INSTALL_BASELINES = "pip install packages/sf2-baselines"


class Registry:
    """Representations of one framework ("jax" or "torch"): registered classes, then entry points. A
    trainer with representations of its own (the on-policy trainer's) has its own registry: its entry-point
    `group`, and the `baselines` its error messages say how to install (none)."""

    def __init__(self, framework: str, group: str | None = None, baselines: tuple[str, ...] = BASELINES):
        self.framework = framework
        self.group = group or GROUP.format(framework=framework)
        self.baselines = baselines
        self._classes: dict[str, type] = {}
        self._entry_points: dict[str, metadata.EntryPoint] | None = None

    def register(self, cls: type) -> type:
        """Make `cls` selectable by `cls.name` (`--repr NAME`). Usable as a class decorator."""
        if not getattr(cls, "name", ""):
            raise ValueError(f"{cls.__name__}.name is empty")
        self._classes[cls.name] = cls
        return cls

    def entry_points(self) -> dict[str, metadata.EntryPoint]:
        """{name: entry point} of the installed distributions (read once per process)."""
        if self._entry_points is None:
            found: dict[str, metadata.EntryPoint] = {}
            for ep in metadata.entry_points(group=self.group):
                found.setdefault(ep.name, ep)
            self._entry_points = found
        return self._entry_points

    def names(self) -> tuple[str, ...]:
        """Registered names (in registration order), then the entry points not loaded yet (sorted)."""
        return tuple(self._classes) + tuple(sorted(set(self.entry_points()) - set(self._classes)))

    def get(self, name: str) -> type:
        """The class of `name`, importing its entry point if needed; `ConfigError` if there is none."""
        if name in self._classes:
            return self._classes[name]
        ep = self.entry_points().get(name)
        if ep is None:
            raise ConfigError(f"unknown representation {name!r}; {self.valid_text()}")
        try:
            cls = ep.load()
        except ImportError as err:
            dist = getattr(ep.dist, "name", None) or "its package"
            raise ConfigError(f"representation {name!r} ({ep.value}, from {dist}) could not be imported: "
                              f"{err}") from err
        return self._classes.setdefault(name, cls)

    def label(self, name: str) -> str:
        """The class's `label` (shown in tables and plots), or `name` when it cannot be loaded."""
        try:
            return self.get(name).label
        except ConfigError:
            return name

    def valid_text(self) -> str:
        """'must be one of none, sf2, sim, ...', with the install line when the baselines are missing."""
        names = self.names()
        text = f"must be one of {', '.join(names)}"
        missing = [b for b in self.baselines if b not in names]
        if missing:
            text += (f" (the baselines {', '.join(missing)} come with sf2-baselines: "
                     f"{INSTALL_BASELINES})")
        return text


def aux_states(cfg, rep) -> dict[str, str]:
    """{group: the optimizer state the representation's loss steps it with} for every group of
    `rep.aux_groups`: the group's own, or with `cfg.shared_adam` False a second state "<group>:aux" when
    the critic trains the group too (ψ; docs/core-contract.md "One SGD step"). Both cores' base algorithms
    use it (sf2_jax `opt_state[...]`, sf2_torch `optimizers[...]`)."""
    return {g: g if cfg.shared_adam or g not in rep.critic_groups else f"{g}:aux" for g in rep.aux_groups}


def check_aux_every(rep) -> None:
    """Raise ValueError unless `rep.aux_every` maps groups of `rep.aux_groups` to periods >= 1 (a
    representation's update schedule; both cores' base algorithms check it when they are built)."""
    for group, every in rep.aux_every.items():
        if group not in rep.aux_groups:
            raise ValueError(f"{type(rep).__name__}.aux_every names {group!r}, which is not one of its "
                             f"aux_groups {rep.aux_groups}")
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise ValueError(f"{type(rep).__name__}.aux_every[{group!r}] = {every!r} is invalid: must be "
                             f"an int >= 1 (a period in gradient steps)")


def check_aux_steps(cfg, rep) -> None:
    """Raise ConfigError when `cfg.aux_steps_per_sgd_step` (representation steps per SGD step) is above 1
    for a representation without a loss of its own (`rep.aux_groups` empty): there is no step to repeat.
    Both cores' base algorithms check it when they are built (the CLI's `configs.validate` first)."""
    k = cfg.aux_steps_per_sgd_step
    if k != 1 and not rep.aux_groups:
        raise ConfigError(f"aux_steps_per_sgd_step = {k!r} is invalid: must be 1 with representation "
                          f"{getattr(rep, 'name', type(rep).__name__)!r}, which has no loss of its own to "
                          f"repeat (those with one, e.g. sf2, take any int >= 1)")
