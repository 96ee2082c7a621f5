#!/usr/bin/env bash
# Issue 16's 1280x720 sweep, a part at a time, at one pinned commit, carrying the finished rows
# from machine to machine in docs/results-720p/rows/ (docs/results-720p/README.md says why:
# the whole sweep is 4-6 hours on 2 cores, longer than a working session on a machine that
# starts empty).
#
#   bash scripts/sweep_720p.sh courtyard courtyard   # scenes, Figure 6 scenes ("" for none)
#   bash scripts/sweep_720p.sh lab lab
#   bash scripts/sweep_720p.sh colonnade ""
#   bash scripts/sweep_720p.sh courtyard,colonnade,lab courtyard,lab   # the tables, from rows
#
# Every run builds the pinned commit in its own worktree (once), checks that its code gives
# the same cache keys as the rows here (the sweep's code fingerprint: the native module's bytes
# among it; a release build of the same commit with the same toolchain gives the same bytes,
# checked on two checkouts), copies the rows into the cache, runs, and copies the new rows
# back here, also when it was interrupted (a row is written whole or not at all).
set -euo pipefail

PIN=5ae7b810d32978a28e792896b5210519e40409ac
FINGERPRINT=21fb1d5ffa804bd48751a3dbe8db832e4414c964d2b5d03398567535ec0d7dd4

repo=$(cd "$(dirname "$0")/.." && pwd)
rows="$repo/docs/results-720p/rows"
wt=${SWEEP_WORKTREE:-$repo/../sweep720}
cache=${SWEEP_CACHE:-$repo/../cache-720p}
scenes=${1:?usage: sweep_720p.sh SCENES RD_SCENES (comma-separated; RD_SCENES may be \"\")}
rd=${2-}
out=${SWEEP_OUT:-$repo/../results-720p-${scenes//,/-}}

if [ ! -d "$wt" ]; then
    git -C "$repo" worktree add --detach "$wt" "$PIN"
fi
if [ "$(git -C "$wt" rev-parse HEAD)" != "$PIN" ]; then
    echo "sweep_720p: $wt is not at the pinned commit $PIN" >&2
    exit 1
fi
if [ ! -f "$wt/python/splitrender/_native.abi3.so" ]; then
    (cd "$wt" && nice -n 10 maturin build --release -o "$wt/wheel")
    (cd "$wt/wheel" && python -m zipfile -e ./*.whl unpacked)
    cp "$wt/wheel/unpacked/splitrender/_native.abi3.so" "$wt/python/splitrender/"
fi
fp=$(cd "$wt" && PYTHONPATH=python python -c \
    "from splitrender.evaluation.sweep import code_fingerprint; print(code_fingerprint())")
if [ "$fp" != "$FINGERPRINT" ]; then
    echo "sweep_720p: this build's code fingerprint is $fp, the rows' is $FINGERPRINT:" \
        "the rows here cannot be reused (another toolchain?)" >&2
    exit 1
fi

mkdir -p "$cache/rows" "$rows"
# A row is copied under a temporary name and renamed into place: the sweep takes a row file's
# existence for a finished task, so an interrupted copy must not leave half a row there.
for f in "$rows"/*.json; do
    [ -e "$f" ] || continue
    dest="$cache/rows/$(basename "$f")"
    [ -e "$dest" ] || { cp "$f" "$dest.part" && mv "$dest.part" "$dest"; }
done
args=(--out "$out" --scenes "$scenes" --scale 0.5 --seconds 3 --stereo --flip-every 25
      --executor local --jobs "${SWEEP_JOBS:-2}" --cache "$cache")
if [ -n "$rd" ]; then
    args+=(--bitrates 10,40,100 --rd-scenes "$rd")
fi
status=0
# Through scripts/sweep_720p_fix.py: the pinned code with its one memory fix (that file says
# why; the outputs and keys are the pinned code's).
(cd "$wt" && PYTHONPATH="$wt/python" nice -n 19 python "$repo/scripts/sweep_720p_fix.py" eval \
    "${args[@]}") || status=$?
cp -n "$cache/rows"/*.json "$rows/" 2>/dev/null || true
echo "sweep_720p: $(ls "$rows" | wc -l) rows in $rows; eval exited $status"
exit "$status"
