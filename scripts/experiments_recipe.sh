#!/usr/bin/env bash
# Tables 1 and 2 (Wiener decoder, small preset) under the release's recipe, over seeds, and the
# ablation that switches one recipe item back to qdo's at a time (EXPERIMENTS.md "The release's
# recipe"). Each part is a `qdo sweep` (resumable: rerun the script after a kill and finished runs
# and cells are kept); two shards run side by side, then --collect writes the tables.
# Usage: bash scripts/experiments_recipe.sh [OUT] [PART]   (default out/recipe; PART grid, ablation or all)
#   SEEDS (default 3), EPOCHS (50), STEPS (36 steps per epoch: 1,800 steps, alpha over steps 180-1,440,
#   the sum of learning rates while alpha blends 8.9 against the release's 8.8), PSF_PATH (radial)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/recipe}
PART=${2:-all}
QDO=${QDO:-./build/qdo}
SEEDS=${SEEDS:-3}
COMMON=(--preset small --test-data ../shared/data/hsi/cave --epochs "${EPOCHS:-50}" --steps-per-epoch "${STEPS:-36}"
        --psf-path "${PSF_PATH:-radial}" --seeds "$SEEDS" --seed 0)
export QDO_CACHE_DIR=${QDO_CACHE_DIR:-$PWD/build/kernel-cache}

# Runs one sweep in two shards side by side, then collects its tables.
sweep() {
  local out=$1; shift
  mkdir -p "$(dirname "$out")"
  "$QDO" sweep "$@" --out "$out" --shard 0/2 > "$out.shard0.log" 2>&1 &
  local p0=$!
  sleep 5  # the first shard creates the folder
  "$QDO" sweep "$@" --out "$out" --shard 1/2 --into-existing > "$out.shard1.log" 2>&1 &
  local p1=$!
  wait $p0 $p1
  "$QDO" sweep "$@" --out "$out" --collect --into-existing
}

if [ "$PART" = grid ] || [ "$PART" = all ]; then
  sweep "$OUT/grid" --recipe release --grid levels=2,4,8,16,32 --grid mode=do,do-refit,qdo,qdo+a "${COMMON[@]}"
fi
if [ "$PART" = ablation ] || [ "$PART" = all ]; then
  # QDO+A and QDO at 4 levels: the release's recipe with one item set back to qdo's (recipe qdo:
  # all of them), each over the same seeds.
  declare -A items=(
    [decay_per_epoch]="--decay-steps epoch --decay-staircase on"
    [init_random]="--init random"
    [aq_pixels]="--aq-domain pixels"
    [no_height_noise]="--height-noise-nm 0"
    [pin_bottom]="--pinned-level bottom"
    [adam_textbook]="--adam-form textbook --adam-eps 1e-8"
    [psf_2d]="--psf-path 2d"
    [recipe_qdo]="--recipe qdo"
  )
  for name in release "${!items[@]}"; do
    extra=${items[$name]:-}
    # shellcheck disable=SC2086
    sweep "$OUT/ablation_$name" --recipe release --grid levels=4 --grid mode=qdo,qdo+a "${COMMON[@]}" $extra
  done
fi
