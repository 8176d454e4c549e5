#!/usr/bin/env bash
# The GPU studies of one device call, in order of priority, each trained, evaluated and packed
# under $OUT before the next starts, so a call stopped at its limit returns what finished:
#   bash benchmarks/gpu_studies.sh DEADLINE_S NAME "SWEEP ARGS" [NAME "SWEEP ARGS" ...]
# Each study: python -m jaxlc.sweep ARGS --out runs/NAME, then python -m jaxlc.evaluate
# runs/NAME --no-figures; packed as NAME_eval.tgz (config, summaries, report, eval/ without
# its per-case files, the commands' output and timing), NAME_heldout_cases.npz (the held-out
# per-case file, for benchmarks/failed_cases.py) and, unless METRICS=0,
# NAME_metrics.tgz (metrics/episodes.npz). Studies run side by side when the script is
# started once per study, each in the background.
set -u
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD
end=$(( $(date +%s) + $1 )); shift
OUT=${OUT:-out}; mkdir -p "$OUT"
bash "$(dirname "$0")/machine_info.sh" > "$OUT/machine.txt" 2>&1
while [ $# -ge 2 ]; do
  name=$1; args=$2; shift 2; run=runs/$name; mkdir -p "$run"
  left=$(( end - $(date +%s) )); [ "$left" -gt 60 ] || break
  t0=$(date +%s)
  timeout "$left" python3 -m jaxlc.sweep --no-progress --out "$run" $args > "$run/sweep_output.txt" 2>&1
  rc=$?; t1=$(date +%s)
  echo "sweep $args: rc=$rc $((t1 - t0)) s" >> "$run/timing.txt"
  [ $rc -eq 0 ] || { tail -5 "$run/sweep_output.txt"; tar czf "$OUT/${name}_eval.tgz" "$run"/*.txt "$run"/*.toml 2>/dev/null; break; }
  left=$(( end - $(date +%s) ))
  timeout "$left" python3 -m jaxlc.evaluate "$run" --no-figures > "$run/evaluate_output.txt" 2>&1
  rc=$?; t2=$(date +%s)
  echo "evaluate: rc=$rc $((t2 - t1)) s" >> "$run/timing.txt"
  cat "$run/timing.txt"
  tar czf "$OUT/${name}_eval.tgz" --exclude=traces.npz --exclude=cases.npz \
    --exclude=heldout_cases.npz "$run"/*.txt "$run"/*.toml "$run"/*.md "$run"/*.json "$run"/eval 2>/dev/null
  cp "$run"/eval/heldout_cases.npz "$OUT/${name}_heldout_cases.npz" 2>/dev/null
  [ "${METRICS:-1}" = 0 ] || tar czf "$OUT/${name}_metrics.tgz" "$run"/metrics/episodes.npz
  ls -la "$OUT"
done
