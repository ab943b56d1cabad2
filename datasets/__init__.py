# This folder is the subpackage enginebench.datasets (pyproject.toml maps it); imported under another name, e.g.
# "import datasets" from the checkout root, every module in it would load a second time, as a second class.
if __name__ != "enginebench.datasets":
    raise ImportError(f"import enginebench.datasets, not {__name__}: this folder is mapped into the enginebench package")
