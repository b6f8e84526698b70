"""`SF2Config`: sizes and loss hyperparameters of SF², validated on construction (paper Appendix E
Table 1, with the authors' effective values where they differ; docs/core-contract.md).

The class lives in `sf2_common.config` and is the same object in `sf2_jax` and `sf2_torch`, so both cores
share one set of fields, defaults and validation messages.
"""

from __future__ import annotations

from sf2_common.config import INTEGRATORS, SF2Config

__all__ = ["SF2Config", "INTEGRATORS"]
