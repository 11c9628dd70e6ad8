#!/usr/bin/env bash
# A slice of the MinAtar head-to-head on a many-core machine (one torch thread a run). Each argument selects runs for
# scripts/benchmark.py (e.g. "--algos dqn --seeds 44-44 --workers 5"); the selections run side by side from step 0,
# checkpointing every 25k env steps, until STOP_AT seconds after this script started; pack_checkpoints.py then packs
# their newest checkpoints into $OUT, to resume elsewhere.
set -u
T0=$(date +%s)
STOP_AT=${STOP_AT:-535}
L=$OUT/slice.log
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl >> $L 2>&1 || { cat $L; exit 1; }
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
{ date -u; lscpu | grep -E "Model name|^CPU\(s\)"; command -v zstd; git rev-parse HEAD 2>&1 | head -1
  python3 -c "import sys,torch,numpy,pandas,stable_baselines3,rl_zoo3,optuna,minatar,sb3_offon,gymnasium as gym; e=gym.make('MinAtar/Breakout-v0'); print(sys.version, torch.__version__, numpy.__version__, pandas.__version__, stable_baselines3.__version__, e.reset(seed=0)[0].shape)"; } >> $L 2>&1 || { cat $L; exit 1; }
ROOT=/tmp/raw; mkdir -p $ROOT /tmp/logs; cp -r results/raw/minatar $ROOT/
B="python3 scripts/benchmark.py --study benchmarks/minatar.yml --root $ROOT --checkpoint-freq ${CKPT:-25000}"
i=0
for runs in "$@"; do $B $runs > /tmp/logs/slice$i.log 2>&1 & i=$((i + 1)); done
sleep 60; { echo "after 60 s:"; uptime; pgrep -fc "sb3_offon.train"; } >> $L
while [ $(( $(date +%s) - T0 )) -lt $STOP_AT ]; do sleep 5; done
{ echo "stopping at $(( $(date +%s) - T0 )) s:"; uptime; } >> $L
# pkill -f stops every matching process of the machine: run this where nothing else trains
pkill -9 -f scripts/benchmark.py; pkill -9 -f sb3_offon.train; sleep 2
tail -n 5 /tmp/logs/*.log >> $L 2>&1
ls /tmp/raw/.checkpoints/minatar/*/*/ >> $L 2>&1
python3 "$(dirname "$0")/pack_checkpoints.py" $ROOT >> $L 2>&1
echo "done at $(( $(date +%s) - T0 )) s" >> $L; ls -la $OUT >> $L; cat $L
