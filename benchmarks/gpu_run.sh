#!/usr/bin/env bash
# The benchmarks on a lent GPU machine, in one call (docs/performance.md, "GPU").
#
#   bash benchmarks/gpu_run.sh [OUTDIR] [quick]
#
# Expects, beside the repository's files (benchmarks/gpu_prepare.sh makes both): .whl/ (wheels the
# machine's image lacks: emcee, and a mitsuba wheel cut down to its cuda_ad_rgb variant, with drjit)
# and .devshared/ (shared/tools and shared/data/merl_nbrdf, from which bench_fit_merl writes the MERL
# table). Run it as: run(command="bash benchmarks/gpu_run.sh $OUT", carry=[".whl", ".devshared"]). Every script writes its
# JSON to OUTDIR (MATFIT_BENCH_RESULTS) and its log to OUTDIR/<name>.log; each runs under its own
# time limit, so one that fails or overruns leaves the others' results. "quick" shrinks every size
# (a dry run of this script on a CPU machine).
set -u -o pipefail
OUT_DIR=${1:-${OUT:-/tmp/matfit_gpu}}
QUICK=${2:-}
mkdir -p "$OUT_DIR"
PY=${PYTHON:-python3}
if [ -d .whl ] && ls .whl/*.whl >/dev/null 2>&1; then
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || echo "wheel install failed"
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD
fi
# JAX takes half the GPU's memory, leaving room for Mitsuba's CUDA backend in the eval step.
export MATFIT_BENCH_RESULTS=$OUT_DIR PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_MEM_FRACTION=0.5
SHARED=${SHARED:-.devshared}
nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.sm,clocks.max.sm --format=csv 2>&1 | tee "$OUT_DIR/gpu.txt"
$PY -c "import jax, numpy; print('jax', jax.__version__, jax.devices(), 'numpy', numpy.__version__)" 2>&1 | tee -a "$OUT_DIR/gpu.txt"

step() {  # step NAME LIMIT_S CMD...
  local name=$1 limit=$2; shift 2
  local t0=$SECONDS
  timeout "$limit" "$@" > "$OUT_DIR/$name.log" 2>&1
  local rc=$?
  echo "== $name: rc $rc, $((SECONDS - t0)) s"
  tail -n 14 "$OUT_DIR/$name.log"
}

if [ "$QUICK" = quick ]; then
  step fit_merl 300 $PY benchmarks/bench_fit_merl.py --shared "$SHARED" --families conductor --quick --repeats 1 \
    --out "$OUT_DIR/fit_merl_conductor.json"
  step batched 300 $PY benchmarks/bench_batched.py --quick
  step emcee 300 $PY benchmarks/bench_emcee.py --quick
  step eval 300 $PY benchmarks/bench_eval.py --n 20000 --repeat 2 --models conductor_ggx,plastic_rough \
    --mitsuba-variant "${MITSUBA_VARIANT:-llvm_ad_rgb}"
else
  # plastic last: new in this script, and the longest (its scipy run alone is ~1 min)
  step fit_merl 120 $PY benchmarks/bench_fit_merl.py --shared "$SHARED" --families conductor --repeats 2 \
    --out "$OUT_DIR/fit_merl_conductor.json"
  step batched 75 $PY benchmarks/bench_batched.py --scipy-texels 100 --repeats 3
  step emcee 50 $PY benchmarks/bench_emcee.py --steps 2000 --numpy-steps 150 --repeats 3 --rounds 3
  step eval 120 $PY benchmarks/bench_eval.py --n 8000000 --numpy-n 1000000 --repeat 5 --mitsuba-variant cuda_ad_rgb \
    --models lambert,conductor_ggx,conductor_beckmann,blend_lambert_ggx,plastic_smooth
  step fit_merl_plastic 150 $PY benchmarks/bench_fit_merl.py --shared "$SHARED" --families plastic --repeats 1 \
    --out "$OUT_DIR/fit_merl_plastic.json"
fi
ls -la "$OUT_DIR"
