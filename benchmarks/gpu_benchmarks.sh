#!/usr/bin/env bash
# The benchmarks of docs/benchmarks.md's GPU section, in order of priority, each under what is
# left of DEADLINE_S (and its own cap), its CSV, JSON and output into runs/bench, packed into
# $OUT/bench.tgz after every step, so a call stopped at its limit returns what finished:
#   bash benchmarks/gpu_benchmarks.sh DEADLINE_S [SIZES] [RUN]
# SIZES: "gpu" (the default: 4,096-262,144 envs, 9/90/900 models, 1/10/100 seeds per cell) or
# "cpu" (the sizes a 2-core CPU runs in minutes: the same scripts, for the CPU figure beside)
# or "smoke" (configs/smoke.toml and the smallest sizes: a check of this script, seconds).
# The sweeps run SWEEP_EPISODES episodes per model (200 unless set; the full 5000 at three seed
# counts would outlast a device call): their wall time, the first chunk (compilation) apart.
# RUN: a trained run (default: the 1-seed sweep's) whose checkpoints the held-out evaluation's
# cost and the validation drive; the validation is model VALIDATE_MODEL (default ④) by crude
# Monte Carlo, stopped with SIGINT, which jaxlc.validate answers by writing what it has: with
# VALIDATE_S set, for that many seconds after the updates (RUN must exist then); else last, for
# what is left.
set -u
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD TQDM_DISABLE=1
end=$(( $(date +%s) + $1 )); sizes=${2:-gpu}
OUT=${OUT:-out}; B=runs/bench; S=benchmarks; rm -rf "$B"; mkdir -p "$B" "$OUT"
run=${3:-runs/bench_s1}; model=${VALIDATE_MODEL:-④}; episodes=${SWEEP_EPISODES:-200}
heldout="--policies 90 --lane-changes 1000"
config=""; update=""
case $sizes in
  gpu) envs="4096 32768 262144"; hazard_envs="4096 32768 65536"; models="9 90 900"
       seeds="1 10 100"; chunk=65536 ;;
  cpu) envs="4096 32768"; hazard_envs="4096"; models="9 90"; seeds="1"; chunk=2048 ;;
  *) envs="64"; hazard_envs="64"; models="9"; seeds="1"; chunk=64; model=0; episodes=40
     heldout="--policies 2 --lane-changes 20"
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
step sim_paper 120 python3 -m benchmarks.sim_throughput --envs $envs --steps 200 --repeats 3 \
  --traffic paper --csv "$B/sim_paper.csv"
for m in $models; do
  step "update_$m" 90 python3 -m benchmarks.update_throughput --models "$m" --repeats 5 $update \
    --out "$B/update_$m.csv"
done
validate() {  # CAP_S: model $model of $run by crude Monte Carlo until SIGINT at CAP_S
  step validate "$1" python3 -m jaxlc.validate "$run" --model "$model" --method mc \
    --lane-changes 100000000 --chunk $chunk --out "$B/validate"
}
[ -n "${VALIDATE_S:-}" ] && [ -d "$run" ] && validate "$VALIDATE_S"
for s in $seeds; do
  step "sweep_s$s" 120 python3 -m jaxlc.sweep $config --no-progress --seeds "$s" \
    train.episodes=$episodes \
    --out "runs/bench_s$s" --force &&
    python3 -m benchmarks.sweep_timing "runs/bench_s$s" "$B/sweep_s$s.json"
done
step heldout 90 python3 -m benchmarks.heldout_cost "$run" $heldout --out "$B"
step sim_hazards 120 python3 -m benchmarks.sim_throughput --envs $hazard_envs --steps 200 --repeats 3 \
  --traffic hazards --csv "$B/sim_hazards.csv"
[ -z "${VALIDATE_S:-}" ] && validate 600
date -u >> "$B/timing.txt"
tar czf "$OUT/bench.tgz" -C runs bench
