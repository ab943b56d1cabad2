"""Exporters of fitted models: FMUs from C steps (``fmu``, ``harness``, ``models``) and ONNX graphs (``onnx``).

The C-step contract they build on (``CModel``) is ``enginebench/c_model.py``.
"""
