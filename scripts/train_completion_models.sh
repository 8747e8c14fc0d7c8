#!/usr/bin/env bash
# Train the completion models at equal time, export them and write models/EVAL.md — the shipped figures.
#
#   scripts/train_completion_models.sh [MINUTES]      # default 85; resumes any run already under way
#
# All four runs train at once, one thread each, so each gets the same share of the machine (on the 2-core
# CPU about half a core each) and the same wall-clock budget. The shipped models/gprnet.onnx is the GPRNet
# variant with the lower best *validation* CD2; the other is kept as models/gprnet_<variant>.onnx.
set -euo pipefail
cd "$(dirname "$0")/.."
MINUTES=${1:-85}
PY=${PYTHON:-.venv/bin/python}
RUNS=("gprnet gprnet_fullfuse" "gprnet gprnet_pyramid" "pcn pcn" "pfnet pfnet")

"$PY" -m training.pointcloud_data train val test
pids=()
for run in "${RUNS[@]}"; do
    set -- $run
    "$PY" -m training.train_completion --model "$1" --name "$2" --minutes "$MINUTES" --threads 1 --seed 0 \
        >"training/logs/$2.out" 2>&1 &
    pids+=($!)
done
for pid in "${pids[@]}"; do wait "$pid"; done

best_val() { "$PY" -c "import torch,sys; print(torch.load(sys.argv[1], weights_only=False)['metrics']['val_cd2'])" "$1"; }
a=$(best_val training/checkpoints/gprnet_fullfuse/best.pt)
b=$(best_val training/checkpoints/gprnet_pyramid/best.pt)
if "$PY" -c "import sys; sys.exit(0 if float(sys.argv[1]) <= float(sys.argv[2]) else 1)" "$a" "$b"; then
    shipped=gprnet_fullfuse; other=gprnet_pyramid
else
    shipped=gprnet_pyramid; other=gprnet_fullfuse
fi
echo "validation CD2: gprnet_fullfuse $a, gprnet_pyramid $b → shipping $shipped as models/gprnet.onnx"
"$PY" tools/export_onnx.py gprnet --checkpoint "training/checkpoints/$shipped/best.pt" --out models/gprnet.onnx
"$PY" tools/export_onnx.py gprnet --checkpoint "training/checkpoints/$other/best.pt" --out "models/$other.onnx"
rm -f "models/$shipped.onnx" "models/$shipped.json"
for model in pcn pfnet; do
    "$PY" tools/export_onnx.py "$model" --checkpoint "training/checkpoints/$model/best.pt" --out "models/$model.onnx"
done
"$PY" -m training.evaluate --out models/
