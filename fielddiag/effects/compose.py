"""Compile numba loops (simulator, grey-box, on-line estimator) for a sum of effect kernels.

The one place where source is generated. A *template* is a plain function (no decorator)
in some module that calls the global ``model_force(r, rdot, x2, theta, consts, dtheta)``
(memoryless models) or ``model_force_z(r, rdot, x2, z, theta, consts, dtheta, dz)`` (with
internal states; ``model_state_partials(r, rdot, x2, z, theta, consts, dfz, dgs, dgz, dgp)``
gives the partial derivatives the states' sensitivity equations need, see
:attr:`~fielddiag.effects.base.Effect.state_partials`). For a combination of effect classes
a small module is generated: the effects' kernels imported, ``model_force``/``model_force_z``
written as the sum of the kernel calls on slices of the parameter, constant and state
vectors (``model_state_partials`` as the calls on their blocks), then the templates'
source, each under ``@njit(cache=True, nogil=True)``, with the template module's other
globals. It is written to the kernel cache directory under a name that hashes the
generator, the effect classes and the source files involved, and imported, so numba's
on-disk cache compiles each combination once, not in every process. Effects defined outside
an importable module (``__main__``) or an unwritable cache directory fall back to the same
source compiled in memory, per process.

Why generate rather than compose closures: numba cannot cache functions that close over
other jitted functions, so plain composition recompiles every loop in every process.
Measured (2026-11-25, shared 2-core machine at load ~9): the first grey-box simulation with
sensitivities of linear + coupling + friction in a fresh process takes 65-100 s when the
loop is compiled in memory (``FIELDDIAG_KERNEL_CACHE=""``, what closures would cost in
every process: the CLI, each diagnosis worker) and 4-5 s from the on-disk cache of the
generated module. First-class function objects would keep one cached loop but call every
kernel through a pointer, without inlining.
"""

from __future__ import annotations

import ast
import hashlib
import importlib
import importlib.util
import os
import sys
import textwrap
import threading
from collections.abc import Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from fielddiag.effects.base import Effect

__all__ = ["compile_templates", "model_force", "model_force_z", "model_state_partials"]

_BOUND_CACHE: dict[tuple[Any, ...], Any] = {}
_COMPILE_LOCK = threading.RLock()
#: Bump when the generated source changes shape.
_GENERATOR_VERSION = "4"
_FORCE_NAMES = ("model_force", "model_force_z", "model_state_partials")


def model_force(r, rd, x2, th, cs, dth):  # pragma: no cover - placeholder
    """Placeholder for the templates: replaced by each model's compiled force.

    Parameters
    ----------
    r, rd, x2 : float
        Suspension extension [m], its rate [m/s], body position [m].
    th, cs : ndarray
        The model's parameter and constant vectors.
    dth : ndarray
        Receives dF/dtheta.

    Returns
    -------
    (float, float, float, float)
        In the compiled version: F [N or N/kg], dF/dr, dF/drdot, dF/dx2.

    Raises
    ------
    NotImplementedError
        Always: call it only from a template compiled by :func:`compile_templates`.
    """
    raise NotImplementedError("templates are compiled per model by compile_templates")


def model_force_z(r, rd, x2, z, th, cs, dth, dz):  # pragma: no cover - placeholder
    """Placeholder for the templates (models with internal states).

    Parameters
    ----------
    r, rd, x2 : float
        Suspension extension [m], its rate [m/s], body position [m].
    z : ndarray
        The effects' internal states.
    th, cs : ndarray
        The model's parameter and constant vectors.
    dth, dz : ndarray
        Receive dF/dtheta and dz/dt.

    Returns
    -------
    (float, float, float, float)
        In the compiled version: F [N or N/kg], dF/dr, dF/drdot, dF/dx2.

    Raises
    ------
    NotImplementedError
        Always: call it only from a template compiled by :func:`compile_templates`.
    """
    raise NotImplementedError("templates are compiled per model by compile_templates")


def model_state_partials(r, rd, x2, z, th, cs, dfz, dgs, dgz, dgp):  # pragma: no cover
    """Placeholder for the templates: the partial derivatives of the force and of the
    states' rates (models with internal states whose effects all give them).

    Parameters
    ----------
    r, rd, x2 : float
        Suspension extension [m], its rate [m/s], body position [m].
    z : ndarray
        The effects' internal states.
    th, cs : ndarray
        The model's parameter and constant vectors.
    dfz, dgs, dgz, dgp : ndarray
        Receive dF/dz ``(n_states,)`` and the derivatives of dz/dt with respect to
        ``(r, rdot, x2)`` ``(n_states, 3)``, the states ``(n_states, n_states)`` and the
        parameters ``(n_states, n_params)``; blocks between different effects are not
        written (the caller keeps them zero).

    Raises
    ------
    NotImplementedError
        Always: call it only from a template compiled by :func:`compile_templates`.
    """
    raise NotImplementedError("templates are compiled per model by compile_templates")


def _partials_source(classes: tuple[type[Effect], ...]) -> tuple[list[str], list[str]]:
    """(import lines, body lines) of ``model_state_partials``."""
    imports: list[str] = []
    body: list[str] = []
    p0 = c0 = s0 = 0
    complete = True
    for i, cls in enumerate(classes):
        p1, c1, s1 = p0 + len(cls.params), c0 + len(cls.constants), s0 + cls.n_states
        if cls.n_states:
            if cls.state_partials is None:
                complete = False
            else:
                fn = cls.state_partials.py_func
                imports.append(f"from {fn.__module__} import {fn.__name__} as s{i}")
                body.append(f"    s{i}(r, rd, x2, z[{s0}:{s1}], th[{p0}:{p1}], cs[{c0}:{c1}], "
                            f"dfz[{s0}:{s1}], dgs[{s0}:{s1}], dgz[{s0}:{s1}, {s0}:{s1}], "
                            f"dgp[{s0}:{s1}, {p0}:{p1}])")
        p0, c0, s0 = p1, c1, s1
    lines = ["@njit(cache=CACHE, nogil=True)",
             "def model_state_partials(r, rd, x2, z, th, cs, dfz, dgs, dgz, dgp):"]
    if not complete or not body:
        return [], [*lines, "    raise NotImplementedError('no state partials for this model')",
                    "", ""]
    return imports, [*lines, *body, "    return 0", "", ""]


def _force_source(classes: tuple[type[Effect], ...]) -> tuple[list[str], list[str]]:
    """(import lines, body lines) of ``model_force``, ``model_force_z`` and
    ``model_state_partials``."""
    imports: list[str] = []
    calls: list[tuple[str, str]] = []  # (call without states, call with states)
    p0 = c0 = s0 = 0
    # without internal states the kernels are inlined where they are called (numba's IR
    # inlining): a call that is not inlined passes its array slices by reference count,
    # which costs more than the force itself in the simulation's inner loop (with states,
    # inlined into the larger loop body, they ran slower)
    inline = not any(cls.n_states for cls in classes)
    for i, cls in enumerate(classes):
        p1, c1, s1 = p0 + len(cls.params), c0 + len(cls.constants), s0 + cls.n_states
        fn = cls.kernel.py_func
        imports += [f"from {fn.__module__} import {fn.__name__} as _k{i}",
                    f"k{i} = njit(nogil=True, inline='always')(_k{i}.py_func)" if inline
                    else f"k{i} = _k{i}"]
        sl = f"th[{p0}:{p1}], cs[{c0}:{c1}], dth[{p0}:{p1}]"
        if cls.n_states:
            call = f"k{i}(r, rd, x2, z[{s0}:{s1}], {sl}, dz[{s0}:{s1}])"
            calls.append(("", call))
        else:
            call = f"k{i}(r, rd, x2, {sl})"
            calls.append((call, call))
        p0, c0, s0 = p1, c1, s1
    p_imports, lines = _partials_source(classes)
    imports += p_imports
    for name, args, pick in (("model_force", "r, rd, x2, th, cs, dth", 0),
                             ("model_force_z", "r, rd, x2, z, th, cs, dth, dz", 1)):
        how = ", inline='always'" if pick == 0 and inline else ""
        lines += [f"@njit(cache=CACHE, nogil=True{how})", f"def {name}({args}):"]
        if pick == 0 and any(not c[0] for c in calls):
            lines += ["    raise NotImplementedError('this model has internal states')", ""]
            continue
        lines += ["    f = 0.0", "    fr = 0.0", "    fv = 0.0", "    fx = 0.0"]
        for c in calls:
            lines += [f"    a, b, c, d = {c[pick]}", "    f += a", "    fr += b",
                      "    fv += c", "    fx += d"]
        lines += ["    return f, fr, fv, fx", "", ""]
    return imports, lines


def _kernel_dir() -> Path | None:
    """Directory of the generated kernel modules (None: keep them in memory only)."""
    env = os.environ.get("FIELDDIAG_KERNEL_CACHE")
    if env == "":
        return None
    from fielddiag.cachedir import cache_dir, writable

    if not env:
        return cache_dir("kernels")  # the per-user cache, never the installed package
    base = Path(env)
    return base if writable(base) else None


def _module_text(module_name: str) -> str:
    mod = sys.modules.get(module_name) or importlib.import_module(module_name)
    path = getattr(mod, "__file__", None)
    if not path:
        raise OSError(f"{module_name} has no source file")
    return Path(path).read_text()


def _template_source(text: str, names: Sequence[str], cache: bool, options: str = "",
                     inline: Sequence[str] = ()) -> list[str]:
    """The named top-level functions of a module's source, each under ``@njit`` (those in
    ``inline`` inlined into their callers by numba).

    The functions are found by name in the same text that is hashed for the cache key, so
    the generated module always matches its name even if the file changed meanwhile.
    """
    tree = ast.parse(text)
    found = {node.name: node for node in tree.body if isinstance(node, ast.FunctionDef)}
    out = []
    for name in names:
        if name not in found:
            raise SyntaxError(f"template {name!r} not found")
        src = ast.get_source_segment(text, found[name])
        how = ", inline='always'" if name in inline else ""
        out += [f"@njit(cache={cache}, nogil=True{options}{how})", textwrap.dedent(src).rstrip(),
                "", ""]
    return out


def compile_templates(classes: tuple[type[Effect], ...], module_name: str,
                      names: tuple[str, ...], error_model: str = "python") -> Any:
    """Compile the named templates of ``module_name`` for the sum of ``classes``' kernels.

    Parameters
    ----------
    classes : tuple of Effect subclasses
        The model's effects, in model order.
    module_name : str
        Importable module holding the templates.
    names : tuple of str
        Template function names.
    error_model : str
        numba's error model of the templates (``"numpy"``: division by zero gives inf
        instead of raising, and the loops carry no checks).

    Returns
    -------
    namespace
        The compiled templates (and ``model_force``, ``model_force_z``,
        ``model_state_partials``) by name, cached in
        memory and on disk per combination of effect classes.
    """
    key = (classes, module_name, names, error_model)
    ns = _BOUND_CACHE.get(key)
    if ns is not None:
        return ns
    with _COMPILE_LOCK:  # fits on threads (fielddiag.threads) compile a combination once
        ns = _BOUND_CACHE.get(key)
        return ns if ns is not None else _compile(key, classes, module_name, names, error_model)


def _compile(key: tuple[Any, ...], classes: tuple[type[Effect], ...], module_name: str,
             names: tuple[str, ...], error_model: str) -> Any:
    options = "" if error_model == "python" else f", error_model={error_model!r}"
    tmod_text = _module_text(module_name)
    # stage functions called in a template's inner loop (the template module's
    # INLINE_TEMPLATES): inlined, their array arguments are not reference-counted per call
    inline = tuple(getattr(sys.modules[module_name], "INLINE_TEMPLATES", ()))
    imports, lines = _force_source(classes)
    kernel_mods = sorted({c.kernel.py_func.__module__ for c in classes})
    header = [
        "from numba import njit",
        f"import {module_name} as _template_module",
        "globals().update({_k: _v for _k, _v in vars(_template_module).items()",
        f"                 if not _k.startswith('__') and _k not in "
        f"{(*_FORCE_NAMES, *names)!r}" "})",
        *imports,
        "",
        "",
    ]

    def source(cache: bool) -> str:
        return "\n".join([
            f'"""Generated by fielddiag.effects.compose from {module_name} '
            f"({', '.join(names)}) for {' + '.join(c.name for c in classes)}. Do not edit."
            '"""',
            *header, *(ln.replace("CACHE", str(cache)) for ln in lines),
            *_template_source(tmod_text, names, cache, options, inline),
        ])

    directory = _kernel_dir()
    result: Any = None
    if directory is not None and "__main__" not in kernel_mods:
        try:
            digest = hashlib.sha1("|".join(
                [_GENERATOR_VERSION, module_name, *names, error_model]
                + [f"{c.__module__}.{c.__qualname__}" for c in classes]
                + [hashlib.sha1(_module_text(m).encode()).hexdigest()
                   for m in sorted({*kernel_mods, __name__})]
                + [hashlib.sha1(tmod_text.encode()).hexdigest()]
            ).encode()).hexdigest()[:24]
            name = f"fielddiag_kernel_{digest}"
            path = directory / f"{name}.py"
            if not path.exists():
                tmp = path.with_name(f".{name}.{os.getpid()}.{threading.get_ident()}.tmp")
                tmp.write_text(source(True))
                os.replace(tmp, path)
            result = sys.modules.get(name)
            if result is None:
                spec = importlib.util.spec_from_file_location(name, path)
                result = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
                spec.loader.exec_module(result)  # type: ignore[union-attr]
                if not all(hasattr(result, n) for n in names):
                    path.unlink(missing_ok=True)
                    raise ImportError(f"{path} is incomplete")
                sys.modules[name] = result
        except (OSError, ImportError, SyntaxError):
            result = None
    if result is None:
        space: dict[str, Any] = {"__name__": f"fielddiag_kernel_{module_name}"}
        space.update({f"k{i}": c.kernel for i, c in enumerate(classes)})
        space.update({f"s{i}": c.state_partials for i, c in enumerate(classes)
                      if c.state_partials is not None})
        body = source(False).replace("\n".join(imports), "")
        exec(compile(body, f"<fielddiag kernel {module_name} {classes}>", "exec"), space)
        result = SimpleNamespace(**{n: space[n] for n in (*names, *_FORCE_NAMES)})
    _BOUND_CACHE[key] = result
    return result
