# This folder is the subpackage enginebench.experiments (pyproject.toml maps it); imported under another name, e.g.
# "import experiments" from the checkout root, every module in it would load a second time, as a second class.
if __name__ != "enginebench.experiments":
    raise ImportError(f"import enginebench.experiments, not {__name__}: this folder is mapped into the enginebench package")
