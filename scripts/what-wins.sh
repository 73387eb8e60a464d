#!/usr/bin/env bash
# The README's "What wins where" table: one `lfr compare` per row (release build, the shared
# scenes in $LFR_SCENES, references cached in CACHE), then the table from their results.json
# (scripts/what-wins.py). Usage: scripts/what-wins.sh OUT_DIR [CACHE_DIR]. About 30-60 minutes
# on 2 cores; every figure is a ratio measured within one comparison (docs/compare.md).
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:?usage: scripts/what-wins.sh OUT_DIR [CACHE_DIR]}"
cache="${2:-$out/cache}"
export LFR_SCENES="${LFR_SCENES:-$(cd .. && pwd)/shared/scenes}"
cargo build --release --quiet
lfr=target/release/lfr
common=(--reference-spp 1024 --pt-max-spp 256 --repeats 3 --cache-dir "$cache" --quiet --force)
run() { local name=$1; shift; echo "== $name: lfr compare $*" >&2; "$lfr" compare "$@" "${common[@]}" --out "$out/$name"; }
run cornell-indirect --scene scenes/cornell.toml --effect indirect --width 128 --height 128 --spp 1,4 \
  --methods ilfr,ilfr:variant=paper,ilfr:grain=filter,ilfr+oidn,ilfr-recursive,ilfr-recursive+oidn,gif,gif+oidn,oidn
run sponza-indirect --scene scenes/sponza.toml --effect indirect --width 160 --height 90 --spp 4,8 \
  --methods ilfr,ilfr:variant=paper,ilfr:grain=filter,ilfr+oidn,ilfr-recursive,ilfr-recursive+oidn,gif,gif+oidn,oidn
run sponza-ao --scene scenes/sponza.toml --effect ao --width 160 --height 90 --spp 1,4 \
  --methods ilfr,ilfr:variant=paper,ilfr+oidn,oidn
run monkeys-glossy --scene scenes/monkeys.toml --effect glossy --width 160 --height 90 --spp 1,8 --max-bounces 2 \
  --methods ilfr,ilfr+oidn,oidn
run monkeys-dof --scene scenes/monkeys-dof-depths.toml --effect dof --width 160 --height 90 --spp 4,16 \
  --methods tlfr,tlfr:gi=whole,tlfr+oidn,tlfr+oidn:aux=centre,ilfr-dof,oidn
run monkeys-dof-direct --scene scenes/monkeys-dof-depths.toml --effect dof --width 160 --height 90 --spp 4,16 \
  --max-bounces 1 --methods tlfr,tlfr+oidn,tlfr+oidn:aux=centre,oidn
run monkeys-dof-motion --scene scenes/monkeys-defocus-motion.toml --effect dof-motion --width 160 --height 90 \
  --spp 4,16 --methods tlfr,tlfr+oidn,oidn
run soft-shadow --scene scenes/soft-shadow.toml --effect soft-shadow --width 128 --height 96 --spp 1,4 \
  --methods tlfr,tlfr+oidn,oidn
python3 scripts/what-wins.py "$out"/*/results.json
