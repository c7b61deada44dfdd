#!/usr/bin/env bash
# Reproduce the shipped weights of unwrap_single(method="learned"): three seeded stages, about 85 minutes on 2 quiet
# CPU cores (7 + 69 + 7). Usage: bash references/learned_single/train_shipped.sh [OUT] (default: a temporary folder;
# copy OUT/stage3/edge_jump.pt to torch_modulo/singleshot/weights/ to ship it).
set -euo pipefail
cd "$(dirname "$0")/../.."
out="${1:-$(mktemp -d)}"
py=".venv/bin/python"
train="references/learned_single/train.py"
# 1. from scratch: 869 steps of 8 crops of 96 x 96, learning rate 2e-3
"$py" "$train" --out "$out/stage1" --steps 869 --seed 0
# 2. longer: 8700 more steps at 1e-3
"$py" "$train" --init "$out/stage1/edge_jump.pt" --out "$out/stage2" --steps 8700 --lr 1e-3 --seed 2
# 3. more context: a fifth bottleneck block (dilation 16, starting near zero), crops of 128 x 128, 741 steps at 5e-4
"$py" "$train" --init "$out/stage2/edge_jump.pt" --out "$out/stage3" --dilations 1 2 4 8 16 --crop 128 --batch 6 \
    --steps 741 --lr 5e-4 --seed 3
echo "weights: $out/stage3/edge_jump.pt"
