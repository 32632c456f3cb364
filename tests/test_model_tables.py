"""The parameter tables of docs/models.md are generated from the models' docstrings
(docs/gen_model_tables.py) and up to date; every exported model has one."""

import importlib.util
import inspect
from pathlib import Path

import pytest

import matfit.models as mm

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "docs" / "gen_model_tables.py"
DOC = ROOT / "docs" / "models.md"


def _load():
    spec = importlib.util.spec_from_file_location("gen_model_tables", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


gen = _load()


def _exported_models():
    """Every concrete model class that matfit.models exports, found here without the script."""
    return sorted(n for n in mm.__all__
                  if inspect.isclass(getattr(mm, n)) and issubclass(getattr(mm, n), mm.AbstractBSDF)
                  and not inspect.isabstract(getattr(mm, n)))


@pytest.mark.check
def test_tables_are_up_to_date():
    assert gen.main(["--check"]) == 0, "run python docs/gen_model_tables.py"


def test_every_exported_model_has_a_block():
    text = DOC.read_text(encoding="utf-8")
    names = _exported_models() + ["CoatedConductor"]  # the factory of a Layered gets one too
    assert set(names) <= set(gen.model_objects())
    for n in names:
        a, b = f"<!-- params:{n} -->", f"<!-- /params:{n} -->"
        assert text.count(a) == 1 and text.count(b) == 1 and text.index(a) < text.index(b), n
        assert "| `" in text[text.index(a):text.index(b)], f"{n}: its block has no table rows"


def test_check_names_the_stale_model(tmp_path, capsys):
    text = DOC.read_text(encoding="utf-8")
    a = "<!-- params:RoughConductor -->"
    stale = tmp_path / "models.md"
    stale.write_text(text.replace(a, a + "\n| a hand-written row |"), encoding="utf-8")
    assert gen.main(["--check", "--doc", str(stale)]) == 1
    assert "RoughConductor" in capsys.readouterr().err
    assert gen.main(["--doc", str(stale)]) == 0  # rewriting repairs it
    assert stale.read_text(encoding="utf-8") == text


def test_check_names_a_model_without_a_block(tmp_path, capsys):
    text = DOC.read_text(encoding="utf-8")
    i, j = text.index("<!-- params:Blend -->"), text.index("<!-- /params:Blend -->")
    missing = tmp_path / "models.md"
    missing.write_text(text[:i] + text[j + len("<!-- /params:Blend -->"):], encoding="utf-8")
    assert gen.main(["--check", "--doc", str(missing)]) == 1
    assert "Blend: no block" in capsys.readouterr().err


def test_entry_grammar():
    row = gen.parse_entry("M", "distribution", '{"ggx", "beckmann"}, default "ggx"; static, not differentiable',
                          ["The distribution. More text."])
    assert (row["type"], row["range"], row["default"], row["differentiable"], row["meaning"]) == (
        "str", '`"ggx"`, `"beckmann"`', '`"ggx"`', "static", "The distribution.")
    row = gen.parse_entry("M", "alpha", "array_like, scalar or (...), default 0.2; >= 0; differentiable when rough",
                          ["Width :math:`\\alpha` (``ALPHA_MIN``)."])
    assert (row["type"], row["range"], row["default"], row["differentiable"], row["meaning"]) == (
        "array_like, scalar or (...)", ">= 0", "`0.2`", "yes when rough", "Width $\\alpha$ (`ALPHA_MIN`).")
    for bad in ("array_like", "array_like; >= 0; maybe", "array_like, optional; differentiable"):
        with pytest.raises(ValueError, match="M: parameter 'x'"):
            gen.parse_entry("M", "x", bad, [])
