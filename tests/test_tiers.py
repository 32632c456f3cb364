"""The `make check` tier (tests marked ``@pytest.mark.check``) covers every test file."""

import re
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


@pytest.mark.check
def test_every_test_file_has_a_check_tier_test():
    # a test marked whole, or one of its parametrizations (``pytest.param(..., marks=pytest.mark.check)``)
    marked = re.compile(r"^@pytest\.mark\.check\n(?:@.*\n|\s.*\n)*def test_\w+\(|marks=pytest\.mark\.check\b", flags=re.M)
    files = sorted(p for p in HERE.glob("test_*.py") if p.name != "test_tiers.py")
    assert len(files) > 40
    unmarked = [p.name for p in files if not marked.search(p.read_text())]
    assert not unmarked, f"no test marked @pytest.mark.check in {unmarked}"
