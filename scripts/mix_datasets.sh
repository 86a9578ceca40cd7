#!/usr/bin/env bash
# Mix simulated datasets into one, by symbolic links (no copies): e.g. realistic-sensor data with
# ideal data, as in the sim-to-real recipe of the documentation's training page.
#
#   scripts/mix_datasets.sh OUT_DIR DATASET...
#
# OUT_DIR/{train,val,test}/ gets a link to every sequence of every DATASET (named
# <dataset folder>_<file>), and OUT_DIR/meta.json is the first dataset's. Train with
# `spikegyro train --data OUT_DIR`.
set -euo pipefail
[ $# -ge 2 ] || { sed -n '5p' "$0" | sed 's/^# *//' >&2; exit 2; }
dest=$1
shift
for d in "$@"; do
    [ -f "$d/meta.json" ] || { echo "mix_datasets.sh: $d has no meta.json (not a dataset)" >&2; exit 2; }
done
mkdir -p "$dest"
cp "$1/meta.json" "$dest/meta.json"
for split in train val test; do
    mkdir -p "$dest/$split"
    for d in "$@"; do
        name=$(basename "$(cd "$d" && pwd)")
        for f in "$d/$split"/*.h5; do
            [ -e "$f" ] || continue
            ln -sf "$(cd "$(dirname "$f")" && pwd)/$(basename "$f")" "$dest/$split/${name}_$(basename "$f")"
        done
    done
done
echo "$dest: $(find "$dest/train" -name '*.h5' | wc -l) train, $(find "$dest/val" -name '*.h5' | wc -l) val, $(find "$dest/test" -name '*.h5' | wc -l) test sequences"
