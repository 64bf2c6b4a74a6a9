# Sourced by the GPU session scripts (gpu_session.sh, gpu_round.sh) on the device machine: the output folder, Warp's
# kernel cache, a timestamped log line, and what the machine has.
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export WARP_CACHE_PATH=/tmp/warp_cache PYTHONUNBUFFERED=1
log() { echo "=== $* ($(date -u +%H:%M:%S))"; }
log "devices"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import torch, warp as wp; wp.init(); print('torch', torch.__version__, 'warp', wp.__version__, wp.get_cuda_devices())"
