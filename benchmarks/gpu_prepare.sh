#!/usr/bin/env bash
# Prepare what benchmarks/gpu_run.sh needs beside the repository, on a machine with PyPI access:
#   .whl/        emcee, drjit, and a mitsuba wheel cut down to its cuda_ad_rgb variant and the BSDF
#                plugins bench_eval loads (the full wheel, 63 MB, is too large to travel with a call)
#   .devshared/  shared/tools and shared/data/merl_nbrdf (bench_fit_merl writes the MERL table from them)
# Both folders are ignored by git (.git/info/exclude). The GPU machine's Python is 3.12.
#
#   bash benchmarks/gpu_prepare.sh [SHARED=../shared]
set -euo pipefail
SHARED=${1:-../shared}
PY=${PYTHON:-.venv/bin/python}
for p in /.whl/ /.devshared/; do grep -qxF "$p" .git/info/exclude 2>/dev/null || echo "$p" >> .git/info/exclude; done
rm -rf .whl .devshared && mkdir -p .whl .devshared/data
cp -r "$SHARED/tools" .devshared/ && cp -r "$SHARED/data/merl_nbrdf" .devshared/data/
dl() { $PY -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux2014_x86_64 -d "$1" "$2"; }
dl .whl emcee==3.1.6
dl .whl drjit==1.5.0
tmp=$(mktemp -d)
dl "$tmp" mitsuba==3.9.1
(cd "$tmp" && mkdir x && cd x && unzip -q ../mitsuba-*.whl)
m=$tmp/x/mitsuba
for f in "$m"/*_ad_*.so; do case $f in *cuda_ad_rgb.cpython*) ;; *) rm "$f";; esac; done
rm -rf "$m/include" "$m/cmake" "$m/data/sunsky" "$m/data/srgb.coeff"
keep=" roughconductor conductor diffuse plastic roughplastic dielectric roughdielectric thindielectric blendbsdf srgb uniform twosided "
for f in "$m"/plugins/*.so; do b=$(basename "$f" .so); case $keep in *" $b "*) ;; *) rm "$f";; esac; done
# pip install --no-deps of a wheel reads its RECORD; an empty one lists nothing that was removed
(cd "$tmp/x" && : > mitsuba-3.9.1.dist-info/RECORD && zip -q -r -9 "$OLDPWD/.whl/$(basename "$tmp"/mitsuba-*.whl)" .)
rm -rf "$tmp"
ls -la .whl
