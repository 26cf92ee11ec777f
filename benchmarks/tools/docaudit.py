"""List public functions, methods and classes whose numpydoc docstring is missing or thin.

Usage::

    python benchmarks/tools/docaudit.py [--returns] [--deep] PATH ...

PATH is a package directory (searched recursively) or a ``.py`` file. A public name does
not start with ``_``; module-level functions and classes and the methods of public classes
are checked. Reported:

* ``NO DOC``: no docstring (properties need only a one-line docstring);
* ``no Parameters``: a function or method with arguments (besides ``self``/``cls``) whose
  docstring has no ``Parameters`` section;
* with ``--returns``: ``no Returns``: a function with a return annotation other than
  ``None`` (not a property) whose docstring has neither ``Returns`` nor ``Yields``;
* with ``--deep``: arguments missing from the ``Parameters`` section, and functions that
  raise directly without a ``Raises`` section.

Prints one line per finding, then ``<checked> <findings>``; exits 1 when anything is
reported. A static check (``ast``): it imports nothing.
"""

from __future__ import annotations

import ast
import pathlib
import re
import sys


def _public_items(tree: ast.Module):
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.ClassDef) and not node.name.startswith("_"):
            yield node.name, node
            if isinstance(node, ast.ClassDef):
                for m in node.body:
                    if isinstance(m, ast.FunctionDef) and not m.name.startswith("_"):
                        yield f"{node.name}.{m.name}", m


def _arg_names(fn: ast.FunctionDef) -> list[str]:
    a = fn.args
    names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
    names += [x.arg for x in (a.vararg, a.kwarg) if x is not None]
    return [n for n in names if n not in ("self", "cls")]


def _is_property(fn: ast.FunctionDef) -> bool:
    return any(getattr(d, "id", getattr(d, "attr", "")) in ("property", "cached_property")
               for d in fn.decorator_list)


def _returns_value(fn: ast.FunctionDef) -> bool:
    r = fn.returns
    return r is not None and not (isinstance(r, ast.Constant) and r.value is None)


def audit(path: pathlib.Path, returns: bool, deep: bool) -> tuple[int, list[str]]:
    """Check one file; (number of public items, findings)."""
    tree = ast.parse(path.read_text())
    checked, out = 0, []
    for qual, node in _public_items(tree):
        checked += 1
        doc = ast.get_docstring(node) or ""
        where = f"{path}:{node.lineno} {qual}"
        if not doc:
            out.append(f"{where} NO DOC")
            continue
        if not isinstance(node, ast.FunctionDef):
            continue
        args = _arg_names(node)
        if args and "Parameters" not in doc:
            out.append(f"{where} no Parameters")
            continue
        if (returns and not _is_property(node) and _returns_value(node)
                and "Returns" not in doc and "Yields" not in doc):
            out.append(f"{where} no Returns")
        if deep:
            section = doc.split("Parameters", 1)[1] if "Parameters" in doc else ""
            missing = [a for a in args if not re.search(rf"\b{a}\b", section)]
            if missing:
                out.append(f"{where} parameters not documented: {missing}")
            raised = [r for r in ast.walk(node) if isinstance(r, ast.Raise) and r.exc]
            if raised and "Raises" not in doc and node.name != "__init__":
                out.append(f"{where} raises without a Raises section")
    return checked, out


def main(argv: list[str]) -> int:
    """Run the audit on the paths in ``argv``; 1 if anything is reported."""
    flags = {a for a in argv if a.startswith("--")}
    paths = [pathlib.Path(a) for a in argv if not a.startswith("--")]
    if not paths:
        print(__doc__)
        return 2
    total, findings = 0, []
    for p in paths:
        for f in [p] if p.is_file() else sorted(p.rglob("*.py")):
            n, out = audit(f, "--returns" in flags, "--deep" in flags)
            total += n
            findings += out
    print("\n".join(findings + [f"{total} {len(findings)}"]))
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
