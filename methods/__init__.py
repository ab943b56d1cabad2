# This folder is the subpackage enginebench.methods (pyproject.toml maps it); imported under another name, e.g.
# "import methods" from the checkout root, every module in it would load a second time, as a second class.
if __name__ != "enginebench.methods":
    raise ImportError(f"import enginebench.methods, not {__name__}: this folder is mapped into the enginebench package")
