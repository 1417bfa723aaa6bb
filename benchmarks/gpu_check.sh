#!/bin/bash
# The GPU checks of docs/benchmarks.md ("On a GPU") in one go, on a machine with CUDA and
# PyTorch: build a wheel of this checkout, then the CUDA tests, the decisions against the CPU
# filter, the speed table, the native filter's speed on the same host cores, the decisions on a
# dense street with the static verification base, the profile, the fast preset's rows (GPU and
# native) and the 32-view street row, each step capped in time and in this order, so that a
# short time on a GPU machine measures what matters most.
#
#     bash benchmarks/gpu_check.sh [OUTDIR] [SECONDS]
#
# OUTDIR (default gpu-out) receives the wheel, each step's full output and log.txt; SECONDS
# (default 520) is the time for all the steps together. The last lines of each step are
# printed as it ends.
set -u
out=${1:-gpu-out}; deadline=${2:-520}
mkdir -p "$out" && out=$(cd "$out" && pwd)
export PYTHONUNBUFFERED=1
t0=$(date +%s)
log="$out/log.txt"
say() { echo "[$(( $(date +%s) - t0 ))s] $*" | tee -a "$log"; }
step() {  # step NAME CAP LINES COMMAND...: run COMMAND for at most CAP seconds (less if late)
    local name=$1 cap=$2 lines=$3; shift 3
    local left=$(( deadline - ($(date +%s) - t0) ))
    [ "$left" -lt "$cap" ] && cap=$left
    if [ "$cap" -lt 15 ]; then say "skipped $name (no time left)"; return; fi
    say "start $name (at most ${cap} s)"
    timeout "$cap" "$@" > "$out/$name.txt" 2>&1
    say "end $name: exit $?"
    tail -n "$lines" "$out/$name.txt"
}
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee -a "$log"
python3 -c "import sys, torch; print(sys.version.split()[0], torch.__version__, torch.cuda.get_device_name())" | tee -a "$log"
say "build"
python3 -m pip wheel -q --no-build-isolation --no-deps -w "$out" . >> "$log" 2>&1 \
    || { say "build failed"; tail -30 "$log"; exit 1; }
python3 -m pip install -q --no-index --no-deps --target "$out/site" "$out"/clearsplat-*.whl \
    >> "$log" 2>&1 || { say "install failed"; exit 1; }
export PYTHONPATH="$out/site"
python3 -c "import clearsplat; print('clearsplat', clearsplat.__version__)" | tee -a "$log"
step tests 90 6 python3 -m pytest -q -p no:cacheprovider tests/test_torch_backend.py -k cuda
step decisions 80 12 python3 benchmarks/gpu_decisions.py --views 4,8 --set backend=torch
step speed_object 170 30 python3 benchmarks/filter_speed.py --device cuda --set backend=torch \
    --views 4,8,16 --repeats 2 --full-repeats 1
step speed_native 100 30 python3 benchmarks/filter_speed.py --views 4,8,16 --repeats 2 \
    --full-repeats 1
step decisions_dense 90 12 python3 benchmarks/gpu_decisions.py --views 24 --family street \
    --resolution 128x224 --set backend=torch --set verify_base=static
step profile 60 40 python3 benchmarks/gpu_profile.py --views 4 --rows 12
step speed_fast 70 12 python3 benchmarks/filter_speed.py --device cuda --set backend=torch \
    --preset fast --views 8,16 --repeats 1 --full-repeats 1
step speed_fast_native 40 12 python3 benchmarks/filter_speed.py --preset fast --views 8,16 \
    --repeats 1 --full-repeats 0
step speed_street 120 12 python3 benchmarks/filter_speed.py --device cuda --set backend=torch \
    --views 32 --family street --repeats 1 --full-repeats 1
say "done"
