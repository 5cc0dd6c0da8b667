#!/usr/bin/env bash
# The shipped learned detector's training on one CUDA GPU machine (16 cores): render the shards with
# 16 processes, then train three proposal-network variants and the second stage side by side (one
# process each, batches prepared by forked workers); the model card says which variant shipped and how.
#
# usage: [RECIPE=scratch|finetune] train_gpu.sh SCALE OUT [STEPS REFINE_STEPS]
#   SCALE  tiny (a handful of scenes and 40 steps: checks the whole chain) or full
#   OUT    folder for the logs, ONNX files and training JSON (shards go to $SHARDS, default /tmp/dd)
#   RECIPE scratch (default): three proposal-network shapes and the second stage from random weights;
#          finetune: the shipped networks (agents/perception/models) fine-tuned on every kind of
#          scene (varied, harder, table1, mottled floors, ring runs) at two learning rates, and the
#          second stage fine-tuned too (the release in models/circles.md: a first call renders the
#          shards, then on the same machine RECIPE=finetune RENDERED=1 BUDGET=360 train_gpu.sh full OUT 4500 14000,
#          with MODELS= a folder holding the release before: git show ffaf4ff:agents/perception/models/<file>)
# Training stops (after a last validation) BUDGET seconds (default 470) after the script started,
# whatever the steps; DEVICE=cpu runs the chain without a GPU.
# Run from the repository root (or a copy of agents/, sims/, decentral/, protocols/).
set -u -o pipefail
SCALE=${1:?tiny or full}; OUT=${2:?output folder}
STEPS=${3:-4000}; RSTEPS=${4:-6000}
SHARDS=${SHARDS:-/tmp/dd}; NPROC=${NPROC:-16}; DEVICE=${DEVICE:-cuda}; BUDGET=${BUDGET:-470}
RECIPE=${RECIPE:-scratch}
case $RECIPE in scratch|finetune) ;; *) echo "RECIPE is scratch or finetune, not $RECIPE" >&2; exit 2 ;; esac
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1 OMP_WAIT_POLICY=PASSIVE
mkdir -p "$OUT" "$SHARDS"
PY=${PY:-python3}
if [ "$SCALE" = tiny ]; then
  RENDER="--varied 2008:2010 --varied-frames 3 --hard 5048:5050 --hard-frames 3 --table1 107:109 --table1-steps 2"
  [ "$RECIPE" = finetune ] && RENDER="$RENDER --mottled 6008:6010 --mottled-frames 3 --ring 308:310 --ring-steps 2"
else
  RENDER="--varied 2000:2400 --hard 5000:5300 --table1 100:109"
  [ "$RECIPE" = finetune ] && RENDER="$RENDER --mottled 6000:6100 --ring 300:400"
fi
t0=$(date +%s)
if [ "${RENDERED:-0}" != 1 ]; then  # RENDERED=1: the shards of an earlier call on the same machine are in $SHARDS
  for i in $(seq 0 $((NPROC - 1))); do
    $PY -m sims.lab.experiments.detector_data "$SHARDS" $RENDER --input-size 384x288 --stride "$NPROC" --offset "$i" \
      > "$SHARDS/render_$i.log" 2>&1 &
  done
  wait
fi
t1=$(date +%s)
ls "$SHARDS"/*.npz > /dev/null 2>&1 || { echo "no shards in $SHARDS" >&2; exit 2; }
[ "${RENDERED:-0}" = 1 ] && how="already rendered" || how="rendered in $((t1 - t0)) s"
echo "$(ls "$SHARDS"/*.npz | wc -l) shards ($(du -sh "$SHARDS" | cut -f1)), $how"
grep -h -i error "$SHARDS"/render_*.log && exit 1
set -f
MINUTES=$(awk "BEGIN {m = ($BUDGET - $t1 + $t0 - 60) / 60; print (m < 0.2 ? 0.2 : m)}")
echo "training for at most $MINUTES min each"
if [ "$RECIPE" = scratch ]; then
  V="--validation varied-2??9.npz hard-5?49.npz table1-108.npz --oversample table1-*=2"; SEED=7
else  # the validation patterns of the ring fine-tune (models/circles.md)
  V="--validation varied-*9.npz table1-*8.npz hard-5049.npz hard-5149.npz mottled-*9.npz ring-*9.npz --oversample table1-*=2"
  SEED=21
fi
EVERY=250
[ "$SCALE" = tiny ] && EVERY=20 STEPS=40 RSTEPS=40
COMMON="--device $DEVICE --eval-every $EVERY --max-minutes $MINUTES --seed $SEED $V"
train() {  # name, then options
  local name=$1; shift
  $PY -m agents.perception.training train "$SHARDS" -o "$OUT/$name" "$@" $COMMON > "$OUT/$name.log" 2>&1
  echo "$name: exit $?"
}
if [ "$RECIPE" = scratch ]; then
  train det_a --network detector --steps "$STEPS" --batch 32 --lr 2e-3 --warmup 200 --workers 4 &
  train det_b --network detector --steps "$STEPS" --batch 32 --lr 2e-3 --warmup 200 --workers 4 \
    --width 64 --channels 24 48 96 144 192 &
  train det_c --network detector --steps "$STEPS" --batch 32 --lr 2e-3 --warmup 200 --workers 4 \
    --width 64 --channels 16 32 64 128 192 &
  train ref --network refine --refine-steps "$RSTEPS" --batch 32 --lr 1e-3 --warmup 200 --workers 2 &
else
  MODELS=${MODELS:-agents/perception/models}  # the release to start from
  train ft_2e3 --network detector --init "$MODELS" --steps "$STEPS" --batch 32 --lr 2e-3 --warmup 200 --workers 7 &
  train ft_1e3b48 --network detector --init "$MODELS" --steps "$((STEPS * 2 / 3))" --batch 48 --lr 1.5e-3 --warmup 200 \
    --workers 7 &
  train ref_1e3 --network refine --init "$MODELS" --refine-steps "$RSTEPS" --batch 32 --lr 1e-3 --warmup 200 --workers 1 &
fi
wait
t2=$(date +%s)
echo "trained in $((t2 - t1)) s (render $((t1 - t0)) s)"
set +f
for f in "$OUT"/*.log; do echo "== $f"; grep -v Warning "$f" | tail -4; done
