"""How the package's docstrings are read: NumPy-style sections, and references resolved as Python would.

1. Docstrings with ``Parameters`` / ``Returns`` sections (NumPy style) go through napoleon, except
   those of attributes, properties and module data: napoleon would read a first line such as
   ``The beliefs: (N, H, W) float64`` as ``type: description``, and the package writes those
   docstrings as prose.

2. A docstring inside ``gym_gridloc`` names things as its own module imports them
   (``:class:`GridModel``` in ``gym_gridloc.engine``), while the reference documents each exported
   object under its public name (``gym_gridloc.GridModel``). When Sphinx cannot resolve such a
   reference, it is looked up the way Python would (in the docstring's module, then its class) and,
   if that object is documented under any name, linked there. A name that Python cannot resolve, or
   whose object is not documented, stays a broken reference: with ``-n -W`` the build fails on it.
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any


# -- 1. napoleon, except for attributes ----------------------------------------------------------------
def _napoleon(app: Any, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    if what in ("attribute", "data", "property"):
        return
    from sphinx.ext.napoleon import Config
    from sphinx.ext.napoleon.docstring import GoogleDocstring, NumpyDocstring

    config = Config(napoleon_use_param=True, napoleon_use_rtype=True, napoleon_use_ivar=True)
    result = NumpyDocstring(lines, config, app, what, name, obj, options).lines()
    result = GoogleDocstring(result, config, app, what, name, obj, options).lines()
    lines[:] = result


# -- dataclass signatures ------------------------------------------------------------------------------
def _dataclass_signature(app: Any, what: str, name: str, obj: Any, options: Any, signature: str | None,
                         return_annotation: str | None) -> tuple[str | None, str | None] | None:
    """``infos: list[...] = <factory>`` is no Python Sphinx can parse: show ``= list()`` instead."""
    import dataclasses

    if not signature or "<factory>" not in signature or not dataclasses.is_dataclass(obj):
        return None
    for f in dataclasses.fields(obj):
        if f.init and f.default_factory is not dataclasses.MISSING:
            factory = getattr(f.default_factory, "__name__", "factory")
            signature = signature.replace("<factory>", f"{factory}()", 1)
    return signature, return_annotation


# -- 2. references resolved as Python resolves them -----------------------------------------------------
_MISSING = object()
_CACHE: dict[str, dict[int, tuple[str, str]]] = {}  # cleared when the read phase ends


def _lookup(path: str) -> Any:
    """The object a dotted path names (a module, then attributes), or _MISSING."""
    parts = path.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj: Any = importlib.import_module(".".join(parts[:i]))
        except Exception:
            continue
        for attr in parts[i:]:
            # class attributes through __dict__ first, so that a property is the property object
            d = getattr(obj, "__dict__", {})
            obj = d[attr] if attr in d else getattr(obj, attr, _MISSING)
            if obj is _MISSING:
                return _MISSING
        return obj
    return _MISSING


def _documented(app: Any) -> dict[int, tuple[str, str]]:
    """id(object) -> (documented name, object type), built once per build from the Python domain."""
    cache = _CACHE.get("documented")
    if cache is None:
        cache = _CACHE["documented"] = {}
        domain = app.env.get_domain("py")
        for name, entry in domain.objects.items():
            if getattr(entry, "aliased", False):
                continue
            obj = _lookup(name)
            if obj is not _MISSING and not isinstance(obj, (int, float, str, tuple, type(None))):
                cache.setdefault(id(obj), (name, entry.objtype))
        for name in domain.modules:
            obj = _lookup(name)
            if obj is not _MISSING:
                cache.setdefault(id(obj), (name, "module"))
    return cache


def _missing_reference(app: Any, env: Any, node: Any, contnode: Any) -> Any:
    if node.get("refdomain") != "py":
        return None
    target = node.get("reftarget", "")
    if not target or " " in target:
        return None
    target = target.lstrip("~.")
    module, cls = node.get("py:module"), node.get("py:class")
    candidates = []
    # In a docstring: the names its own module (and class) sees, whatever page shows it.
    source = str(node.source or "")
    if "docstring of " in source:
        owner_name = source.split("docstring of ", 1)[1].strip()
        owner = _lookup(owner_name)
        if owner is not _MISSING:
            owner = getattr(owner, "fget", owner)  # a property: its getter's module
            defined_in = owner.__name__ if inspect.ismodule(owner) else getattr(owner, "__module__", None)
            qual = getattr(owner, "__qualname__", "")
            if defined_in and inspect.isclass(owner):
                candidates.append(f"{defined_in}.{qual}.{target}")
            if defined_in and "." in qual:
                candidates.append(f"{defined_in}.{qual.rsplit('.', 1)[0]}.{target}")
            if defined_in:
                candidates.append(f"{defined_in}.{target}")
    if module and cls:
        candidates.append(f"{module}.{cls}.{target}")
    if module:
        candidates.append(f"{module}.{target}")
    candidates.append(target)
    if not any(c.startswith(("gym_gridloc", "gym_gridloc_agents")) for c in candidates):
        return None
    documented = _documented(app)
    for path in candidates:
        obj = _lookup(path)
        if obj is _MISSING:
            continue
        hit = documented.get(id(obj))
        if hit is None:
            return None  # Python finds it, but it is not documented: leave the reference broken
        name, objtype = hit
        domain = env.get_domain("py")
        role = "mod" if objtype == "module" else "obj"
        return domain.resolve_xref(env, node["refdoc"], app.builder, role, name, node, contnode)
    return None


def setup(app: Any) -> dict[str, Any]:
    app.connect("autodoc-process-docstring", _napoleon)
    app.connect("autodoc-process-signature", _dataclass_signature)
    app.connect("missing-reference", _missing_reference)
    app.connect("env-updated", lambda app, env: _CACHE.clear())
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
