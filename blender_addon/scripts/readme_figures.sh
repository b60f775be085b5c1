#!/bin/sh
# Renders the README figures into docs/images/ with the add-on's headless script
# (docs/blender.md): for the Teardrop demo and for the CT skull, the C4 heat map of err_est,
# the C1 threshold map with its CDF, C6 hidden features over standard MC, and the combined
# view (heat map + hidden features).
#
#   blender_addon/scripts/readme_figures.sh [OUTDIR]
#
# Needs blender and the isouq binary ($ISOUQ_CLI, else build/houdini_style_nodes/isouq) and the
# data folder ($ISOUQ_DATA_DIR, else ../shared/data next to the checkout).
set -eu
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
ISOUQ=${ISOUQ_CLI:-$ROOT/build/houdini_style_nodes/isouq}
DATA=${ISOUQ_DATA_DIR:-$ROOT/../shared/data}
OUT=$(mkdir -p "${1:-$ROOT/docs/images}" && cd "${1:-$ROOT/docs/images}" && pwd)
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT

# meshes: the demo (Teardrop 64^3), Teardrop 32^3 with hidden features (the paper's case,
# SPEC §4), the skull at its documented isovalue 2.9 with its voxel spacing
"$ISOUQ" demo --dir "$WORK" --quiet
"$ISOUQ" mesh field:teardrop --resolution 32 -o "$WORK/td32.ply" --hidden-features \
    --hidden-out "$WORK/td32_hf.ply" --summary "$WORK/td32.json" --quiet
"$ISOUQ" mesh "$DATA/skull_64x64x64_float32.raw" --isovalue 2.9 \
    --spacing 3.943050,3.943050,3.650790 -o "$WORK/skull.ply" --hidden-features \
    --hidden-out "$WORK/skull_hf.ply" --summary "$WORK/skull.json" --quiet

render() {   # render NAME ARGS...: the figure OUT/NAME.png
    name=$1
    shift
    blender -b --factory-startup --python-exit-code 1 \
        -P "$ROOT/blender_addon/scripts/render_view.py" -- \
        --out "$WORK/$name.render.png" --figure "$OUT/$name.png" --size 560 --samples 32 "$@" \
        > "$WORK/$name.log" 2>&1 || { cat "$WORK/$name.log"; exit 1; }
    echo "wrote $OUT/$name.png"
}

TD="--mesh $WORK/teardrop.ply --summary $WORK/teardrop.summary.json --direction 0.3,-1,0.45"
render teardrop_heatmap $TD --view heatmap \
    --title "Teardrop 64³ (WENO): estimated error err_est (C4)"
render teardrop_threshold $TD --view threshold --percentile 90 \
    --title "Teardrop 64³: err_est above its 90th percentile (C1)"
TD32="--mesh $WORK/td32.ply --hidden $WORK/td32_hf.ply --summary $WORK/td32.json --direction 0.3,-1,0.45"
render teardrop_hidden $TD32 --view hidden \
    --title "Teardrop 32³: standard MC (2 pieces) and hidden features (1 piece) (C6)"
render teardrop_combined $TD32 --view combined \
    --title "Teardrop 32³ with hidden features: err_est, refined cells in green"

SK="--mesh $WORK/skull.ply --hidden $WORK/skull_hf.ply --summary $WORK/skull.json --direction 0.6,-1,0.25"
render skull_heatmap $SK --view heatmap --clip-percentile 99 \
    --title "CT skull 64³, k = 2.9 (WENO): err_est (C4)"
render skull_threshold $SK --view threshold --percentile 90 \
    --title "CT skull: err_est above its 90th percentile (C1)"
render skull_hidden $SK --view hidden \
    --title "CT skull: hidden features (orange) over standard MC (blue) (C6)"
render skull_combined $SK --view combined --clip-percentile 99 \
    --title "CT skull with hidden features: err_est, refined cells in green"
