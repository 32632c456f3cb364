"""The `make check` tier covers every test file, and every test it names exists."""

import re
from pathlib import Path

from conftest import CHECK_TIER

HERE = Path(__file__).resolve().parent


def test_check_tier_names_every_test_file_and_only_existing_tests():
    files = sorted(p.name for p in HERE.glob("test_*.py") if p.name != "test_tiers.py")
    assert sorted(CHECK_TIER) == files
    for name, tests in CHECK_TIER.items():
        src = (HERE / name).read_text()
        defined = set(re.findall(r"^def (test_\w+)\(", src, flags=re.M))
        assert tests and set(tests) <= defined, f"{name}: {sorted(set(tests) - defined)} not defined there"
