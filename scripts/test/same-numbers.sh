#!/usr/bin/env bash
# Same numbers before and after a reshaping: runs a fixed set of `nis integrate --json` cases
# (budgets, precision targets bounded by max_evals, channels and their shared flow, signs,
# NIS's switch to the codes' masks, every method) with the given binary and writes each result,
# without its timings, to OUTDIR/N.json; a digest per case goes to stdout. Compare two binaries with `diff -r OUT_BEFORE OUT_AFTER`.
#
#   scripts/test/same-numbers.sh target/release/nis /tmp/after
#
# The last four runs keep VEGAS+'s race and the codes' probe on, which decide by wall time: on
# these integrands the decision is clear-cut (VEGAS+ answers the first two, NIS the others), so
# they match too unless the machine is far slower or busier than the run before.
set -euo pipefail
nis=${1:?usage: same-numbers.sh NIS_BINARY OUTDIR}
out=${2:?usage: same-numbers.sh NIS_BINARY OUTDIR}
mkdir -p "$out"
strip='
import json, sys
d = json.load(sys.stdin)
def strip(o):
    if isinstance(o, dict):
        return {k: strip(v) for k, v in o.items() if k != "seconds"}
    if isinstance(o, list):
        return [strip(v) for v in o]
    return o
print(json.dumps(strip(d), indent=1, sort_keys=True))'
norace='--nis-config {"race_vegas":false,"auto_masks":false}'
i=0
while IFS= read -r args; do
    i=$((i + 1))
    # shellcheck disable=SC2086
    "$nis" integrate $args --json 2>/dev/null | python3 -c "$strip" > "$out/$i.json"
    echo "$i  $(md5sum < "$out/$i.json" | cut -c1-12)  $args"
done <<CASES
camel --dim 4 --method nis --evals 200000
camel --dim 4 --method vegas --evals 200000
camel --dim 4 --method uniform --evals 200000
camel --dim 4 --method nis --rel-err 3e-3 --max-evals 400000 $norace
gauss --dim 2 --method vegas --rel-err 1e-4 --max-evals 3000000
camel --dim 2 --method uniform --rel-err 1e-2 --max-evals 3000000
dalitz --channels --method nis --rel-err 1e-2 --max-evals 300000
gauss-pm --method nis --abs-err 1e-3 --max-evals 300000
resonances-4d --channels --method vegas --rel-err 1e-2 --max-evals 2000000
resonances-4d --channels --method uniform --rel-err 3e-2 --max-evals 2000000
gauss-pm --method vegas --signs split --abs-err 1e-3 --max-evals 300000
camel --dim 4 --method nis --rel-err 1e-2 --max-evals 300000 --nis-config {"race_vegas":false}
gauss --dim 8 --method nis --rel-err 1e-2 --max-evals 250000 --nis-config {"race_vegas":false}
dalitz --channels --method nis --evals 300000
camel --dim 2 --method nis --rel-err 1e-3
gauss --dim 8 --method nis --rel-err 1e-2 --max-evals 3000000
peaks --dim 4 --method nis --rel-err 1e-2 --max-evals 3000000
camel --dim 8 --method nis --rel-err 1e-2 --max-evals 3000000
CASES
