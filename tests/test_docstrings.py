"""matfit's documentation rule: docs that teach, at the level where they teach.

- A public module opens with a docstring (what it holds, the math where it has some).
- A public class carries the math, its parameter table (Parameters or Attributes, when it takes
  any) and an Examples section that teaches.
- Arguments are documented once: a class need not repeat those a base's table names (MRO).
- A public function documents its arguments (Parameters, when it takes any) and what it returns
  (Returns, unless it returns None); an example where one teaches.
- A public method needs a summary line; a one-line method gets a one-line docstring.
- Across ``matfit/`` docstring lines are at most 0.8 x the code lines, and at most 2 x in every
  module of 50 or more code lines (:func:`doc_code_lines` counts them).

Sections are parsed with numpydoc's own reader, so a section numpydoc cannot read counts as
missing."""

import ast
import importlib
import inspect
import pathlib
import pkgutil
import warnings

import pytest
from numpydoc.docscrape import NumpyDocString

import matfit

#: Docstring lines / code lines: across the package, and in one module of ``MODULE_MIN_CODE`` or
#: more code lines.
PACKAGE_RATIO, MODULE_RATIO, MODULE_MIN_CODE = 0.8, 2.0, 50


def _public_module_names():
    """Every module of matfit without a private (underscore) part in its name."""
    names = ["matfit"]
    for info in pkgutil.walk_packages(matfit.__path__, "matfit."):
        if not any(part.startswith("_") for part in info.name.split(".")[1:]):
            names.append(info.name)
    return names


#: The public modules: what each lists in ``__all__`` is public.
PUBLIC_MODULES = tuple(_public_module_names())


def _public_objects():
    seen = {}
    for mn in PUBLIC_MODULES:
        mod = importlib.import_module(mn)
        for name in getattr(mod, "__all__", ()):
            obj = getattr(mod, name)
            if inspect.isfunction(obj) or inspect.isclass(obj):
                seen.setdefault(f"{obj.__module__}.{obj.__qualname__}", obj)
    out = []
    for q, obj in sorted(seen.items()):
        out.append((q, obj, None))
        if inspect.isclass(obj):
            for an, a in vars(obj).items():
                if not an.startswith("_") and inspect.isfunction(a):
                    out.append((f"{q}.{an}", a, obj))
    return out


OBJECTS = _public_objects()


def _takes_arguments(fn, owner):
    params = list(inspect.signature(fn).parameters.values())
    if owner is not None and params and params[0].name in ("self", "cls"):
        params = params[1:]
    return bool(params)


def _section_names(parsed):
    """The names a parsed docstring's Parameters and Attributes give (``a, b : float`` gives two)."""
    return {n.strip().lstrip("*") for item in (*parsed["Parameters"], *parsed["Attributes"])
            for n in item.name.split(",")}


def inherited_names(cls):
    """The argument names documented in the Parameters or Attributes of ``cls``'s base classes."""
    names = set()
    for base in cls.__mro__[1:]:
        doc = base.__dict__.get("__doc__")
        if doc:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                names |= _section_names(NumpyDocString(inspect.cleandoc(doc)))
    return names


def _init_arguments(cls):
    """The constructor's argument names (a builtin ``__init__``'s ``**kwargs``, as ``ValueError``'s, aside)."""
    params = list(inspect.signature(cls.__init__).parameters.values())[1:]
    builtin = not inspect.isfunction(cls.__init__)
    return {p.name for p in params if not (builtin and p.kind is p.VAR_KEYWORD)}


def _returns_something(fn):
    ann = inspect.signature(fn).return_annotation
    return ann not in (None, "None")


def doc_code_lines(path):
    """``(docstring lines, code lines)`` of one source file: non-blank lines inside the docstrings
    of the module, its classes and functions; non-blank lines outside them that are not comments."""
    src = pathlib.Path(path).read_text()
    lines = src.splitlines()
    doc = set()
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            first = node.body[0] if node.body else None
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                doc.update(range(first.lineno, first.end_lineno + 1))
    n_doc = sum(1 for i in doc if lines[i - 1].strip())
    n_code = sum(1 for i, line in enumerate(lines, 1)
                 if i not in doc and line.strip() and not line.strip().startswith("#"))
    return n_doc, n_code


SOURCES = sorted(pathlib.Path(matfit.__file__).parent.rglob("*.py"))


@pytest.mark.parametrize("qualname, obj, owner", OBJECTS, ids=[o[0] for o in OBJECTS])
def test_numpy_docstring(qualname, obj, owner):
    doc = inspect.getdoc(obj if owner is None else getattr(owner, obj.__name__)) or ""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        parsed = NumpyDocString(doc)
    missing = []
    if not "".join(parsed["Summary"]).strip():
        missing.append("a summary line")
    if owner is not None:  # a method: a summary line is the rule; sections where they teach
        pass
    elif inspect.isclass(obj):
        if not parsed["Examples"]:
            missing.append("Examples")
        init = obj.__init__
        takes = (init is not object.__init__ and _takes_arguments(init, obj)) or bool(getattr(obj, "__dataclass_fields__", None))
        inherited = _init_arguments(obj) <= inherited_names(obj)  # documented once, in a base class
        if takes and not (parsed["Parameters"] or parsed["Attributes"]) and not inherited:
            missing.append("Parameters (or Attributes)")
    else:
        if _takes_arguments(obj, owner) and not parsed["Parameters"]:
            missing.append("Parameters")
        if _returns_something(obj) and not (parsed["Returns"] or parsed["Yields"]):
            missing.append("Returns (or annotate the function `-> None`)")
    assert not missing, f"{qualname}: its docstring lacks {', '.join(missing)}"


@pytest.mark.check
def test_the_catalogue_is_not_empty():
    assert len(OBJECTS) > 150 and "matfit.fitting.lm" in PUBLIC_MODULES


@pytest.mark.parametrize("name", PUBLIC_MODULES)
def test_public_module_opens_with_a_docstring(name):
    doc = importlib.import_module(name).__doc__ or ""
    assert doc.strip(), f"{name} has no module docstring"


@pytest.mark.parametrize("name", [m for m in PUBLIC_MODULES if m not in ("matfit.cli", "matfit.demo")])
def test_public_module_declares_its_api(name):
    """A public module says what is public (``__all__``), so that the check above sees it."""
    assert hasattr(importlib.import_module(name), "__all__"), f"{name} has no __all__"


def test_docs_do_not_outweigh_the_code():
    """Docstring lines <= 0.8 x code lines across matfit, <= 2 x in each module of >= 50 code lines."""
    root = pathlib.Path(matfit.__file__).parent
    counts = {str(p.relative_to(root)): doc_code_lines(p) for p in SOURCES}
    n_doc = sum(d for d, _ in counts.values())
    n_code = sum(c for _, c in counts.values())
    heavy = {k: f"{d}/{c} = {d / c:.2f}" for k, (d, c) in counts.items()
             if c >= MODULE_MIN_CODE and d > MODULE_RATIO * c}
    assert n_doc <= PACKAGE_RATIO * n_code, f"matfit: {n_doc} docstring lines / {n_code} code lines = {n_doc / n_code:.2f} > {PACKAGE_RATIO}"
    assert not heavy, f"modules whose docstrings outweigh their code > {MODULE_RATIO} x: {heavy}"
