"""The scenario walk: which files a scenario crosses from an entry point, and how often the
walk climbs back up the layer order (issue 21's "Must show").

Static (``ast``), no import of the package's runtime: from an entry function the walk
follows every call that passes *the scenario* (the object ``load_scenario`` / ``load_typed``
/ ``typed`` returns, bound to a parameter or a local name) into the callee's matching
parameter, in source order, expanding each call site once (a loop body counts once), and
records a *touch* wherever the scenario is read (``sc.x``, ``sc.get(...)``, ``sc[...]``)
or handed on. A *part* is one of the scenario's tables (``sc.radar``, ``sc.get("motion",
{})``, ...: the table names the schema declares); the walk follows parts too and reports
them apart.

Reported per entry, for the whole scenario (and, second line, scenario or part):

- ``files``: the files the walk touches, in order of first touch;
- ``climbs``: transitions of the touch sequence (consecutive touches in the same file
  merged) from a file in one layer to a file in a *higher* layer (the layer list of
  ``pyproject.toml`` ``[tool.importlinter]``, ``cli`` highest), i.e. the scenario handed
  down, then read again further up, then handed down again;
- ``below``: functions in a layer below ``scenarios`` (the scenario's own layer) that
  receive the whole scenario, i.e. a lower layer reading a higher layer's type.

Run: ``python benchmarks/scenario_walk.py`` (``--verbose`` prints the touch sequence).
"""

from __future__ import annotations

import argparse
import ast
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "uavest"
LAYERS: list[list[str]] = []
TABLES: set[str] = set()
MODS: dict = {}

#: (entry function, its parameter bound to the scenario; None: created inside)
ENTRIES = [
    ("uavest.experiments.radar.run_trackers", "sc"),
    ("uavest.cli.track.cmd_track", None),
    ("uavest.cli.bench.cmd_bench", None),
]
#: Calls whose result is the scenario (given the scenario, or creating it).
MAKERS = {"load_scenario", "load_typed", "typed", "parse", "apply_sets", "replace",
          "deepcopy"}
#: Calls that hand the scenario back as it is (``typed`` of a typed scenario, a copy):
#: a touch in the caller, not followed.
ALIASES = {"typed", "replace", "deepcopy"}
READERS = {"get", "setdefault", "items", "keys", "values"}


#: This checkout: its layer list and scenario schema are the rules when the measured
#: checkout (``--root``, e.g. a commit before the contracts or the schema) has none.
HERE = ROOT


def layers() -> list[list[str]]:
    """The layer rows of ``pyproject.toml``'s import-linter contract (top first)."""
    with open(ROOT / "pyproject.toml", "rb") as fh:
        tool = tomllib.load(fh)["tool"]
    if "importlinter" not in tool:
        with open(HERE / "pyproject.toml", "rb") as fh:
            tool = tomllib.load(fh)["tool"]
    cfg = tool["importlinter"]["contracts"]
    lay = next(c for c in cfg if c["type"] == "layers")["layers"]
    return [[s.strip() for s in row.split("|")] for row in lay]




def layer_of(module: str) -> int:
    """Index in the layer list (0 = top, ``__main__``); -1 if not listed."""
    top = module.split(".")[1] if "." in module else module
    for i, row in enumerate(LAYERS):
        if top in row:
            return i
    return -1


def table_names() -> set[str]:
    """The scenario tables (fields of kind table / tables) the schema declares."""
    schema = PKG / "scenarios" / "schema.py"
    if not schema.exists():
        schema = HERE / "uavest" / "scenarios" / "schema.py"
    src = schema.read_text()
    out = set()
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.AnnAssign) and isinstance(node.value, ast.Call):
            f = node.value.func
            if isinstance(f, ast.Name) and f.id in ("T", "TS"):
                out.add(node.target.id)  # type: ignore[union-attr]
    return out




@dataclass
class Module:
    name: str
    path: Path
    tree: ast.Module
    imports: dict[str, str] = field(default_factory=dict)  # local name -> dotted target
    funcs: dict[str, ast.FunctionDef] = field(default_factory=dict)  # qualname -> def


def imported(m: Module, node: ast.ImportFrom) -> dict[str, str]:
    """{local name: dotted target} of one ``from ... import ...``."""
    pkg = m.name if m.path.name == "__init__.py" else m.name.rsplit(".", 1)[0]
    base = node.module or ""
    if node.level:
        up = pkg.split(".")
        up = up[: len(up) - node.level + 1]
        base = ".".join(up + ([base] if base else []))
    return {a.asname or a.name: f"{base}.{a.name}" for a in node.names}


def load_modules() -> dict[str, Module]:
    mods = {}
    for p in sorted(PKG.rglob("*.py")):
        rel = p.relative_to(ROOT).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        name = ".".join(parts)
        m = Module(name, p, ast.parse(p.read_text()))
        for node in m.tree.body:  # module-level imports (function-level: in the walk)
            if isinstance(node, ast.ImportFrom):
                m.imports.update(imported(m, node))
        for node in m.tree.body:
            if isinstance(node, ast.FunctionDef):
                m.funcs[node.name] = node
            elif isinstance(node, ast.ClassDef):
                for sub in node.body:
                    if isinstance(sub, ast.FunctionDef):
                        m.funcs[f"{node.name}.{sub.name}"] = sub
        mods[name] = m
    return mods




def resolve(mod: Module, func: ast.expr, local: dict | None = None
            ) -> tuple[Module, str] | None:
    """(module, qualname) of a called uavest function, or None (``local``: the calling
    function's own imports so far)."""
    imports = {**mod.imports, **(local or {})}
    if isinstance(func, ast.Name):
        if func.id in imports:
            target = imports[func.id]
        elif func.id in mod.funcs:
            return mod, func.id
        elif f"{func.id}.__init__" in mod.funcs:
            return mod, f"{func.id}.__init__"
        else:
            return None
    elif isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name):
        base = imports.get(func.value.id, func.value.id if func.value.id in
                               {c.split(".")[0] for c in mod.funcs} else None)
        if base is None:
            return None
        if base in {c.split(".")[0] for c in mod.funcs}:
            q = f"{base}.{func.attr}"
            return (mod, q) if q in mod.funcs else None
        target = f"{base}.{func.attr}"
    else:
        return None
    if not target or not target.startswith("uavest"):
        return None
    for cut in range(1, target.count(".") + 1):
        mname, rest = target.rsplit(".", cut)[0], ".".join(target.split(".")[-cut:])
        if mname in MODS:
            m = MODS[mname]
            if rest in m.funcs:
                return m, rest
            if f"{rest}.__init__" in m.funcs:
                return m, f"{rest}.__init__"
            if "." not in rest and rest in m.imports:  # re-export
                return resolve(m, ast.Name(rest))
            return None
    return None


def call_name(func: ast.expr) -> str:
    return func.id if isinstance(func, ast.Name) else (
        func.attr if isinstance(func, ast.Attribute) else "")


@dataclass
class Touch:
    path: str
    layer: int
    func: str
    what: str  # "scenario" | "part"


class Walk:
    def __init__(self) -> None:
        self.touches: list[Touch] = []
        self.below: set[str] = set()
        self.stack: list[str] = []
        self.local: list[dict[str, str]] = []  # per frame: the function's imports so far
        self.maker_calls: set[int] = set()  # calls whose result a maker returns

    def function(self, mod: Module, qual: str, bound: dict[str, str]) -> None:
        key = f"{mod.name}.{qual}"
        if key in self.stack or len(self.stack) > 30:
            return
        self.stack.append(key)
        fn = mod.funcs[qual]
        if "scenario" in bound.values() and layer_of(mod.name) > layer_of("uavest.scenarios"):
            self.below.add(key)
        names = dict(bound)
        if not names:  # a maker: what it returns is the scenario
            for node in ast.walk(fn):
                if isinstance(node, ast.Return) and node.value is not None:
                    self.returned(node.value, names)
        self.local.append({})
        self.body(mod, qual, fn.body, names)
        self.local.pop()
        self.stack.pop()

    def returned(self, e: ast.expr, names: dict[str, str]) -> None:
        """Mark what a maker returns: names (also in a tuple or subscripted), or the call
        to another maker (``_load(...)[1]``), followed as a maker in turn."""
        if isinstance(e, ast.Name):
            names[e.id] = "scenario"
        elif isinstance(e, ast.Tuple):
            for x in e.elts:
                self.returned(x, names)
        elif isinstance(e, ast.Subscript):
            self.returned(e.value, names)
        elif isinstance(e, ast.Call):
            self.maker_calls.add(id(e))

    def kind(self, e: ast.expr | None, names: dict[str, str]) -> str | None:
        """'scenario', 'part' or None for an expression."""
        if e is None:
            return None
        if isinstance(e, ast.Name):
            return names.get(e.id)
        if isinstance(e, ast.Call):
            if call_name(e.func) in MAKERS and any(
                    self.kind(a, names) == "scenario" for a in e.args):
                return "scenario"
            if call_name(e.func) in ("load_scenario", "load_typed"):
                return "scenario"
            f = e.func
            if (isinstance(f, ast.Attribute) and f.attr == "get" and e.args
                    and self.kind(f.value, names) == "scenario"
                    and isinstance(e.args[0], ast.Constant) and e.args[0].value in TABLES):
                return "part"
            if call_name(e.func) in ("dict", "list", "tuple") and e.args:
                return self.kind(e.args[0], names)
        if isinstance(e, ast.Attribute) and self.kind(e.value, names) == "scenario":
            return "part" if e.attr in TABLES else None
        if isinstance(e, ast.Subscript) and self.kind(e.value, names) == "scenario":
            s = e.slice
            return "part" if isinstance(s, ast.Constant) and s.value in TABLES else None
        if isinstance(e, ast.BoolOp):
            for v in e.values:
                k = self.kind(v, names)
                if k:
                    return k
        return None

    def body(self, mod: Module, qual: str, stmts: list[ast.stmt], names: dict) -> None:
        for st in stmts:
            if isinstance(st, ast.FunctionDef | ast.ClassDef):
                continue
            nodes = sorted((n for n in ast.walk(st) if hasattr(n, "lineno")),
                           key=lambda n: (n.lineno, n.col_offset))
            for n in nodes:
                self.node(mod, qual, n, names)
            if isinstance(st, ast.Assign | ast.AnnAssign):
                k = self.kind(st.value, names)
                tgts = st.targets if isinstance(st, ast.Assign) else [st.target]
                for t in tgts:
                    if isinstance(t, ast.Name):
                        if k:
                            names[t.id] = k
                        else:
                            names.pop(t.id, None)

    def touch(self, mod: Module, qual: str, what: str) -> None:
        self.touches.append(Touch(str(mod.path.relative_to(ROOT)), layer_of(mod.name),
                                  f"{mod.name}.{qual}", what))

    def node(self, mod: Module, qual: str, n: ast.AST, names: dict) -> None:
        if isinstance(n, ast.ImportFrom):
            self.local[-1].update(imported(mod, n))
        elif isinstance(n, ast.Attribute | ast.Subscript) and isinstance(n.value, ast.Name):
            k = names.get(n.value.id)
            if k:
                self.touch(mod, qual, k)
        elif isinstance(n, ast.Call):
            args = [(i, a) for i, a in enumerate(n.args)]
            kws = [(kw.arg, kw.value) for kw in n.keywords if kw.arg]
            passed = [(p, self.kind(a, names)) for p, a in args + kws]
            passed = [(p, k) for p, k in passed if k]
            if passed and call_name(n.func) in ALIASES:
                self.touch(mod, qual, "scenario")
                return
            if not passed:
                if call_name(n.func) in ("load_scenario", "load_typed") or (
                        id(n) in self.maker_calls):
                    target = resolve(mod, n.func, self.local[-1])
                    if target is not None:  # where the scenario is made
                        self.touch(mod, qual, "scenario")
                        self.function(*target, {})
                return
            target = resolve(mod, n.func, self.local[-1])
            if target is None:
                return
            m2, q2 = target
            fn = m2.funcs[q2]
            params = [a.arg for a in fn.args.posonlyargs + fn.args.args
                      + fn.args.kwonlyargs]
            if params and params[0] in ("self", "cls"):
                params = params[1:]
            bound = {}
            for p, k in passed:
                name = params[p] if isinstance(p, int) and p < len(params) else p
                if isinstance(name, str) and name in params:
                    bound[name] = k
            if bound:
                self.touch(mod, qual, max(bound.values(), key=lambda k: k == "scenario"))
                self.function(m2, q2, bound)


def summary(touches: list[Touch], kinds: tuple[str, ...]) -> tuple[list[str], int, list]:
    seq: list[Touch] = []
    for t in touches:
        if t.what in kinds and (not seq or seq[-1].path != t.path):
            seq.append(t)
    files = list(dict.fromkeys(t.path for t in seq))
    climbs = [(a.path, b.path) for a, b in zip(seq, seq[1:], strict=False)
              if b.layer < a.layer]
    return files, len(climbs), seq


def setup(root: Path) -> None:
    """Point the walk at the checkout ``root`` (its package, layers and schema)."""
    global ROOT, PKG, LAYERS, TABLES, MODS
    ROOT, PKG = root.resolve(), root.resolve() / "uavest"
    LAYERS = layers()
    TABLES = table_names()
    MODS = load_modules()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--verbose", action="store_true", help="print the touch sequences")
    ap.add_argument("--root", type=Path, default=ROOT,
                    help="the checkout to measure (default: this one), e.g. an export of "
                         "an earlier commit")
    a = ap.parse_args()
    setup(a.root)
    for entry, param in ENTRIES:
        mname, qual = entry.rsplit(".", 1)
        if mname not in MODS or qual not in MODS[mname].funcs:
            mname, cls = mname.rsplit(".", 1)
            qual = f"{cls}.{qual}"
        w = Walk()
        mod = MODS[mname]
        w.function(mod, qual, {param: "scenario"} if param else {"__seed__": "none"})
        print(f"{entry}:")
        for kinds, label in ((("scenario",), "scenario"), (("scenario", "part"),
                                                           "scenario or part")):
            files, climbs, seq = summary(w.touches, kinds)
            print(f"  {label:16s}: {len(files):2d} files, {climbs} climbs back up; "
                  + ", ".join(Path(f).relative_to("uavest").as_posix() for f in files))
            if a.verbose:
                print("    " + " -> ".join(f"{t.func.removeprefix('uavest.')}[{t.layer}]"
                                          for t in seq))
        print(f"  whole scenario received below the scenarios layer: {len(w.below)}"
              + (f" ({', '.join(sorted(x.removeprefix('uavest.') for x in w.below))})"
                 if w.below else ""))


if __name__ == "__main__":
    main()
