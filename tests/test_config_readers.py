"""`READ_BY` refuses an override only where no trainer of that algo reads the field.

`sf2_common.agents.configs.READ_BY` names, for fields only some algos' trainers read, the algos that read
them; `make_config` refuses an override of such a field for any other algo. That is right only while no
trainer of another algo reads it: each trainer module's `cfg.FIELD` reads (the JAX and torch cores, the
off-policy algorithms class by class) are checked against the table here. Text only: nothing is imported
from the trainers, so it runs without the [train] extras.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest
from sf2_common.agents.configs import ALGOS, ONPOLICY_ALGOS, READ_BY

# module of a core's agents package (or "module:Class", the class's body alone) -> the algos it trains
_OFF = ("td3", "sac")
TRAINERS = {
    "sf2_jax": {"onpolicy.py": ONPOLICY_ALGOS, "policies_onpolicy.py:SiluMLP": ONPOLICY_ALGOS,
                "policies_onpolicy.py:CategoricalPolicy": ("ppo",),
                "policies_onpolicy.py:FlowPolicy": ("fpo",),
                "representations_onpolicy.py": ONPOLICY_ALGOS, "playground_onpolicy.py": ONPOLICY_ALGOS,
                "minatar.py": ("ppo",), "crl.py": ("crl",), "goal_replay.py": ("crl",),
                "antgoal.py": ("crl",), "trainer.py": _OFF, "representations.py": _OFF, "replay.py": _OFF,
                "algorithms.py:Algorithm": _OFF, "algorithms.py:TD3": ("td3",),
                "algorithms.py:SAC": ("sac",)},
    "sf2_torch": {"trainer.py": _OFF, "representations.py": _OFF, "replay.py": _OFF, "envs.py": _OFF,
                  "graphs.py": _OFF, "algorithms.py:Algorithm": _OFF, "algorithms.py:TD3": ("td3",),
                  "algorithms.py:SAC": ("sac",)},
}
# reads in a class shared by more algos than read the field, each with where it happens
ONLY_FOR = {("sf2_jax", "algorithms.py:Algorithm", "alpha_learning_rate"):
            "the temperature's Adam (`_tx`'s log_alpha group), which only SAC trains",
            ("sf2_torch", "algorithms.py:Algorithm", "alpha_learning_rate"):
            "`_make_adam`'s log_alpha group, which only SAC builds"}

READ = re.compile(r"\bcfg\.(\w+)")


def _source(package: str, where: str) -> str:
    agents = Path(importlib.util.find_spec(package).origin).parent / "agents"
    name, _, cls = where.partition(":")
    text = (agents / name).read_text()
    if not cls:
        return text
    start = re.search(rf"^class {cls}\b.*$", text, re.M)
    assert start, f"{package}.agents.{name} has no class {cls}"
    end = re.search(r"^\S", text[start.end() + 1:], re.M)
    return text[start.start(): start.end() + 1 + end.start()] if end else text[start.start():]


@pytest.mark.parametrize("package", sorted(TRAINERS))
def test_no_trainer_reads_a_field_refused_for_its_algos(package):
    """Every `cfg.FIELD` a trainer module reads is allowed for each algo it trains (or for all)."""
    if importlib.util.find_spec(package) is None:
        pytest.fail(f"{package} is not installed: this test reads its trainers' sources")
    reads = 0
    for where, algos in TRAINERS[package].items():
        assert set(algos) <= set(ALGOS)
        for field in set(READ.findall(_source(package, where))):
            reads += 1
            if (package, where, field) in ONLY_FOR:
                continue
            refused = [a for a in algos if field in READ_BY and a not in READ_BY[field]]
            assert not refused, (f"{package}.agents.{where} reads cfg.{field}, which READ_BY refuses for "
                                 f"--algo {', '.join(refused)} (it allows {', '.join(READ_BY[field])})")
    assert reads >= 20, f"only {reads} cfg reads found in {package}'s trainers: the pattern no longer matches"

