"""CPU time of the commands that print stored results, each in a fresh interpreter (issue 35, item 5: < 1 s).

    python benchmarks/cli_startup.py [--store STORE] [--repeats 5]

Without --store, a small run is written to a temporary store (``tests/helpers.stored_run``: 2 methods x 30
repetitions); with one, ``latest`` of that store is read (e.g. after `enginebench run gas-turbine-nox-quick
--store STORE`). Each command runs --repeats times in a child ``python -c`` started outside the checkout; the
best user+sys CPU time of the child is printed with the heavy packages it imported. The references, measured the
same way: the interpreter with the CLI imported and nothing run (the floor every command pays), and the imports
the printing paths avoid (scipy.special, which the Student-t quantile used to come from; pandas, which
`runs list` no longer needs). No assertion: tests/cli/test_startup_imports.py checks the imports.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

HEAVY = ("pandas", "pyarrow", "scipy", "sklearn", "torch")
RUN_CLI = """
import json, sys
from enginebench.cli.main import cli
try:
    cli(sys.argv[1:], prog_name="enginebench", standalone_mode=False)
except SystemExit:
    pass
print("\\nMODULES " + json.dumps(sorted({m.split('.')[0] for m in sys.modules})))
"""


def child_cpu(code: str, args: list[str], cwd: str) -> tuple[float, list[str]]:
    """User+sys CPU seconds of one child interpreter running ``code`` with ``args``, and the heavy packages it
    had imported (when it prints them)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=cwd, check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    _, _, tail = done.stdout.rpartition("\nMODULES ")
    heavy = [m for m in json.loads(tail) if m in HEAVY] if tail else []
    return cpu, heavy


def small_store(root: Path) -> Path:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from helpers import stored_run

    from enginebench.results.store import RunStore

    rs = RunStore(root / "runs")
    values = {m: [1.0 + 0.5 * i + 0.013 * r + 0.0007 * r * r for r in range(30)]
              for i, m in enumerate(("naive-mean", "ridge"))}
    stored_run(rs, "startup-benchmark", values)
    return rs.root


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", default=None, help="a run store whose latest run is read [default: a small one]")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        store = args.store or str(small_store(Path(tmp)))
        commands = {
            "table": ["table", "latest", "--store", store],
            "table --format csv": ["table", "latest", "--format", "csv", "--store", store],
            "runs show": ["runs", "show", "latest", "--store", store],
            "runs list": ["runs", "list", "--store", store],
            "methods list": ["methods", "list"],
        }
        references = {
            "reference: import the CLI, run nothing": ("import enginebench.cli.main", []),
            "reference: import pandas": ("import pandas", []),
            "reference: import scipy.special": ("import scipy.special", []),
        }
        print(f"python {sys.version.split()[0]}, load average {os.getloadavg()[0]:.1f}, best of {args.repeats}")
        for name, argv in commands.items():
            runs = [child_cpu(RUN_CLI, argv, tmp) for _ in range(args.repeats)]
            print(f"  {name:40s} {min(c for c, _ in runs):6.3f} s CPU  imports: {', '.join(runs[0][1]) or '-'}")
        for name, (code, argv) in references.items():
            best = min(child_cpu(code, argv, tmp)[0] for _ in range(args.repeats))
            print(f"  {name:40s} {best:6.3f} s CPU")


if __name__ == "__main__":
    main()
