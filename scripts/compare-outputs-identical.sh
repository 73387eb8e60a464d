#!/usr/bin/env bash
# Runs a fixed set of small `lfr compare` runs, and `lfr dump` of every kind, with two `lfr`
# binaries and checks that they write the same outputs: every sample file and every image (EXR
# and PNG) byte for byte, and results.json with the fields that measure time removed (times,
# timing spreads, speedups, the winners per time budget, verdict sentences, peak memory,
# durations in the notes). Every effect, every method that handles it (probes for indirect
# light), an external reference, repetitions, explicit reconstruction rays and the reference
# check switched off.
#
#   scripts/compare-outputs-identical.sh BASE_LFR NEW_LFR [WORK_DIR]
#
# BASE_LFR and NEW_LFR are release binaries (e.g. one built from main and copied aside, and
# target/release/lfr of a branch). WORK_DIR (default: a fresh temporary folder) keeps the
# outputs; each binary gets its own reference cache there (WORK_DIR/{base,new}/cache), so that
# both trace their references and then read them back from the cache in the later runs.
# Exits 0 when every output matches, 1 naming each difference.
set -euo pipefail

if [[ $# -lt 2 ]]; then
    sed -n '2,15p' "$0" | sed 's/^# \{0,1\}//'
    exit 2
fi
base_lfr=$(realpath "$1")
new_lfr=$(realpath "$2")
work=${3:-$(mktemp -d)}
root=$(cd "$(dirname "$0")/.." && pwd)
scenes="$root/scenes"
mkdir -p "$work"
work=$(realpath "$work")

# name | scene | effect | methods | extra arguments
cases=(
    "indirect|cornell.toml|indirect|box,oidn,gif,gif-normal,bilateral,atrous,atrous-sn,ilfr,ilfr-recursive,probes:probes=8:receivers=1500:directions=64:relight_rays=400:pixel_samples=2|"
    "indirect-rays|cornell.toml|indirect|ilfr,ilfr:grain=filter,box|--recon-rays 2,6 --repeats 2"
    "indirect-external|cornell.toml|indirect|box,ilfr|--reference EXTERNAL_A,EXTERNAL_B"
    "indirect-external-one|cornell.toml|indirect|box|--reference EXTERNAL_A --reference-check off"
    "glossy|monkeys.toml|glossy|box,oidn,gif,ilfr|--max-bounces 2"
    "ao|cornell.toml|ao|box,oidn,ilfr|--reference-check off"
    "dof|monkeys-defocus-motion.toml|dof|box,oidn,tlfr,tlfr-nn,tlfr-bw,ilfr-dof|"
    "motion|monkeys-defocus-motion.toml|motion|box,tlfr,ilfr-dof|--repeats 2"
    "dof-motion|monkeys-defocus-motion.toml|dof-motion|box,oidn,tlfr,ilfr-dof|"
    "soft-shadow|soft-shadow.toml|soft-shadow|box,oidn,tlfr,tlfr:gi=split|"
    "soft-shadow-cornell|cornell.toml|soft-shadow|box,tlfr|"
)
common=(--width 32 --height 32 --spp 1,4 --reference-spp 64 --pt-max-spp 8 --quiet --threads 2)

# The external reference: two halves of the Cornell box's indirect light, rendered once (by
# BASE_LFR) and read by both.
external="$work/external"
if [[ ! -f "$external/b.exr" ]]; then
    mkdir -p "$external"
    for half in a:91 b:92; do
        "$base_lfr" render --scene "$scenes/cornell.toml" --width 32 --height 32 --spp 32 \
            --seed "${half#*:}" --quiet --out "$external/${half%%:*}.exr" >/dev/null
    done
fi

run_side() {
    local side=$1 lfr=$2
    rm -rf "$work/$side"
    mkdir -p "$work/$side/cache"
    for case in "${cases[@]}"; do
        IFS='|' read -r name scene effect methods extra <<<"$case"
        extra=${extra//EXTERNAL_A/$external/a.exr}
        extra=${extra//EXTERNAL_B/$external/b.exr}
        [[ $extra == *--repeats* ]] || extra="$extra --repeats 1"
        # shellcheck disable=SC2086
        if ! "$lfr" compare --scene "$scenes/$scene" --effect "$effect" --methods "$methods" "${common[@]}" \
            $extra --cache-dir "$work/$side/cache" --out "$work/$side/$name" \
            >"$work/$side/$name.log" 2>&1; then
            echo "$side: $name failed:" >&2
            tail -5 "$work/$side/$name.log" >&2
            return 1
        fi
        echo "$side: $name done"
    done
}

# results.json without what measures time: every field named *_s or *seconds, the repetitions'
# timings and their spread, the verdicts read off them (against path tracing and against OIDN,
# and the headline's winners per time budget), peak memory, the verdict sentences, and
# in the notes every duration ("0.012 s", "3 ms" become "T s", "T ms").
normalise() {
    jq -S '
        walk(if type == "object" then
                with_entries(select(
                    (.key | test("(_s|seconds|^timings|timing_spread|speedup|speedup_range|equal_time_psnr_gain_db|verdict_extrapolated|break_even_frames|peak_rss_mb|summary|difference|best_speedup_input_spp|best_speedup_recon_rays|speedup_over_oidn|speedup_over_oidn_range|oidn_curve_position|budgets|headline)$")) | not))
            elif type == "string" then
                gsub("[0-9]+(\\.[0-9]+)?(e-?[0-9]+)? (?<unit>s|ms|µs)\\b"; "T \(.unit)")
            else . end)' "$1"
}

run_side base "$base_lfr"
run_side new "$new_lfr"

status=0
compared=0
# `lfr dump` of every kind (lens-time also with the soft-shadow fields): the same files.
dumps=("lens-time|monkeys-defocus-motion.toml|" "lens-time|soft-shadow.toml|--soft-shadow" "light|soft-shadow.toml|"
    "indirect|cornell.toml|" "ao|cornell.toml|" "guide|cornell.toml|")
for dump in "${dumps[@]}"; do
    IFS='|' read -r kind scene extra <<<"$dump"
    extension=lfrs
    [[ $kind == guide ]] && extension=exr
    name="dump-$kind${extra:+-soft-shadow}-${scene%.toml}.$extension"
    for side in base new; do
        lfr=$base_lfr
        [[ $side == new ]] && lfr=$new_lfr
        # shellcheck disable=SC2086
        "$lfr" dump --scene "$scenes/$scene" --kind "$kind" $extra --spp 2 --width 16 --height 12 --seed 5 \
            --quiet --out "$work/$side/$name" >/dev/null
    done
    compared=$((compared + 1))
    if ! cmp -s "$work/base/$name" "$work/new/$name"; then
        echo "DIFFERENT: lfr dump --kind $kind $extra ($name)"
        status=1
    fi
done
for case in "${cases[@]}"; do
    name=${case%%|*}
    base_dir="$work/base/$name" new_dir="$work/new/$name"
    base_files=$(cd "$base_dir" && find images -type f | sort)
    new_files=$(cd "$new_dir" && find images -type f | sort)
    if [[ "$base_files" != "$new_files" ]]; then
        echo "DIFFERENT $name: the image lists differ:"
        diff <(echo "$base_files") <(echo "$new_files") || true
        status=1
    fi
    for file in $base_files; do
        [[ -f "$new_dir/$file" ]] || continue
        compared=$((compared + 1))
        if ! cmp -s "$base_dir/$file" "$new_dir/$file"; then
            echo "DIFFERENT $name: $file"
            status=1
        fi
    done
    compared=$((compared + 1))
    if ! diff <(normalise "$base_dir/results.json") <(normalise "$new_dir/results.json") >"$work/$name.results.diff"; then
        echo "DIFFERENT $name: results.json (timing fields removed; diff in $work/$name.results.diff):"
        head -20 "$work/$name.results.diff"
        status=1
    fi
done
if [[ $status == 0 ]]; then
    echo "IDENTICAL: $compared files over ${#cases[@]} comparisons (outputs in $work)"
fi
exit $status
