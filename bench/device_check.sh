#!/usr/bin/env bash
# The GPU checks of issues 3 (registration) and 7 (super-resolution) in one short run on a lent GPU
# machine (the session's `device` tool), about 3 minutes once the machine is up:
#
#   here, once:  bash bench/device_check.sh --prepare
#                (copies the pure-Python packages the GPU machine lacks, filterpy, into .device_site/,
#                 which .git/info/exclude ignores; torch, OpenCV, numpy, scipy, tqdm, yaml, pytest and
#                 matplotlib are there already)
#   device:      run(command="bash bench/device_check.sh", carry=[".device_site"], timeout_s=480)
#
# It prints the GPU and torch versions, runs the CUDA variants of the registration and SR tests,
# bench/registration.py on cuda (no baseline: the OpenCV figures are CPU figures, taken here),
# bench/registration_profile.py on cuda (per-stage ms, kernels and synchronisations per frame) and
# bench/sr.py's speed section on the CPU and the GPU (the 20x goal). Everything goes to
# $OUT/device_check.log (or bench/out/device/ without the tool).
set -uo pipefail
cd "$(dirname "$0")/.."

if [ "${1:-}" = "--prepare" ]; then
    mkdir -p .device_site
    site=$(.venv/bin/python -c 'import filterpy, os; print(os.path.dirname(os.path.dirname(filterpy.__file__)))') || exit 1
    rm -rf .device_site/filterpy && cp -r "$site/filterpy" .device_site/
    grep -qx '/.device_site/' .git/info/exclude 2>/dev/null || echo '/.device_site/' >> .git/info/exclude
    du -sh .device_site
    exit 0
fi

out=${OUT:-bench/out/device}
mkdir -p "$out"
export PYTHONPATH="$PWD/.device_site:$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 MPLBACKEND=Agg
py=${PYTHON:-python3}
log="$out/device_check.log"
step() { echo; echo "### $*"; }
{
    step "machine"
    nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader || true
    $py -c 'import torch, cv2, numpy; print("torch", torch.__version__, "cuda", torch.cuda.is_available(),
torch.cuda.get_device_name(0) if torch.cuda.is_available() else "-", "| opencv", cv2.__version__, "| numpy", numpy.__version__)'
    step "CUDA tests (registration, SR)"
    timeout 240 $py -m pytest -q -p no:cacheprovider test/core/registration/test_registration_torch.py test/core/sr/test_sr_reconstruct.py \
        -k "cuda or gpu" -rs
    step "bench/registration.py --device cuda (describe: fixed shapes, then replayed as a CUDA graph)"
    timeout 150 $py bench/registration.py --device cuda --frames 30 --no-baseline --threads 2 --worlds brighton
    timeout 150 $py bench/registration.py --device cuda --frames 30 --no-baseline --threads 2 --worlds brighton --cuda-graphs
    step "bench/registration_profile.py --device cuda (without, with CUDA graphs)"
    timeout 90 $py bench/registration_profile.py --device cuda --frames 30
    timeout 90 $py bench/registration_profile.py --device cuda --frames 30 --cuda-graphs
    step "bench/sr.py --only speed --device auto (CPU and GPU)"
    timeout 180 $py bench/sr.py --only speed --device auto --threads 2 --out "$out"
} 2>&1 | tee "$log"
