#!/usr/bin/env bash
# Reproduce the shipped weights of unwrap_single(method="learned"): four seeded stages, about 105 minutes on 2 quiet
# CPU cores (7 + 69 + 7 + 18). Usage: bash references/learned_single/train_shipped.sh [OUT] (default: a temporary
# folder; copy OUT/stage4/edge_jump.pt to torch_modulo/singleshot/weights/ to ship it).
set -euo pipefail
cd "$(dirname "$0")/../.."
out="${1:-$(mktemp -d)}"
py=".venv/bin/python"
train="references.learned_single.train"
# 1. from scratch: 869 steps of 8 crops of 96 x 96, learning rate 2e-3
"$py" -m "$train" --out "$out/stage1" --steps 869 --seed 0
# 2. longer: 8700 more steps at 1e-3
"$py" -m "$train" --init "$out/stage1/edge_jump.pt" --out "$out/stage2" --steps 8700 --lr 1e-3 --seed 2
# 3. more context: a fifth bottleneck block (dilation 16, starting near zero), crops of 128 x 128, 741 steps at 5e-4
"$py" -m "$train" --init "$out/stage2/edge_jump.pt" --out "$out/stage3" --dilations 1 2 4 8 16 --crop 128 --batch 6 \
    --steps 741 --lr 5e-4 --seed 3
# 4. the pairs whose wrapped step is wrong weighted 2x in the loss instead of 5x, 1800 steps at 5e-4
"$py" -m "$train" --init "$out/stage3/edge_jump.pt" --out "$out/stage4" --dilations 1 2 4 8 16 --crop 128 --batch 6 \
    --hard-weight 2 --steps 1800 --lr 5e-4 --seed 8
echo "weights: $out/stage4/edge_jump.pt"
