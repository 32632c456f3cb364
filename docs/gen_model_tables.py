r"""Generate the parameter tables of ``docs/models.md`` from the models' docstrings.

Usage::

    python docs/gen_model_tables.py           # rewrite the tables in docs/models.md
    python docs/gen_model_tables.py --check   # exit 1, naming every model whose table is stale

The models
----------
Every name in ``matfit.models.__all__`` that is a concrete subclass of
:class:`~matfit.models.AbstractBSDF`, or a function whose return annotation is one (a factory:
``CoatedConductor``). Each has a block in ``docs/models.md`` between the marker comments
``<!-- params:Name -->`` and ``<!-- /params:Name -->``; whatever stands between them is
replaced, everything else in the page is kept. A model without its markers is an error (in both
modes), as is a marker of a name that is not a model.

What a block holds
------------------
The constructor's signature, then one table row per entry of the ``Parameters`` section of the
model's own docstring (the class docstring; the function docstring of a factory), read by
numpydoc (:class:`numpydoc.docscrape.NumpyDocString`). The documented names must be exactly the
constructor's arguments, in any order. The columns are

==================  ==========================================================================
parameter           the entry's name(s), as code
type/shape          the type field (below), without its default
range               the range field; for a set type ``{...}`` without one, its members
default             the value after ``, default``; ``required`` when there is none
differentiable      ``yes``, ``no`` or ``static``, with the field's qualifier
meaning             the first sentence of the entry's description
==================  ==========================================================================

The grammar of an entry
-----------------------
::

    name : TYPE[, default DEFAULT][; RANGE]; DIFFERENTIABILITY
        Description: the first sentence becomes the meaning column.

The part after ``name :`` is split at the semicolons that stand outside braces, brackets,
parentheses and quotes, into two or three fields:

- ``TYPE`` (first field) is the type and shape, e.g. ``array_like, scalar or (..., C)`` or a set
  of choices ``{"ggx", "beckmann"}``; it may end with numpydoc's ``, default VALUE``.
- ``RANGE`` (middle field, optional) is the accepted values, e.g. ``>= 0``, ``[0, 1]``. Without
  it the range is the members of a set ``TYPE`` (whose type column is then ``str``, or ``bool``
  for ``{True, False}``), else ``–``.
- ``DIFFERENTIABILITY`` (last field) is one of ``differentiable[ QUALIFIER]`` (column
  ``yes[ QUALIFIER]``), ``not differentiable[ QUALIFIER]`` (``no[ QUALIFIER]``) and
  ``static, not differentiable`` (``static``: an ``eqx.field(static=True)`` option, whose change
  retraces).

An entry that does not follow it is an error naming the model and the parameter.

The text of the cells: reST's ``code`` becomes Markdown code, ``:math:`x``` becomes ``$x$``,
a cross-reference role ``:class:`~a.b.C``` becomes ```C``` (```a.b.C``` without the tilde), and
``|`` is escaped.
"""

from __future__ import annotations

import argparse
import inspect
import re
import sys
import warnings
from pathlib import Path

from numpydoc.docscrape import NumpyDocString

#: The page whose blocks are rewritten.
DOC_PATH = Path(__file__).resolve().parent / "models.md"

_OPEN = "<!-- params:{} -->"
_CLOSE = "<!-- /params:{} -->"
_MARKER = re.compile(r"<!-- (/?)params:([A-Za-z_][A-Za-z0-9_]*) -->")
_PAIRS = {"{": "}", "[": "]", "(": ")"}


def model_objects():
    """The models that get a table: ``{name: class or factory}`` in ``matfit.models.__all__`` order.

    Returns
    -------
    dict
        Concrete :class:`~matfit.models.AbstractBSDF` subclasses, and functions annotated to
        return one.
    """
    import matfit.models as mm

    out = {}
    for name in mm.__all__:
        obj = getattr(mm, name)
        if inspect.isclass(obj):
            if issubclass(obj, mm.AbstractBSDF) and not inspect.isabstract(obj):
                out[name] = obj
        elif inspect.isfunction(obj):
            ret = inspect.signature(obj, eval_str=True).return_annotation
            if inspect.isclass(ret) and issubclass(ret, mm.AbstractBSDF):
                out[name] = obj
    return out


def split_fields(text):
    """Split ``text`` at the semicolons outside brackets and quotes.

    Parameters
    ----------
    text : str
        The part of an entry after ``name :``.

    Returns
    -------
    list of str
        The stripped fields.
    """
    fields, depth, quote, start = [], [], None, 0
    for i, ch in enumerate(text):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'`":
            quote = ch
        elif ch in _PAIRS:
            depth.append(_PAIRS[ch])
        elif depth and ch == depth[-1]:
            depth.pop()
        elif ch == ";" and not depth:
            fields.append(text[start:i].strip())
            start = i + 1
    fields.append(text[start:].strip())
    return fields


def _set_members(type_text):
    """The members of a set type ``{a, b}``, or None."""
    t = type_text.strip()
    if not (t.startswith("{") and t.endswith("}")):
        return None
    return [m.strip() for m in t[1:-1].split(",") if m.strip()]


def _md(text):
    """reST inline markup of a docstring as Markdown (see the module docstring)."""
    text = re.sub(r":math:`([^`]*)`", r"$\1$", text)
    text = re.sub(r":[a-z]+:`~?([^`<]*?)\s*<[^`>]*>`", r"`\1`", text)
    text = re.sub(r":[a-z]+:`~([^`]*)`", lambda m: "`" + m.group(1).rsplit(".", 1)[-1] + "`", text)
    text = re.sub(r":[a-z]+:`([^`]*)`", r"`\1`", text)
    text = text.replace("``", "`")
    return text.replace("|", "\\|")


def _first_sentence(desc_lines):
    text = " ".join(line.strip() for line in desc_lines).strip()
    m = re.search(r"(?<!\be\.g)(?<!\bi\.e)\.(\s|$)", text)
    return text[: m.start() + 1] if m else text


def parse_entry(model, name, spec, desc):
    """One table row from a ``Parameters`` entry (see the grammar in the module docstring).

    Parameters
    ----------
    model : str
        The model, named in errors.
    name : str
        The entry's name(s), ``"eta"`` or ``"eta, k"``.
    spec : str
        The entry's type text (after ``name :``).
    desc : list of str
        The entry's description lines.

    Returns
    -------
    dict
        ``names`` (list of str) and the cells ``parameter``, ``type``, ``range``, ``default``,
        ``differentiable``, ``meaning`` (Markdown).

    Raises
    ------
    ValueError
        For an entry that does not follow the grammar.
    """
    where = f"{model}: parameter {name!r}"
    fields = split_fields(spec)
    if len(fields) not in (2, 3) or not all(fields):
        raise ValueError(f"{where}: expected 'TYPE[, default D][; RANGE]; DIFFERENTIABILITY', found {spec!r}")
    type_text, diff = fields[0], fields[-1]
    default = "required"
    m = re.search(r",\s*default\s+(.+)$", type_text)
    if m:
        default = f"`{m.group(1).strip()}`"
        type_text = type_text[: m.start()].strip()
    if re.search(r",\s*optional\s*$", type_text):
        raise ValueError(f"{where}: give its default (', default VALUE') instead of ', optional'")
    members = _set_members(type_text)
    if len(fields) == 3:
        rng = _md(fields[1])
    elif members is not None:
        rng = ", ".join(f"`{v}`" for v in members)
    else:
        rng = "–"
    if members is not None:
        kind = "bool" if set(members) <= {"True", "False"} else "str" if all(v[:1] in "\"'" for v in members) else "choice"
        type_cell = kind
    else:
        type_cell = _md(type_text)
    if diff == "static, not differentiable":
        diff_cell = "static"
    elif diff.startswith("not differentiable"):
        diff_cell = ("no " + diff[len("not differentiable"):].strip()).strip()
    elif diff.startswith("differentiable"):
        diff_cell = ("yes " + diff[len("differentiable"):].strip()).strip()
    else:
        raise ValueError(f"{where}: the last field must be 'differentiable[ ...]', 'not differentiable[ ...]' "
                         f"or 'static, not differentiable', found {diff!r}")
    names = [n.strip() for n in name.split(",")]
    return {
        "names": names,
        "parameter": ", ".join(f"`{n}`" for n in names),
        "type": type_cell,
        "range": rng,
        "default": default,
        "differentiable": _md(diff_cell),
        "meaning": _md(_first_sentence(desc)),
    }


def model_rows(name, obj):
    """The rows of a model's table, checked against its constructor's arguments.

    Parameters
    ----------
    name : str
        The model's name.
    obj : class or function
        The model class or factory.

    Returns
    -------
    list of dict
        :func:`parse_entry` of every entry, in the docstring's order.

    Raises
    ------
    ValueError
        For an entry off the grammar, or documented names that are not the constructor's arguments.
    """
    doc = inspect.cleandoc(obj.__doc__ or "")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        parsed = NumpyDocString(doc)
    rows = [parse_entry(name, p.name, p.type, p.desc) for p in parsed["Parameters"]]
    if not rows:
        raise ValueError(f"{name}: its docstring has no Parameters section")
    documented = [n for r in rows for n in r["names"]]
    args = [p for p in _signature(obj).parameters if p != "self"]
    if sorted(documented) != sorted(args):
        raise ValueError(f"{name}: the Parameters section documents {documented}, the constructor takes {args}")
    return rows


def _signature(obj):
    return inspect.signature(obj.__init__ if inspect.isclass(obj) else obj)


def _call(name, obj):
    parts = []
    for p in _signature(obj).parameters.values():
        if p.name == "self":
            continue
        if p.default is inspect.Parameter.empty:
            parts.append(p.name)
        else:
            parts.append(f"{p.name}={p.default!r}".replace("'", '"'))
    return f"{name}({', '.join(parts)})"


def render(name, obj):
    """The text of a model's block (between its markers, without them).

    Parameters
    ----------
    name, obj : str, class or function
        As for :func:`model_rows`.

    Returns
    -------
    str
    """
    cols = ("parameter", "type", "range", "default", "differentiable", "meaning")
    head = ("parameter", "type/shape", "range", "default", "differentiable", "meaning")
    lines = [
        "",
        "",
        f"Constructor: `{_call(name, obj)}`.",
        "",
        "| " + " | ".join(head) + " |",
        "| " + " | ".join("---" for _ in head) + " |",
    ]
    lines += ["| " + " | ".join(r[c] for c in cols) + " |" for r in model_rows(name, obj)]
    return "\n".join(lines) + "\n\n"


def update(text, models=None):
    """Rewrite every model's block of the page ``text``.

    Parameters
    ----------
    text : str
        The page.
    models : dict, optional
        ``{name: obj}`` (default :func:`model_objects`).

    Returns
    -------
    new_text : str
        The page with every block regenerated.
    stale : list of str
        The models whose block changed.
    problems : list of str
        Models without markers, unknown or unbalanced markers.
    """
    models = model_objects() if models is None else models
    problems = []
    found = {}
    for m in _MARKER.finditer(text):
        found.setdefault(m.group(2), []).append(m.group(1))
    for n, kinds in found.items():
        if n not in models:
            problems.append(f"{n}: a params marker for a name that is not an exported model")
        elif kinds != ["", "/"]:
            problems.append(f"{n}: expected one '{_OPEN.format(n)}' followed by one '{_CLOSE.format(n)}'")
    stale = []
    for n, obj in models.items():
        if n not in found:
            problems.append(f"{n}: no block '{_OPEN.format(n)}' ... '{_CLOSE.format(n)}' in the page")
            continue
        if found[n] != ["", "/"]:
            continue
        a = text.index(_OPEN.format(n)) + len(_OPEN.format(n))
        b = text.index(_CLOSE.format(n))
        new = render(n, obj)
        if text[a:b] != new:
            stale.append(n)
            text = text[:a] + new + text[b:]
    return text, stale, problems


def main(argv=None):
    """Rewrite the tables, or with ``--check`` report the stale ones.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (default ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit status: 0, or 1 when ``--check`` finds a stale table or a block is missing.
    """
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if a table is out of date; write nothing")
    ap.add_argument("--doc", type=Path, default=DOC_PATH, help="the page (default: docs/models.md)")
    args = ap.parse_args(argv)
    text = args.doc.read_text(encoding="utf-8")
    new, stale, problems = update(text)
    for p in problems:
        print(f"{args.doc}: {p}", file=sys.stderr)
    if args.check:
        for n in stale:
            print(f"{args.doc}: the parameter table of {n} is out of date; run python docs/gen_model_tables.py",
                  file=sys.stderr)
        return 1 if stale or problems else 0
    if new != text:
        args.doc.write_text(new, encoding="utf-8")
        print(f"{args.doc}: rewrote the tables of {', '.join(stale)}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
