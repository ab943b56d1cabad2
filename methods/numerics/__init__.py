"""The numerics the methods compose: differentiation, fixed-step integration, device choice.

``derivatives``: regularised (total-variation or Kalman) derivatives of sampled signals,
windowed for long segments (MoE and SINDy targets). ``integrate``: one batched fixed-step
integrator (RK4 / Euler) with the divergence envelope every simulating method shares.
``device``: the CPU/CUDA choice of torch-based solvers. The kernel solvers live beside
the methods that use them (``methods/kernels.py``, ``shifted.py``, ``falkon.py``).
"""
