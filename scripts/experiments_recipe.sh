#!/usr/bin/env bash
# Tables 1 and 2 (Wiener decoder, small preset) under the release's recipe, over seeds, and the
# ablation that switches one recipe item back to qdo's at a time (EXPERIMENTS.md "The release's
# recipe"). Each part is a `qdo sweep` (resumable: rerun the script after a kill and finished runs
# and cells are kept); two shards run side by side, then --collect writes the tables.
# Usage: bash scripts/experiments_recipe.sh [OUT] [PART]   (default out/recipe; PART grid, ablation, network,
#   network_qdo_items (the network sweep with the network's four items qdo's), network_ablation (DO with
#   one of those four items qdo's, NET_SEEDS seeds, default 1) or all (grid, ablation, network))
#   SEEDS (default 3), EPOCHS (50), STEPS (36 steps per epoch: 1,800 steps, alpha over steps 180-1,440,
#   the sum of learning rates while alpha blends 8.9 against the release's 8.8), PSF_PATH (radial),
#   NET_EPOCHS (50) x NET_STEPS (10) steps per network design, FT_STEPS (100) do-finetune steps
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/recipe}
PART=${2:-all}
QDO=${QDO:-./build/qdo}
SEEDS=${SEEDS:-3}
COMMON=(--preset small --test-data ../shared/data/hsi/cave --epochs "${EPOCHS:-50}" --steps-per-epoch "${STEPS:-36}"
        --psf-path "${PSF_PATH:-radial}" --seeds "$SEEDS" --seed 0)
DESIGN=(--preset small --epochs "${EPOCHS:-50}" --steps-per-epoch "${STEPS:-36}")  # qdo design's share of COMMON
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
  # QDO+A at 4 levels: the release's recipe with one item set back to qdo's (recipe qdo: all of
  # them, QDO too), each over the same seeds; the baseline is the grid's 4-level cells (the same
  # options and test patches).
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
  # The designs (qdo design) and their evaluations (qdo eval on the grid's test patches, as a
  # sweep's cells evaluate) in OUT/ablation_<item>/runs and cells/<mode>_L4_s<seed>, two lanes
  # side by side. Finished evaluations are skipped and interrupted designs resumed on a rerun.
  jobs=()
  for name in $(printf '%s\n' "${!items[@]}" | sort); do
    modes=qdo+a
    [ "$name" = recipe_qdo ] && modes="qdo qdo+a"  # the ordering under qdo's recipe too
    for mode in $modes; do
      for ((s = 0; s < SEEDS; ++s)); do jobs+=("$name $mode $s"); done
    done
  done
  one() {  # one ITEM MODE SEED
    local name=$1 mode=$2 seed=$3 extra=${items[$1]}
    [ "$name" = recipe_qdo ] || extra="--recipe release $extra"
    [[ "$extra" == *--psf-path* ]] || extra="$extra --psf-path ${PSF_PATH:-radial}"
    local run="$OUT/ablation_$name/runs/${mode}_L4_s$seed" cell="$OUT/ablation_$name/cells/${mode}_L4_s$seed"
    [ -f "$cell/metrics.json" ] && return 0
    mkdir -p "$OUT/ablation_$name/runs" "$OUT/ablation_$name/cells"
    if [ -f "$run/checkpoint.h5" ] && [ ! -f "$run/design.h5" ]; then
      "$QDO" design --resume --out "$run" > "$run.log" 2>&1
    elif [ ! -f "$run/design.h5" ]; then
      # shellcheck disable=SC2086
      "$QDO" design --mode "$mode" --levels 4 "${DESIGN[@]}" --seed "$seed" $extra --out "$run" > "$run.log" 2>&1
    fi
    "$QDO" eval "$run" --data ../shared/data/hsi/cave --out "$cell" > "$cell.log" 2>&1
  }
  lane() {
    local i
    for ((i = $1; i < ${#jobs[@]}; i += 2)); do
      # shellcheck disable=SC2086
      one ${jobs[$i]} || { echo "ablation ${jobs[$i]} failed (see its .log)"; return 1; }
    done
  }
  lane 0 & l0=$!
  lane 1 & l1=$!
  wait $l0 $l1
fi
if [ "$PART" = network ] || [ "$PART" = all ]; then
  # The Res-UNet (depth 4, root 16) trained jointly under the release's recipe at 4 and 8 levels,
  # on the CAVE training scenes, tested on the 3 CAVE crops.
  sweep "$OUT/network" --recipe release --grid decoder=resunet --grid levels=4,8 --grid mode=do,do-finetune,qdo,qdo+a \
    --preset small --data ../shared/data/hsi/cave_train,../shared/data/hsi/cave_png --test-data ../shared/data/hsi/cave \
    --epochs "${NET_EPOCHS:-50}" --steps-per-epoch "${NET_STEPS:-10}" --finetune-steps "${FT_STEPS:-100}" \
    --psf-path "${PSF_PATH:-radial}" --seeds "$SEEDS" --seed 0
fi
if [ "$PART" = network_qdo_items ]; then
  sweep "$OUT/network_qdo_items" --recipe release --noise-at rgb --patches random --batch-norm torch --final-init he \
    --grid decoder=resunet --grid levels=4,8 --grid mode=do,do-finetune,qdo,qdo+a \
    --preset small --data ../shared/data/hsi/cave_train,../shared/data/hsi/cave_png --test-data ../shared/data/hsi/cave \
    --epochs "${NET_EPOCHS:-50}" --steps-per-epoch "${NET_STEPS:-10}" --finetune-steps "${FT_STEPS:-100}" \
    --psf-path "${PSF_PATH:-radial}" --seeds "$SEEDS" --seed 0
fi
if [ "$PART" = network_ablation ]; then
  # DO with the Res-UNet, the release recipe with one of the network's four items set back to
  # qdo's, evaluated as the network sweep's cells (4 levels); two lanes side by side.
  declare -A net_items=([noise_rgb]="--noise-at rgb" [patches_random]="--patches random"
                        [batch_norm_torch]="--batch-norm torch" [final_init_he]="--final-init he")
  net_one() {  # net_one ITEM SEED
    local name=$1 seed=$2 run="$OUT/network_ablation_$1/runs/do_s$2" cell="$OUT/network_ablation_$1/cells/do_L4_resunet-depth4-root16_s$2"
    [ -f "$cell/metrics.json" ] && return 0
    mkdir -p "$(dirname "$run")" "$(dirname "$cell")"
    if [ -f "$run/checkpoint.h5" ] && [ ! -f "$run/design.h5" ]; then
      "$QDO" design --resume --out "$run" > "$run.log" 2>&1
    elif [ ! -f "$run/design.h5" ]; then
      # shellcheck disable=SC2086
      "$QDO" design --recipe release ${net_items[$name]} --mode do --decoder resunet --preset small \
        --data ../shared/data/hsi/cave_train,../shared/data/hsi/cave_png --epochs "${NET_EPOCHS:-50}" \
        --steps-per-epoch "${NET_STEPS:-10}" --psf-path "${PSF_PATH:-radial}" --seed "$seed" --out "$run" > "$run.log" 2>&1
    fi
    # As the sweep's do cells: the network trained for H_f, measured through the re-quantized DOE.
    "$QDO" eval "$run" --levels 4 --decoder mismatch --data ../shared/data/hsi/cave --out "$cell" > "$cell.log" 2>&1
  }
  net_jobs=()
  for name in $(printf '%s\n' "${!net_items[@]}" | sort); do
    for ((s = 0; s < ${NET_SEEDS:-1}; ++s)); do net_jobs+=("$name $s"); done
  done
  net_lane() {
    local i
    for ((i = $1; i < ${#net_jobs[@]}; i += 2)); do
      # shellcheck disable=SC2086
      net_one ${net_jobs[$i]} || { echo "network_ablation ${net_jobs[$i]} failed (see its .log)"; return 1; }
    done
  }
  net_lane 0 & n0=$!
  net_lane 1 & n1=$!
  wait $n0 $n1
fi
python3 scripts/recipe_tables.py "$OUT" "${EPOCHS:-50}" "${STEPS:-36}" > "$OUT/tables.md"
for py in python3 /usr/bin/python3; do  # the figures need matplotlib (Debian: python3-matplotlib)
  if "$py" -c 'import matplotlib' 2> /dev/null; then "$py" scripts/recipe_figures.py "$OUT"; break; fi
done
echo "experiments_recipe: tables in $OUT/tables.md and each sweep's table1.md, table2.md, comparisons.md"
