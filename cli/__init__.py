# This folder is the subpackage enginebench.cli (pyproject.toml maps it); imported under another name, e.g.
# "import cli" from the checkout root, every module in it would load a second time, as a second class.
if __name__ != "enginebench.cli":
    raise ImportError(f"import enginebench.cli, not {__name__}: this folder is mapped into the enginebench package")
