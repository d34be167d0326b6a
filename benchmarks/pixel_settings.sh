#!/bin/bash
# Pixel PPO settings side by side: many `cartpole train` runs at once, each on one torch thread,
# evaluated on our renderer (full evaluations of 100 episodes), then a line per run: env steps/s and
# every evaluation as STEPk:MEAN (/100: a full one; *: solved). benchmarks/README.md#pixels ran it on
# a lent 16-core GPU machine (DEVICE=cuda BUDGET=380s, then 290s; the two waves' settings below).
#
#   DEVICE=cuda BUDGET=380s WAVE=1 bash benchmarks/pixel_settings.sh
#   DEVICE=cpu BUDGET=2000 WAVE=2 bash benchmarks/pixel_settings.sh    # a smoke test
#   DEVICE=cuda BUDGET=330s WAVE=dqn bash benchmarks/pixel_settings.sh  # DQN's pixels preset, 8 x 2 seeds
#
# Each run's best checkpoint is copied to $OUT/best/NAME.pt, to be judged on Gymnasium's pictures with
# `cartpole eval` where the CPU time is (the wave's own verdicts use our renderer).
# The runs of a wave go at once: give the machine a core per run (14 or 16 of them).
DEVICE=${DEVICE:-cuda}; BUDGET=${BUDGET:-380s}; WAVE=${WAVE:-1}; OUT=${OUT:-/tmp/pixel_settings}
CARTPOLE=${CARTPOLE:-cartpole}
rm -rf "$OUT"; mkdir -p "$OUT"
# The settings of the preset before 2026-11-26 (8 envs x 16 steps, batch 128), then each run's changes.
base="--set num_envs=8 --set minibatch_size=128 --set eval_simulator=fast --set verdict_simulator=fast --set eval_every=10000 --set schedule_steps=500000"
AGENT=ppo
if [ "$WAVE" = dqn ]; then
  # The DQN pixels preset's own settings, evaluated as the PPO waves were; latest.pt (the whole replay)
  # only every 10 minutes, so that 16 runs do not spend the machine's disk on it.
  AGENT=dqn; base="--set eval_simulator=fast --set verdict_simulator=fast --set eval_every=10000 --set checkpoint_seconds=600"
fi
run() { name=$1; seed=$2; device=$3; shift 3
  $CARTPOLE train $AGENT --env cartpole/CartPolePixels-v1 --preset pixels --budget "$BUDGET" --seed "$seed" \
    --device "$device" --torch-threads 1 $base "$@" --runs-dir "$OUT/$name" > "$OUT/$name.log" 2>&1 & }
if [ "$WAVE" = dqn ]; then
  b128="--set batch_size=128"; e8="--set num_envs=8 --set gradient_steps=2"
  for s in 1 2; do
    run base_s$s $s $DEVICE
    run b128lr5_s$s $s $DEVICE $b128 --set lr=5e-4
    run e8b128_s$s $s $DEVICE $e8 $b128
    run buf50tau5_s$s $s $DEVICE --set buffer_size=50000 --set tau=0.005
    run heavy_s$s $s $DEVICE --set num_envs=8 --set gradient_steps=4 --set batch_size=256 --set lr=5e-4
    run duelb128_s$s $s $DEVICE --set dueling=true $b128
    run hard500b128_s$s $s $DEVICE --set tau=1 --set target_update_interval=500 $b128
    run combo_s$s $s $DEVICE $e8 $b128 --set buffer_size=50000 --set lr=5e-4 --set tau=0.005
  done
elif [ "$WAVE" = 1 ]; then
  run base_s1 1 $DEVICE; run base_s2 2 $DEVICE
  run shared_s1 1 $DEVICE --set shared_trunk=true; run shared_s2 2 $DEVICE --set shared_trunk=true
  run ep8_s1 1 $DEVICE --set n_epochs=8; run ep8_s2 2 $DEVICE --set n_epochs=8
  run mb64_s1 1 $DEVICE --set minibatch_size=64
  run lr1e3_s1 1 $DEVICE --set lr=1e-3
  run g99_s1 1 $DEVICE --set gamma=0.99
  run ent01_s1 1 $DEVICE --set ent_coef=0.01
  run env16_s1 1 $DEVICE --set num_envs=16 --set minibatch_size=256
  run lam95_s1 1 $DEVICE --set gae_lambda=0.95
  run relu256_s1 1 $DEVICE --set hidden_sizes=256 --set activation=relu
  run const_s1 1 $DEVICE --set lr_schedule=constant
  run cpu_base_s1 1 cpu; run cpu_shared_s1 1 cpu --set shared_trunk=true
else
  e16="--set num_envs=16 --set minibatch_size=256"; e32="--set num_envs=32 --set minibatch_size=512"
  run e16_s2 2 $DEVICE $e16; run e16_s3 3 $DEVICE $e16; run e16_s4 4 $DEVICE $e16
  run e32_s1 1 $DEVICE $e32; run e32_s2 2 $DEVICE $e32; run e32_s3 3 $DEVICE $e32
  run e16lr1_s1 1 $DEVICE $e16 --set lr=1e-3; run e16lr1_s2 2 $DEVICE $e16 --set lr=1e-3
  run e16n32_s1 1 $DEVICE --set num_envs=16 --set n_steps=32 --set minibatch_size=512
  run e32n8_s1 1 $DEVICE --set num_envs=32 --set n_steps=8 --set minibatch_size=256
  run e64n8_s1 1 $DEVICE --set num_envs=64 --set n_steps=8 --set minibatch_size=512
  run e16sh_s1 1 $DEVICE $e16 --set shared_trunk=true
  run e16ent_s1 1 $DEVICE $e16 --set ent_coef=0.01
  run e16mb128_s1 1 $DEVICE --set num_envs=16 --set minibatch_size=128
  run cpu_e16_s1 1 cpu $e16; run cpu_e32_s1 1 cpu $e32
fi
wait
python - "$OUT" <<'PY'
import json, pathlib, sys
root = pathlib.Path(sys.argv[1])
for log in sorted(root.glob("*.log")):
    evals, last = [], {}
    for best in (root / log.stem).glob("*/checkpoints/best.pt"):
        (root / "best").mkdir(exist_ok=True)
        (root / "best" / f"{log.stem}.pt").write_bytes(best.read_bytes())
    for metrics in (root / log.stem).glob("*/metrics.jsonl"):
        for line in metrics.read_text().splitlines():
            row = json.loads(line)
            if "eval/mean_return" in row:
                full = "/100" if row["eval/episodes"] >= 100 else ""
                evals.append(f"{row['step'] // 1000}k:{row['eval/mean_return']:.0f}{full}{'*' if row['eval/solved'] else ''}")
            elif "time" in row:
                last = row
    rate = last.get("step", 0) / max(last.get("time", 1), 1)
    print(f"{log.stem}: {rate:.0f} steps/s, {last.get('step')} steps; {' '.join(evals)}")
    print("   ", log.read_text().strip().splitlines()[-1][:160])
PY
