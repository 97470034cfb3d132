#!/usr/bin/env bash
# Trains a camouflage and ships it beside the object's mesh, with its provenance and its score
# under the evaluation protocol:
#
#   tools/ship_texture.sh OBJECT TARGET [ITERATIONS] [EVAL_SEED] [EXTRA TRAIN FLAGS...]
#   tools/ship_texture.sh pickup person 1200 31
#
# writes meshes/OBJECT/cac-TARGET.png (the atlas) and meshes/OBJECT/cac-TARGET.json: the exact
# commands, the scene and attack config, the seed, the versions, the training time and the
# evaluation summary (FV/RV x bright/dark, 50 views per level and set, seed EVAL_SEED, NanoDet and
# CenterNet). The run folder stays in runs/ship-OBJECT-TARGET (resumable); the evaluation report in
# runs/ship-OBJECT-TARGET-eval. Needs a release build (cargo build --release) and python3.
# TRAIN_SIZE=512 renders the training views at 512² (default 320², the training preset);
# TRAIN_SPP=2 at 2 samples per pixel (default 1, the training preset);
# TRAIN_SKY_OCCLUSION=0.5 lights half the training views' ambient from an open sky over the ground
# (environment.sky_occlusion; default 0, the evaluation protocol's ambient).
# SHIP_SUFFIX=logit ships beside the texture instead of over it: meshes/OBJECT/cac-TARGET-logit.png
# (and its run folder runs/ship-OBJECT-TARGET-logit), for a variant trained with other flags.
# A run folder is resumed only under the settings and extra train flags it was started with
# (those are kept in runs/ship-OBJECT-TARGET.flags).
set -euo pipefail
cd "$(dirname "$0")/.."
object=${1:?object (pickup, jeep, barrel, container)}
target=${2:?target COCO class, e.g. person or "stop sign"}
iterations=${3:-1200}
eval_seed=${4:-31}
size=${TRAIN_SIZE:-320}
[[ $size =~ ^[1-9][0-9]*$ ]] || { echo "TRAIN_SIZE must be a positive number of pixels, got '$size'" >&2; exit 2; }
spp=${TRAIN_SPP:-1}
[[ $spp =~ ^[1-9][0-9]*$ ]] || { echo "TRAIN_SPP must be a positive number of samples per pixel, got '$spp'" >&2; exit 2; }
sky=${TRAIN_SKY_OCCLUSION:-0.0}
python3 -c 'import sys; v = float(sys.argv[1]); assert 0 <= v <= 1' "$sky" 2>/dev/null || { echo "TRAIN_SKY_OCCLUSION must be a probability within [0, 1], got '$sky'" >&2; exit 2; }
suffix=${SHIP_SUFFIX:-}
[[ -z $suffix || $suffix =~ ^[a-z0-9][a-z0-9-]*$ ]] || { echo "SHIP_SUFFIX must be lower-case letters, digits and dashes, got '$suffix'" >&2; exit 2; }
invocation="${TRAIN_SIZE:+TRAIN_SIZE=$TRAIN_SIZE }${TRAIN_SPP:+TRAIN_SPP=$TRAIN_SPP }${TRAIN_SKY_OCCLUSION:+TRAIN_SKY_OCCLUSION=$TRAIN_SKY_OCCLUSION }${SHIP_SUFFIX:+SHIP_SUFFIX=$SHIP_SUFFIX }tools/ship_texture.sh $*"
shift $(( $# < 4 ? $# : 4 ))
slug=$(echo "$target" | tr ' ' '_')${suffix:+-$suffix}
# The commit the texture is trained with, read before anything is written; "-dirty" when tracked
# files outside meshes/ differ from it.
rev=$(git rev-parse HEAD 2>/dev/null) || { echo "not a git checkout: the texture's commit cannot be recorded" >&2; exit 2; }
git diff --quiet HEAD -- . ':(exclude)meshes' || rev=$rev-dirty
cac=target/release/cac
[ -x "$cac" ] || { echo "build first: cargo build --release" >&2; exit 1; }
run=runs/ship-$object-$slug
ev=runs/ship-$object-$slug-eval
mkdir -p runs
"$cac" config > "$run.toml.tmp"
sed -e "s/^mesh = .*/mesh = \"$object\"/" -e "s/^width = 512/width = $size/" \
    -e "s/^height = 512/height = $size/" -e "s/^samples = 4/samples = $spp/" \
    -e 's/^atlas_res = 512/atlas_res = 256/' -e "s/^sky_occlusion = .*/sky_occlusion = $sky/" \
    "$run.toml.tmp" > "$run.toml"
rm "$run.toml.tmp"
train=("$cac" train --config "$run.toml" --target "$target" --iterations "$iterations" --seed 0 "$@")
if [ -f "$run/run.json" ]; then
    # Resume only the run these settings ask for: an earlier run at another size, sampling,
    # object, target or seed would otherwise be shipped under this command.
    python3 - "$run/run.json" "$object" "$target" "$size" "$spp" "$sky" <<'EOF' || exit 2
import json, sys
path, obj, target, size, spp, sky = sys.argv[1:]
r = json.load(open(path))
render = r["scene"]["render"]
have = (r["scene"]["object"]["mesh"], r["attack"]["target"], render["width"], render["height"],
        render["samples"], r["attack"]["seed"],
        float(r["scene"]["environment"].get("sky_occlusion", 0.0)))
want = (obj, target, int(size), int(size), int(spp), 0, float(sky))
if have != want:
    names = ("object", "target", "width", "height", "samples", "seed", "sky_occlusion")
    diff = [f"{n} {h} (asked {w})" for n, h, w in zip(names, have, want) if h != w]
    sys.exit(f"{path}: holds a run with other settings: {'; '.join(diff)}; remove it first")
EOF
    # The extra train flags are not in the settings above: a run started with others (e.g.
    # another --target-loss) would be shipped under this command's.
    if [ -f "$run.flags" ] && [ "$(cat "$run.flags")" != "$*" ]; then
        echo "$run: was started with extra train flags '$(cat "$run.flags")' (asked '$*'); remove it first" >&2
        exit 2
    fi
    "$cac" train --resume "$run" --iterations "$iterations"
else
    printf '%s' "$*" > "$run.flags"
    "${train[@]}" --out "$run"
fi
case "$object" in
    barrel|container) true_classes=none ;;
    *) true_classes=car,truck ;;
esac
evalcmd=("$cac" eval --object "$object" --texture "original,CAC=$run" --models nanodet,centernet
         --views 50 --seed "$eval_seed" --target "$target" --true-classes "$true_classes" --out "$ev")
"${evalcmd[@]}"
cp "$run/atlas.png" "meshes/$object/cac-$slug.png.tmp"
mv "meshes/$object/cac-$slug.png.tmp" "meshes/$object/cac-$slug.png"
python3 - "$run" "$ev" "meshes/$object/cac-$slug.json" "${train[*]} --out $run" \
    "${evalcmd[*]}" "$invocation" "$rev" <<'EOF'
import json, os, sys
run, ev, out, train_cmd, eval_cmd, invocation, rev = sys.argv[1:]
r = json.load(open(os.path.join(run, "run.json")))
e = json.load(open(os.path.join(ev, "results.json")))
doc = {
    "texture": os.path.basename(out).replace(".json", ".png"),
    "commands": {"train": train_cmd, "evaluate": eval_cmd,
                 "regenerate": invocation},
    "seed": r["seed"], "iterations": r["iteration"],
    # Sum of the logged per-iteration times (render, forward, backward, optimiser): the
    # training time whatever the resumes; on a loaded machine it is larger than on an idle one.
    "train_seconds": round(sum(l["ms_render"] + l["ms_forward"] + l["ms_backward"]
                               + l["ms_optimiser"] for l in r["log"]) / 1e3),
    "versions": {"cac": r["cac_version"], "burn": r["burn_version"], "git": rev},
    "scene": r["scene"], "attack": r["attack"],
    "evaluation": {"info": e["info"], "protocol": e["protocol_text"],
                   "summaries": [s for s in e["summaries"] if s.get("texture") == "CAC"
                                 or s.get("texture") == "Original"]},
}
# Trained through a printer: the profile (its filaments or response) beside the texture's record.
if r["attack"].get("printer"):
    import tomllib
    with open(r["attack"]["printer"], "rb") as f:
        doc["printer"] = {"profile": r["attack"]["printer"], **tomllib.load(f)}
tmp = out + ".tmp"
with open(tmp, "w") as f:
    json.dump(doc, f, indent=1)
os.replace(tmp, out)
print("wrote", out)
EOF
