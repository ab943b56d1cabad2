"""The built-in ``marine-diesel`` data set (synthetic) and its physical model (egt-hybrid).

* ``generate(size, seed, progress)``: the synthetic data set (``generate.py``), driven by
  a vessel profile (``profile.py``) through a rich mean-value "true engine"
  (``engine.py``, ``thermal.py``, ``sensors.py``).
* ``MarineDieselPM``: the egt-hybrid paper's mean-value physical model, modules A-F (equations in ``pm.py``,
  the ``PhysicalModel`` in ``physical_model.py``).
* ``calibrate_to_fat``: weighted least-squares calibration of the PM to factory
  acceptance test points (``calibration.py``); ``load_fat`` reads the egt-hybrid paper's FAT table
  shipped as ``fat_seed000.csv``; ``simulator_fat`` measures FAT points on the true
  engine (``fat.py``); ``simulator_fat_params(seed)`` is the PM calibrated on them, the
  calibration the ``marine-diesel`` experiments use (``MarineDieselPM`` default; the
  generator records it as ``meta["pm_calibration"] = "simulator"``).
"""

from enginebench.datasets.marine_diesel.calibration import calibrate_to_fat, seed_fat_params, simulator_fat_params
from enginebench.datasets.marine_diesel.fat import load_fat, simulator_fat
from enginebench.datasets.marine_diesel.generate import generate
from enginebench.datasets.marine_diesel.physical_model import MarineDieselPM
from enginebench.datasets.marine_diesel.pm import PM_NAME

__all__ = ["generate", "MarineDieselPM", "PM_NAME", "calibrate_to_fat", "seed_fat_params",
           "simulator_fat_params", "load_fat", "simulator_fat"]
