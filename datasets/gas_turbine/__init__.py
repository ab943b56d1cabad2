"""The UCI gas-turbine CO and NOx emission data (real, CC BY 4.0): importer and physical model."""
