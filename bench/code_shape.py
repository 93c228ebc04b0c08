"""The shape of bfc/'s code, the figures the layout issues are measured by: lines, functions over
60 lines and functions with more than 8 parameters (self and cls not counted; *args and **kwargs
not counted), each listed.

    python bench/code_shape.py [--package bfc]     # from the repository root (a package folder there)
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path


def functions(package: Path):
    for path in sorted(package.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                a = node.args
                named = [*a.posonlyargs, *a.args, *a.kwonlyargs]
                params = len(named) - (1 if named and named[0].arg in ("self", "cls") else 0)
                yield f"{path}:{node.lineno} {node.name}", node.end_lineno - node.lineno + 1, params


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--package", default="bfc")
    package = Path(p.parse_args().package)
    lines = sum(len(path.read_text().splitlines()) for path in package.rglob("*.py"))
    found = list(functions(package))
    long = sorted(((n, where) for where, n, _ in found if n > 60), reverse=True)
    wide = sorted(((k, where) for where, _, k in found if k > 8), reverse=True)
    print(f"lines in {package}/: {lines:,}")
    print(f"functions over 60 lines: {len(long)}")
    for n, where in long:
        print(f"  {n:4d}  {where}")
    print(f"functions with more than 8 parameters: {len(wide)}")
    for k, where in wide:
        print(f"  {k:4d}  {where}")


if __name__ == "__main__":
    main()
