"""The numerics the methods compose: kernels and their solvers, differentiation, fixed-step integration,
device choice.

``derivatives``: regularised (total-variation or Kalman) derivatives of sampled signals,
windowed for long segments (MoE and SINDy targets). ``integrate``: one batched fixed-step
integrator (RK4 / Euler) with the divergence envelope every simulating method shares.
``device``: the CPU/CUDA choice of torch-based solvers. ``kernels``: the Gaussian kernel,
its blocked application and the feature scaling shared by the kernel methods; ``shifted``:
ridge and shifted-system solutions for a whole grid from one factorisation per gamma
(KRLS, MTL-KRLS); ``kernel_grid``: a (lag set, gamma, lambda) grid's predictions from one
distance matrix per lag set and ``shifted``'s solver per gamma (NFIR); ``lag_gram``: the
Gram matrix of the longest lags shared by an ARX order grid; ``falkon``: the large-scale Nystroem + conjugate-gradient solver.
"""
