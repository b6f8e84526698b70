"""What every module of the study system uses: its error and the text form of a list of seeds."""

from __future__ import annotations

from sf2_common.errors import ConfigError

__all__ = ["StudyError", "seeds_text"]


class StudyError(ConfigError):
    """A study file or study folder that cannot be used as it is (exit status 2)."""


def seeds_text(seeds) -> str:
    """(0, 1, 2, 5) → '0-2,5' (what `--seeds` takes)."""
    parts, start = [], None
    for i, s in enumerate(seeds):
        if start is None:
            start = s
        if i + 1 == len(seeds) or seeds[i + 1] != s + 1:
            parts.append(str(start) if s == start else f"{start}-{s}")
            start = None
    return ",".join(parts)
