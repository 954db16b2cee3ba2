#!/usr/bin/env bash
# One GPU check of issue 39, as one prepared script: the CUDA test run, then quick.yaml,
# table1.yaml and paper.yaml, each timed, with the GPU's use sampled by nvidia-smi every 2 s.
# Usage: bash scripts/gpu_check.sh OUT_DIR [recipes...]   (default: quick table1 paper)
# Packages the machine lacks travel as wheels in .whl/ (DEVELOPERS.md): installed first.
set -uo pipefail
out="${1:?usage: gpu_check.sh OUT_DIR [recipe ...]}"; shift
recipes=("${@:-quick table1 paper}")
mkdir -p "$out"
if compgen -G ".whl/*.whl" >/dev/null; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl && export PYTHONPATH="/tmp/site:$PWD" || exit 1
fi
export TACTILE_BENCH_NO_WANDB=1
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), \
  torch.cuda.get_device_name(0) if torch.cuda.is_available() else '-', \
  'cpu', torch.backends.cpu.get_cpu_capability())" | tee "$out/machine.txt"
nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used --format=csv -l 2 >"$out/smi.csv" &
smi=$!
trap 'kill $smi 2>/dev/null' EXIT
timeout 300 python3 -m pytest -q -n 12 -p no:cacheprovider >"$out/tests.log" 2>&1
echo "tests rc=$?" | tee -a "$out/summary.txt"
for name in ${recipes[@]}; do
  start=$(date +%s)
  timeout 900 python3 -m tactile_bench fit "recipes/$name.yaml" --run-dir "/tmp/gpu_$name" \
    --no-progress >"$out/$name.log" 2>&1
  rc=$?
  echo "$name rc=$rc wall_s=$(( $(date +%s) - start )) from $(date -d @"$start" +%T)" \
    | tee -a "$out/summary.txt"
  cp "/tmp/gpu_$name/report.md" "$out/${name}_report.md" 2>/dev/null
done
# the share of samples with the GPU busy, over the whole check
awk -F', ' 'NR > 1 { n++; if ($2 + 0 > 0) busy++ } END { printf "gpu busy in %d of %d samples\n", busy, n }' \
  "$out/smi.csv" | tee -a "$out/summary.txt"
