"""The largest classes and the long functions of the package, measured with ``ast``.

Run from the repository root::

    python benchmarks/code_sizes.py            # top 10 classes, functions over 80 lines
    python benchmarks/code_sizes.py --top 20 --over 60
    python benchmarks/code_sizes.py --root /path/to/other/checkout   # another commit's tree

A class's size is its source lines (``end_lineno - lineno + 1``, decorators excluded)
and the number of functions defined directly in its body; a function's size counts its
whole body, docstring and comments included, so the figures are comparable between
commits (issue 21: the large classes split along their seams).
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / "uavest"


def _sizes(root: Path) -> tuple[list[tuple[int, int, str]], list[tuple[int, str]]]:
    """Return (classes as (lines, methods, where), functions as (lines, where))."""
    classes: list[tuple[int, int, str]] = []
    functions: list[tuple[int, str]] = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root.parent).as_posix()
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=rel)
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                methods = sum(isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))
                              for n in node.body)
                lines = node.end_lineno - node.lineno + 1
                classes.append((lines, methods, f"{rel}:{node.name}"))
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                functions.append((lines, f"{rel}:{node.name}"))
    return classes, functions


def main(argv: list[str] | None = None) -> int:
    """Print the table; return 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--top", type=int, default=10, help="classes to list (default 10)")
    ap.add_argument("--over", type=int, default=80,
                    help="list functions longer than this many lines (default 80)")
    ap.add_argument("--root", type=Path, default=ROOT.parent,
                    help="the checkout to measure (default: this one)")
    args = ap.parse_args(argv)
    classes, functions = _sizes(args.root.resolve() / "uavest")
    classes.sort(reverse=True)
    print(f"largest classes (lines, methods), top {args.top}:")
    for lines, methods, where in classes[: args.top]:
        print(f"  {lines:5d} {methods:4d}  {where}")
    long = sorted((f for f in functions if f[0] > args.over), reverse=True)
    print(f"functions over {args.over} lines: {len(long)}")
    for lines, where in long:
        print(f"  {lines:5d}  {where}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
