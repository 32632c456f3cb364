PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test check install bench clean

$(PY):
	$(PYTHON) -m venv $(VENV) || python3 -m venv $(VENV)

$(STAMP): $(PY) pyproject.toml
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

# The models tour (lobes.png, albedo.csv), then the main job on data_synth/scenes/demo.toml:
# synthesize demo_out/demo_synth.npz, fit, sample the posterior, report (demo_out/report/), compare.
demo: $(STAMP)
	$(PY) -m matfit demo --out demo_out
	$(PY) -m matfit info demo_out/demo_synth.npz

test: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile tests matfit docs/examples.md --doctest-modules --doctest-glob='*.md'

# The quick tier while working (a few minutes): the tests marked `@pytest.mark.check` (one or a
# few per test file), the library's doctests and docs/examples.md.
check: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile -m check tests matfit docs/examples.md --doctest-modules --doctest-glob='*.md'

bench: $(STAMP)
	$(PY) benchmarks/run_all.py

clean:
	rm -rf $(VENV) demo_out .pytest_cache
