#!/usr/bin/env bash
# The benchmarks of docs/benchmarks.md's GPU section, in order of priority, each under what is
# left of DEADLINE_S (and its own cap), its CSV, JSON and output into runs/bench, packed into
# $OUT/bench.tgz after every step, so a call stopped at its limit returns what finished:
#   bash benchmarks/scripts/gpu_benchmarks.sh DEADLINE_S [SIZES]
# SIZES: "gpu" (the default: 4,096-262,144 envs, 9/90/900 models, 1/10/100 seeds per cell) or
# "cpu" (the sizes a 2-core CPU runs in minutes: the same scripts, for the CPU figure beside)
# or "smoke" (configs/smoke.toml and the smallest sizes: a check of this script, seconds).
# The 100-seed sweep runs 500 episodes per model (the full 5000 would outlast a device call).
# Validation: the default's ④ (the 1-seed sweep's) by crude Monte Carlo for what time is left,
# stopped with SIGINT, which jaxlc.validate answers by writing what it has.
set -u
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD TQDM_DISABLE=1
end=$(( $(date +%s) + $1 )); sizes=${2:-gpu}
OUT=${OUT:-out}; B=runs/bench; S=benchmarks/scripts; rm -rf "$B"; mkdir -p "$B" "$OUT"
config=""; model=④; update=""
case $sizes in
  gpu) envs="4096 32768 262144"; hazard_envs="4096 32768 65536"; models="9 90 900"
       seeds="1 10 100"; chunk=65536 ;;
  cpu) envs="4096 32768"; hazard_envs="4096"; models="9 90"; seeds="1"; chunk=2048 ;;
  *) envs="64"; hazard_envs="64"; models="9"; seeds="1"; chunk=64; model=0
     config="--config configs/smoke.toml"; update="--tiny" ;;
esac

step() {  # NAME CAP_S COMMAND...: COMMAND under min(CAP_S, what is left), SIGINT at the end
  local name=$1 cap=$2 left t0 rc; shift 2
  left=$(( end - $(date +%s) )); [ "$left" -gt 20 ] || return 1
  [ "$cap" -lt "$left" ] && left=$cap
  t0=$(date +%s)
  timeout -s INT -k 20 "$left" "$@" > "$B/$name.txt" 2>&1; rc=$?
  echo "$name: rc=$rc $(( $(date +%s) - t0 )) s: $*" | tee -a "$B/timing.txt"
  tar czf "$OUT/bench.tgz" -C runs bench
  return $rc
}

bash $S/machine_info.sh > "$B/machine.txt" 2>&1
step sim_paper 120 python3 $S/sim_throughput.py --envs $envs --steps 200 --repeats 3 \
  --traffic paper --csv "$B/sim_paper.csv"
for m in $models; do
  step "update_$m" 90 python3 $S/update_throughput.py --models "$m" --repeats 5 $update \
    --out "$B/update_$m.csv"
done
for s in $seeds; do
  extra=""; [ "$s" -ge 100 ] && extra="train.episodes=500"
  step "sweep_s$s" 240 python3 -m jaxlc.sweep $config --no-progress --seeds "$s" $extra \
    --out "runs/bench_s$s" --force && cp "runs/bench_s$s/summary.json" "$B/sweep_s$s.json"
done
step heldout 120 python3 $S/heldout_cost.py runs/bench_s1 --policies 90 --lane-changes 1000 \
  --out "$B"
step sim_hazards 120 python3 $S/sim_throughput.py --envs $hazard_envs --steps 200 --repeats 3 \
  --traffic hazards --csv "$B/sim_hazards.csv"
step validate 600 python3 -m jaxlc.validate runs/bench_s1 --model "$model" --method mc \
  --lane-changes 100000000 --chunk $chunk --out "$B/validate"
date -u >> "$B/timing.txt"
tar czf "$OUT/bench.tgz" -C runs bench
