"""The two-Gaussian study of Appendix A.2–A.3 (Figures 3 and 4; hyperparameters: Table 2, Appendix E.2).

Learning p = γ·N(−2, 0.3²) + (1 − γ)·N(2, 0.7²) (which component carries γ, and why: `mixture`) with
flow matching on mixture samples, flow matching with the explicit mixture objective of Appendix A.3, a VAE
and a GAN (`models`); every (γ, seed) of a model is trained in one jitted, vmapped program (`train`); W1 to
the exact mixture, figures and tables (`report`). Run from the repository root:

    python -m sf2_jax.experiments.two_gaussians --out results/two-gaussians --seeds 0-4 --gammas 0.5,0.9,0.99

(results/two-gaussians/summary.md holds the committed run; matplotlib is needed for the figures only).
"""

from .mixture import Mixture, wasserstein1
from .models import LABELS, MODELS, Settings, flow_matching_loss, make_model, sample_component, sample_mixture
from .train import run_grid

__all__ = ["Mixture", "wasserstein1", "LABELS", "MODELS", "Settings", "flow_matching_loss", "make_model",
           "sample_component", "sample_mixture", "run_grid"]
