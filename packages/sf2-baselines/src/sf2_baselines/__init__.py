"""sf2_baselines: the comparison methods of the SF² paper (ICLR 2026, §4.2 and Appendix B.1).

Three representations, each in both frameworks with the same module and function names:
``sim`` (TD3Sim / SACSim, §4.2): successor features "the simple way" (Chua et al., 2024), basis features
φ(s, a, w), SF heads ψᵢ, Qᵢ = wᵀψᵢ; ``simlap`` (TD3SimLap / SACSimLap, §4.2): Sim without the
Q-alignment of φ, plus a graph-Laplacian orthogonality objective on normalized φ; ``spr`` (TD3+SPR /
SAC+SPR, Appendix B.1): self-predictive representations (Schwarzer et al., 2021) for state inputs, K = 1,
Gaussian-noise augmentation.

``sf2_baselines.jax`` needs ``sf2-core-jax`` (extra ``[jax]``), ``sf2_baselines.torch`` needs
``sf2-core-torch`` (extra ``[torch]``). Importing either registers the representations ``sim``,
``simlap``, ``simlap_authors`` and ``spr`` with that framework's agents, so ``--repr sim`` works like
``--repr sf2``. This top-level module imports neither framework. See README.md for the equations.
"""

__version__ = "0.2.0"

METHODS = {
    "sim": "Sim (Chua et al., 2024): TD3Sim / SACSim",
    "simlap": "SimLap: Sim without Q-alignment of the features, plus a graph-Laplacian objective",
    "simlap_authors": "SimLap as the SF² authors' code runs it: the critic also trains the features",
    "spr": "SPR (Schwarzer et al., 2021) for state inputs: K = 1, Gaussian-noise augmentation",
}

__all__ = ["METHODS", "__version__"]
