"""Small experiments of the paper that run on a CPU, each a subpackage runnable with `python -m`:

- `two_gaussians`: the one-dimensional two-Gaussian study of Appendix A.2–A.3 (Figures 3 and 4, Table 2 of
  Appendix E.2): flow matching with the explicit mixture objective against flow matching on mixture
  samples, a VAE and a GAN.
"""
