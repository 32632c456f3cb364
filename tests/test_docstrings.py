"""Every public function, class and method of matfit documents itself NumPy style: Parameters
(when it takes any), Returns (unless it returns None), and Examples. Parsed with numpydoc's own
docstring reader, so a section that numpydoc cannot read counts as missing."""

import importlib
import inspect
import pkgutil
import warnings

import pytest
from numpydoc.docscrape import NumpyDocString

import matfit


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


def _returns_something(fn):
    ann = inspect.signature(fn).return_annotation
    return ann not in (None, "None")


@pytest.mark.parametrize("qualname, obj, owner", OBJECTS, ids=[o[0] for o in OBJECTS])
def test_numpy_docstring(qualname, obj, owner):
    doc = inspect.getdoc(obj if owner is None else getattr(owner, obj.__name__)) or ""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        parsed = NumpyDocString(doc)
    missing = []
    if not "".join(parsed["Summary"]).strip():
        missing.append("a summary line")
    if not parsed["Examples"]:
        missing.append("Examples")
    if inspect.isclass(obj):
        init = obj.__init__
        takes = (init is not object.__init__ and _takes_arguments(init, obj)) or bool(getattr(obj, "__dataclass_fields__", None))
        if takes and not (parsed["Parameters"] or parsed["Attributes"]):
            missing.append("Parameters (or Attributes)")
    else:
        if _takes_arguments(obj, owner) and not parsed["Parameters"]:
            missing.append("Parameters")
        if _returns_something(obj) and not (parsed["Returns"] or parsed["Yields"]):
            missing.append("Returns (or annotate the function `-> None`)")
    assert not missing, f"{qualname}: its docstring lacks {', '.join(missing)}"


def test_the_catalogue_is_not_empty():
    assert len(OBJECTS) > 150 and "matfit.fitting.lm" in PUBLIC_MODULES


@pytest.mark.parametrize("name", [m for m in PUBLIC_MODULES if m not in ("matfit.cli", "matfit.demo")])
def test_public_module_declares_its_api(name):
    """A public module says what is public (``__all__``), so that the check above sees it."""
    assert hasattr(importlib.import_module(name), "__all__"), f"{name} has no __all__"
