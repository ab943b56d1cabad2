# This folder is the subpackage enginebench.reports (pyproject.toml maps it); imported under another name, e.g.
# "import reports" from the checkout root, every module in it would load a second time, as a second class.
if __name__ != "enginebench.reports":
    raise ImportError(f"import enginebench.reports, not {__name__}: this folder is mapped into the enginebench package")
