"""Named constants of the marine-diesel case: engine data, gas properties, logging.

The engine resembles the one of egt-hybrid (sec. 3 and Table 4): a four-stroke,
medium-speed, 12-cylinder V propulsion diesel (two banks of six cylinders, one
turbocharger per bank) on one shaft of a twin-shaft patrol vessel with a
controllable-pitch propeller. Its factory acceptance test (FAT) points lie on the
propeller law at 25, 50, 75, 85, 100 and 110 % load, which puts the maximum continuous
rating (MCR) at 1000 rpm: (0.25, 0.5, 0.75, 0.85, 1.0, 1.1) ** (1/3) * 1000 rpm =
630, 794, 909, 947, 1000, 1032 rpm, the FAT speeds of Table 4. Bore, stroke and rating
are typical of that class of engine (assumed; the paper does not give them). Every
constant carries its unit in its name or comment; SI units unless the name says
otherwise.
"""

from __future__ import annotations

import math

# -- engine geometry and rating ------------------------------------------------------
N_CYL = 12
"""Cylinders (two banks of six)."""
N_CYL_BANK = 6
"""Cylinders per bank; each bank drives its own turbocharger."""
BORE_M = 0.28
STROKE_M = 0.33
V_D_CYL_M3 = math.pi / 4.0 * BORE_M**2 * STROKE_M
"""Swept volume of one cylinder, m^3 (20.3 litres)."""
COMPRESSION_RATIO = 13.5
"""Geometric compression ratio, dimensionless."""
N_MCR_RPM = 1000.0
"""Engine speed at maximum continuous rating (100 % FAT load), rpm."""
P_MCR_W = 5.0e6
"""Brake power at MCR, W (bmep 24.6 bar)."""
N_MAX_RPM = 1030.0
"""Highest engine speed of the combinator curves, rpm (110 % FAT point: 1031 rpm)."""
N_IDLE_RPM = 400.0
"""Lowest engine speed of the combinator curves, rpm."""
FAT_SPEEDS_RPM = (631.0, 795.0, 910.0, 947.0, 1000.0, 1031.0)
"""Speeds of the egt-hybrid paper's FAT points (Table 4), rpm."""

# -- fuel ----------------------------------------------------------------------------
LHV_J_PER_KG = 42.7e6
"""Lower heating value of the marine gas oil, J/kg (egt-hybrid, sec. 5.1: 42,700 kJ/kg)."""
AFR_STOICH = 14.5
"""Stoichiometric air/fuel mass ratio of diesel fuel, kg air per kg fuel."""

# -- gas properties (constant, per stream) -------------------------------------------
R_AIR = 287.1
"""Gas constant of air, J/(kg K)."""
CP_AIR = 1005.0
"""Isobaric specific heat of air, J/(kg K)."""
KAPPA_AIR = CP_AIR / (CP_AIR - R_AIR)
"""Ratio of specific heats of air (1.40)."""
CP_GAS = 1150.0
"""Isobaric specific heat of exhaust gas, J/(kg K)."""
KAPPA_GAS = 1.34
"""Ratio of specific heats of exhaust gas."""
R_GAS = CP_GAS * (KAPPA_GAS - 1.0) / KAPPA_GAS
"""Gas constant of exhaust gas, J/(kg K) (291.8)."""
T_REF_K = 298.15
"""Reference temperature of enthalpies and of corrected turbocharger quantities, K."""
P_REF_PA = 1.01325e5
"""Reference pressure of corrected turbocharger quantities, Pa."""
CP_WATER = 4186.0
"""Specific heat of cooling water, J/(kg K)."""
CP_OIL = 2000.0
"""Specific heat of lube oil, J/(kg K)."""

# -- conversions ---------------------------------------------------------------------
KELVIN = 273.15
"""0 degC in K."""
BAR = 1.0e5
"""1 bar in Pa."""
RPM_TO_RAD_S = 2.0 * math.pi / 60.0

# -- logging -------------------------------------------------------------------------
DT_LOG_S = 3.0
"""Sample period of the vessel's logging system, s (1/3 Hz, egt-hybrid sec. 3)."""
FULL_HOURS = 3347.0
"""Logged hours of the egt-hybrid paper's data set (3,988,939 samples)."""
SMALL_HOURS = 72.0
"""Logged hours of the ``small`` size (a few days, for tests)."""

# -- propulsion train ----------------------------------------------------------------
GEAR_RATIO = 4.8
"""Engine speed / propeller shaft speed of the reduction gearbox."""
ETA_GEARBOX = 0.975
"""Gearbox mechanical efficiency."""
