# This folder is the subpackage enginebench.results (pyproject.toml maps it); imported under another name, e.g.
# "import results" from the checkout root, every module in it would load a second time, as a second class.
if __name__ != "enginebench.results":
    raise ImportError(f"import enginebench.results, not {__name__}: this folder is mapped into the enginebench package")
