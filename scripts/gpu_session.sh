#!/usr/bin/env bash
# Everything a lent GPU session has to run, in three calls of under 10 minutes each
# (device time is 30 minutes a session: make the calls back to back, the machine stays warm
# only ~30 s between calls).
#
#   bash scripts/gpu_session.sh xmae    # issue 3: XMAE on Bandai (fit + test), a small checkpoint back for fix (issue 5)
#   bash scripts/gpu_session.sh bench   # issue 6: inference, training vs ref_xmae, data pipeline, fix and DVAE speed
#   bash scripts/gpu_session.sh dvae    # issue 4: Motion-DVAE prior (+ its test) + denoising + test
#   bash scripts/gpu_session.sh dvae-prior     # issue 4 over several calls: the prior only (RESUME=1 goes on)
#   bash scripts/gpu_session.sh dvae-denoise   # ... then its test, the denoising stage and its test
#   bash scripts/gpu_session.sh dvae-speed     # the prior's training step eager vs compiled (minutes)
#   bash scripts/gpu_session.sh profile        # issue 6: where the compiled XMAE training step's time goes (~2 min)
#   bash scripts/gpu_session.sh tune           # issue 6: the kernel-time levers: attention backends, max-autotune
#   bash scripts/gpu_session.sh gpu-tests      # the tests marked gpu (CUDA paths: CUDA graphs, bf16, resume across devices)
#   bash scripts/gpu_session.sh accuracy       # issue 6: XMAE test tables, fast path vs plain path, two seeds each
#   bash scripts/gpu_session.sh many-holes     # issue 31: Hermite-correcting XMAEs trained on the fix case's holes
#   bash scripts/gpu_session.sh many           # issue 31: XMAE across studios (configs/xmae_many.yaml), paper
#                                            # sizes on the GPU and the cpu preset on 8 of its CPU cores at once
#   bash scripts/gpu_session.sh corpora        # issue 50 (TRAIN_TIME + ~1 min): the paper sizes and the cpu preset on
#                                            # every corpus read (Human3.6M's training subjects too), both on the GPU
#   bash scripts/gpu_session.sh jobs           # issue 50 (~2 min): fix FOLDER --jobs 1..16 on the machine's cores
#   bash scripts/gpu_session.sh throughput     # issue 50 (~2 min): training throughput at batch 512 beside ref_xmae.py
#   bash scripts/gpu_session.sh issue50        # the three: jobs, throughput, then corpora (ROWS=device+cudagraphs
#                                            # TRAIN_TIME=00:00:04:00 fit one 10-minute call)
#
# A run longer than one call: the machine keeps checkpoints/ while it stays warm (~30 s between
# calls), so back-to-back calls with RESUME=1 continue last.ckpt. MAX_TIME / PRIOR_TIME count the
# whole run (Lightning's Timer state is in the checkpoint), so raise them by one call each time.
# FIT_ONLY=1 (xmae): fit only, no test/fix, for the calls before the last. COMPILE=1 (xmae, dvae*):
# model.compile_model (25.1 instead of 36.5 ms a step on the H100, docs/performance.md); give it on
# the first call: a resumed run takes the checkpoint's hyperparameters over the command line.
#
# Needs, carried as git-ignored folders (the GPU image has torch and lightning but not these):
#   .whl/          wheels: roma omegaconf antlr4-python3-runtime jsonargparse docstring-parser typeshed-client,
#                  pytest pluggy iniconfig pygments (for gpu-tests)
#   .device_data/  bandai_pos30.npz and bandai_rot30.npz (parsed Bandai), ref_xmae.py (../shared does not travel);
#                  corpus_body21.npz for `many` and `corpora`: scripts/build_corpus.py (docs/data.md), a
#                  compact archive (with --h36m for `corpora`); bandai_takes/ for `jobs`: 200 Bandai takes
#                  as positions .npz (prepare writes it, ~8 MB), which bench/fix_jobs.py cuts holes into
# Make both here first: `PYTHON=.venv/bin/python bash scripts/gpu_session.sh prepare` (then carry [".whl", ".device_data"]).
# .device_data with every part's files is over a call's 64 MiB: carry the files a part reads, e.g. for
# issue50: [".whl", ".device_data/corpus_body21.npz", ".device_data/bandai_takes", ".device_data/ref_xmae.py"]
# STEPS / MAX_TIME (xmae), PRIOR_TIME / DENOISE_TIME (dvae) trim the runs to the call's 10 minutes.
# Results land in $OUT (the device tool brings them back): eval tables, bench JSON, a small checkpoint.
set -euo pipefail
PART=${1:?usage: gpu_session.sh prepare|xmae|bench|profile|tune|gpu-tests|accuracy|dvae|dvae-prior|dvae-denoise|dvae-speed|many|many-hermite|many-holes|corpora|throughput|issue50}
if [ "$PART" = prepare ]; then  # on this machine, before the calls: what they carry
  mkdir -p .device_data .whl
  cp ../shared/bench/ref_xmae.py .device_data/
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl \
    roma==1.8.0 omegaconf==2.4.0 antlr4-python3-runtime==4.13.2 jsonargparse==4.53.0 docstring-parser typeshed-client \
    pytest==9.2.0 pluggy iniconfig pygments
  "${PYTHON:-.venv/bin/python}" - <<'PY'
from pathlib import Path
from mocapfix.data.datamodule import MotionDataModule
from mocapfix.data.windows import save_clips
clips = MotionDataModule(source="bvh", path="../shared/data/bandai-namco", drop_joints=["joint_Root"], fps=30).load_clips()
save_clips(Path(".device_data/bandai_rot30.npz"), clips)
save_clips(Path(".device_data/bandai_pos30.npz"),
           [c.replace(rotations=None, root_translation=None, offsets=None) for c in clips])
from mocapfix.io.positions import write_positions
Path(".device_data/bandai_takes").mkdir(exist_ok=True)
for clip in clips[:200]:  # bench/fix_jobs.py's takes (gpu_session.sh jobs)
    name = Path(clip.source).stem + ".npz"
    write_positions(Path(".device_data/bandai_takes", name), clip.positions.astype("float32"), clip.fps, clip.skeleton)
PY
  ls -la .device_data .whl
  exit 0
fi
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
PY=${PYTHON:-python3}
if [ -z "${PYTHON:-}" ]; then  # the GPU image: add what it lacks (once a machine)
  [ -d /tmp/site/roma ] || python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl
  export PYTHONPATH=/tmp/site:.
fi
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | tee "$OUT/gpu.txt" || true
# EXTRA: more CLI settings for every fit/test; FIT_EXTRA: for the first fit only (model sizes).
# A CPU smoke run of the plumbing: PYTHON=.venv/bin/python EXTRA="--trainer.accelerator cpu ..."
read -ra EXTRA_ARGS <<< "${EXTRA:-}"
read -ra FIT_ARGS <<< "${FIT_EXTRA:-}"
COMMON=(--data.source archive --data.cache_dir null --trainer.enable_progress_bar false "${EXTRA_ARGS[@]}")
# many, many-hermite (issue 31): the corpus of scripts/build_corpus.py, performers held out for
# validation (CMU 39, ReActIdle 014 and 015), each source's share of the batches
CORPUS=(--data.source archive --data.path .device_data/corpus_body21.npz --data.cache_dir null
  --data.split_by file --data.val_fraction 0 --data.test_fraction 0
  --data.val_patterns '["*/cmu39/*", "*/reactidle014/*", "*/reactidle015/*"]'
  --data.source_weights '{"*/bandai*": 0.6, "*/reactidle*": 0.25, "*/cmu*": 0.15}'
  --trainer.enable_progress_bar false)

case "$PART" in
xmae)
  # Bandai Namco, train split by file (seeded hash, 80/10/10), paper-sized XMAE, bf16, data on the GPU.
  START=$(date +%s)
  RUN_ARGS=()
  if [ -n "${RESUME:-}" ]; then RUN_ARGS+=(--ckpt_path checkpoints/xmae_bandai_gpu/last.ckpt); fi
  if [ -n "${COMPILE:-}" ]; then RUN_ARGS+=(--model.init_args.compile_model true); fi
  $PY -m mocapfix fit --config configs/xmae_bvh.yaml --experiment xmae_bandai_gpu "${COMMON[@]}" "${FIT_ARGS[@]}" \
    --data.path .device_data/bandai_pos30.npz --trainer.max_steps "${STEPS:-15000}" --model.init_args.total_steps "${STEPS:-15000}" \
    --trainer.max_time "${MAX_TIME:-00:00:06:00}" --trainer.val_check_interval 1000 "${RUN_ARGS[@]}" 2>&1 | tail -n 30
  FIT_END=$(date +%s)
  if [ -n "${FIT_ONLY:-}" ]; then ls -la checkpoints/xmae_bandai_gpu; exit 0; fi
  BEST=$(ls checkpoints/xmae_bandai_gpu/best-*.ckpt 2>/dev/null | head -1 || true)
  BEST=${BEST:-checkpoints/xmae_bandai_gpu/last.ckpt}
  $PY -m mocapfix test --config configs/xmae_bvh.yaml --experiment xmae_bandai_gpu "${COMMON[@]}" \
    --data.path .device_data/bandai_pos30.npz --ckpt_path "$BEST" 2>&1 | tee "$OUT/xmae_test.txt" | grep -v "test/" | tail -n 60
  echo "fit wall time: $((FIT_END - START)) s; tested: $BEST; last step: $($PY -c "import torch, sys; \
print(torch.load(sys.argv[1], map_location='cpu', weights_only=True)['global_step'])" checkpoints/xmae_bandai_gpu/last.ckpt)" \
    | tee -a "$OUT/xmae_test.txt"
  cp "$(ls -t logs/xmae_bandai_gpu/version_*/eval.json | head -1)" "$OUT/xmae_eval.json"
  tar czf "$OUT/xmae_logs.tgz" logs/xmae_bandai_gpu  # TensorBoard events of every call of the run
  $PY scripts/shrink_checkpoint.py "$BEST" "$OUT/xmae_bandai.ckpt"
  # issue 5 on the same model: fix --mode both on the corrupted Bandai test clips vs Lerp
  $PY bench/fix_bandai.py --ckpt "$BEST" --source archive --path .device_data/bandai_pos30.npz \
    --json-out "$OUT/fix_bandai-cuda.json" 2>&1 | tail -n 10
  ;;
bench)
  # most important first: a call cut at 10 minutes keeps what ran
  $PY bench/train_throughput.py --ref .device_data/ref_xmae.py --json-out "$OUT/train_throughput-cuda.json" \
    2>&1 | grep -v -e "^GPU available" -e "^TPU available" -e "LOCAL_RANK" -e "Tip:" | tail -n 20
  cp "$OUT/train_throughput-cuda.json" bench/results/  # data_pipeline compares against it
  $PY bench/inference.py --compile --json-out "$OUT/inference-cuda.json" 2>&1 | tail -n 12
  $PY bench/data_pipeline.py --bvh none --json-out "$OUT/data_pipeline-cuda.json" 2>&1 | tail -n 10
  $PY bench/dvae_speed.py --compile --json-out "$OUT/dvae_speed-cuda.json" 2>&1 | tail -n 10
  $PY bench/fix_speed.py --device cuda --batch-size 512 --json-out "$OUT/fix_speed-cuda.json" 2>&1 | tail -n 8
  ;;
profile)
  # torch.profiler over 20 compiled steps: busy fraction, kernels per step, time by kernel kind
  $PY bench/profile_train_step.py --json-out "$OUT/profile_train_step-cuda.json" 2>&1 | tail -n 40
  $PY bench/profile_train_step.py --compile-mode reduce-overhead \
    --json-out "$OUT/profile_train_step-cuda-cudagraphs.json" 2>&1 | tail -n 40
  $PY bench/profile_train_step.py --eager --json-out "$OUT/profile_train_step-cuda-eager.json" 2>&1 | tail -n 40
  # and batched inference (benchmark 2's pass, compiled with CUDA graphs): what bounds 8,530 windows/s
  $PY bench/profile_inference.py --json-out "$OUT/profile_inference-cuda.json" 2>&1 | tail -n 40
  ;;
gpu-tests)
  # CI has no GPU: the CUDA paths are tested here (../shared does not travel: its tests skip)
  $PY -m pytest -q -m gpu -p no:cacheprovider tests 2>&1 | tee "$OUT/gpu_tests.txt" | tail -n 30
  ;;
tune)
  # What would cut the kernel time (the bound once CUDA graphs remove the launches): which SDPA
  # backend is fastest on each attention call (~1 min), then max-autotune (Triton matmul templates
  # with the ReLU / residual work fused in; minutes of compiling each, so last) for training and
  # for inference, each beside the reduce-overhead row measured in the same run.
  $PY bench/attention_backends.py --json-out "$OUT/attention_backends-cuda.json" 2>&1 | tail -n 14
  $PY bench/train_throughput.py --ref .device_data/ref_xmae.py --rows device+cudagraphs,device+autotune \
    --json-out "$OUT/train_throughput-cuda-autotune.json" 2>&1 | grep -v -e "^GPU available" -e "^TPU available" \
    -e "LOCAL_RANK" -e "Tip:" | tail -n 8
  $PY bench/inference.py --compile --compile-mode max-autotune --json-out "$OUT/inference-cuda-autotune.json" 2>&1 | tail -n 12
  ;;
accuracy)
  # Issue 6's "no regression in accuracy": paper-sized XMAE on Bandai, the plain path (fp32, eager,
  # DataLoader) against the fast path (bf16, compiled, data on the GPU), two seeds each, both
  # paths of a seed at once on the one GPU (the speed does not matter here). Not yet run on a GPU:
  # the fp32 eager step is untimed there; STEPS=3000 fits the call's 10 minutes if it is under ~70 ms.
  $PY bench/fast_path_accuracy.py --device "${DEVICE:-cuda}" --steps "${STEPS:-3000}" --seeds "${SEEDS:-0,1}" --jobs 2 \
    --data-source archive --data-path .device_data/bandai_pos30.npz --workdir /tmp/fast_path_accuracy \
    --json-out "$OUT/fast_path_accuracy-cuda.json" "${EXTRA_ARGS[@]}" 2>&1 | tail -n 20
  ;;
many)
  # Issue 31: one run across studios (Bandai Namco minus the shared subset's val/test files, CMU
  # subjects 35-39, ReActIdle), validated on performers held out (CMU 39, ReActIdle 014 and 015),
  # which also calibrate the fill policy. The paper-sized model trains on the GPU (bf16, compiled)
  # while the cpu preset trains on 8 of the machine's CPU cores: they share no device.
  MANY=("${CORPUS[@]}" "${EXTRA_ARGS[@]}")
  OMP_NUM_THREADS=8 $PY -m mocapfix fit --config configs/xmae_many.yaml --experiment xmae_many_cpu "${MANY[@]}" \
    --model.init_args.preset cpu --model.init_args.lr 1e-3 --model.init_args.warmup_steps 300 \
    --trainer.accelerator cpu --trainer.precision 32-true --data.batches_on_device false --data.batch_size 64 \
    --trainer.max_steps "${CPU_STEPS:-4000}" --model.init_args.total_steps "${CPU_STEPS:-4000}" \
    --trainer.val_check_interval 2000 --trainer.max_time "${MAX_TIME:-00:00:07:00}" > "$OUT/many_cpu_fit.txt" 2>&1 &
  CPU_PID=$!
  $PY -m mocapfix fit --config configs/xmae_many.yaml --experiment xmae_many "${MANY[@]}" "${FIT_ARGS[@]}" \
    --model.init_args.compile_model "${COMPILE:-true}" --trainer.max_steps "${STEPS:-9000}" \
    --model.init_args.total_steps "${STEPS:-9000}" --trainer.max_time "${MAX_TIME:-00:00:07:00}" 2>&1 \
    | tee "$OUT/many_fit.txt" | grep -v -e Warning -e warn | tail -n 25
  if [ ! -f checkpoints/xmae_many/last.ckpt ]; then  # compiling failed: the rest of the call eager
    echo "compiled run left no checkpoint; eager for ${RETRY_TIME:-00:00:04:30}"
    $PY -m mocapfix fit --config configs/xmae_many.yaml --experiment xmae_many "${MANY[@]}" "${FIT_ARGS[@]}" \
      --trainer.max_steps 5000 --model.init_args.total_steps 5000 --trainer.max_time "${RETRY_TIME:-00:00:04:30}" \
      2>&1 | tee "$OUT/many_fit_eager.txt" | grep -v -e Warning -e warn | tail -n 25
  fi
  wait "$CPU_PID" || echo "cpu-preset run failed: $(tail -n 5 "$OUT/many_cpu_fit.txt")"
  tail -n 5 "$OUT/many_cpu_fit.txt"
  for run in xmae_many xmae_many_cpu; do
    BEST=$(ls checkpoints/$run/best-*.ckpt 2>/dev/null | head -1 || true)
    [ -n "$BEST" ] || BEST=checkpoints/$run/last.ckpt
    [ -f "$BEST" ] && $PY scripts/shrink_checkpoint.py "$BEST" "$OUT/$run.ckpt" && echo "$run: $BEST"
    cp checkpoints/$run/last.ckpt "$OUT/${run}_last_full.ckpt" 2>/dev/null || true  # to go on training (adapt)
  done
  rm -f "$OUT/xmae_many_last_full.ckpt"  # the paper-sized run's optimiser state is too large to bring back
  tar czf "$OUT/many_logs.tgz" logs/xmae_many logs/xmae_many_cpu
  ;;
corpora)
  # Issue 50: XMAE on every corpus the project reads (scripts/build_corpus.py --h36m: three studios
  # and Human3.6M's training subjects), validated on performers held out (CMU 39, ReActIdle 014
  # and 015); the paper sizes (compiled) and the cpu preset (eager) at once on the one GPU, both
  # for TRAIN_TIME (their cosines end with it). Session 26 (H100, 4:15): 4,581 and 9,073 steps.
  ALL=("${CORPUS[@]}" --data.source_weights '{"*/bandai*": 0.45, "*/h36m*": 0.25, "*/reactidle*": 0.19, "*/cmu*": 0.11}'
    --trainer.max_time "${TRAIN_TIME:-00:00:05:00}" --trainer.max_steps 200000 --model.init_args.total_steps 200000
    --trainer.val_check_interval "${VAL_EVERY:-2000}" "${EXTRA_ARGS[@]}")
  $PY -m mocapfix fit --config configs/xmae_many.yaml --experiment xmae_all_cpu "${ALL[@]}" \
    --model.init_args.preset cpu --model.init_args.lr 1e-3 --model.init_args.warmup_steps 300 > "$OUT/all_cpu_fit.txt" 2>&1 &
  $PY -m mocapfix fit --config configs/xmae_many.yaml --experiment xmae_all "${ALL[@]}" "${FIT_ARGS[@]}" \
    --model.init_args.compile_model "${COMPILE:-true}" > "$OUT/all_fit.txt" 2>&1 || echo "paper-sized run failed"
  wait || true
  for run in xmae_all xmae_all_cpu; do
    grep -e "stopped" -e "Time limit" -e Error "$OUT/${run#xmae_}_fit.txt" | tail -n 3 || true
    CK=$(ls checkpoints/$run/version_*/best-*.ckpt 2>/dev/null | tail -n 1 || true)
    [ -n "$CK" ] || CK=checkpoints/$run/last.ckpt
    FP32=(); [ "$run" = xmae_all ] || FP32=(--fp32)  # the cpu preset ships in fp32
    [ -f "$CK" ] && $PY scripts/shrink_checkpoint.py "${FP32[@]}" "$CK" "$OUT/$run.ckpt" && echo "$run: $CK"
    [ -f checkpoints/$run/last.ckpt ] && $PY -c "import torch, sys; c = torch.load(sys.argv[1], map_location='cpu', \
weights_only=True); print(sys.argv[1], 'step', c['global_step'])" checkpoints/$run/last.ckpt
  done
  tar czf "$OUT/all_logs.tgz" logs/xmae_all logs/xmae_all_cpu "$OUT"/all_*fit.txt 2>/dev/null || true
  rm -f "$OUT"/all_*fit.txt  # in the tarball: $OUT brings back 8 files at most
  ;;
jobs)
  # Issue 50: fix FOLDER --jobs N on the machine's cores, nothing else running: 200 Bandai takes
  # (30 fps, ~5 s each: ~38 CPU-s for --jobs 1 on the 2-core CPU). Not the CMU sample's long
  # takes: at 120 fps and ~13 s each, 200 of them took over 200 s for --jobs 1 on the H100
  # machine's cores (session 26: the call was cut before --jobs 2).
  $PY bench/fix_jobs.py --data .device_data/bandai_takes --min-seconds 0 --count "${TAKES:-200}" \
    --jobs "${JOBS:-1,16,8,4,2}" --json-out "$OUT/fix_jobs-$(nproc)cores.json" 2>&1 | tail -n 9
  ;;
issue50)
  # Issue 50 in one call: fix --jobs (~2 min), the throughput (~2 min), then the training for
  # TRAIN_TIME, so a call cut at its limit loses training time, not a benchmark; a part that fails
  # does not stop the next. TRAIN_TIME=00:00:04:00 fits a 10-minute call.
  bash "$0" jobs || echo "jobs failed: $?"
  bash "$0" throughput || echo "throughput failed: $?"
  bash "$0" corpora || echo "corpora failed: $?"
  ;;
throughput)
  # Issue 50: the product's training step at batch 512 (compiled, and with CUDA graphs) beside
  # ref_xmae.py at the same batch, in one run
  $PY bench/train_throughput.py --ref .device_data/ref_xmae.py --batch "${BATCH:-512}" \
    --rows "${ROWS:-device+compile,device+cudagraphs}" --json-out "$OUT/train_throughput-cuda-b${BATCH:-512}.json" \
    2>&1 | grep -v -e "^GPU available" -e "^TPU available" -e "LOCAL_RANK" -e "Tip:" | tail -n 10
  ;;
many-hermite)
  # Issue 31, the correction to the Hermite fill (fill_kind hermite): the cpu preset and the paper
  # sizes at once on the one GPU (eager: compiling would take a third of a short call), MAX_TIME each.
  MANY=("${CORPUS[@]}" --model.init_args.fill_kind hermite --trainer.max_time "${MAX_TIME:-00:00:01:20}"
    --trainer.max_steps "${STEPS:-2500}" --model.init_args.total_steps "${STEPS:-2500}"
    --model.init_args.warmup_steps 300 --trainer.val_check_interval 1200 "${EXTRA_ARGS[@]}")
  $PY -m mocapfix fit --config configs/xmae_many.yaml --experiment xmae_hermite_cpu "${MANY[@]}" \
    --model.init_args.preset cpu --model.init_args.lr 1e-3 > "$OUT/hermite_cpu_fit.txt" 2>&1 &
  $PY -m mocapfix fit --config configs/xmae_many.yaml --experiment xmae_hermite "${MANY[@]}" \
    > "$OUT/hermite_fit.txt" 2>&1
  wait
  for run in xmae_hermite xmae_hermite_cpu; do
    tail -n 3 "$OUT/${run#xmae_}_fit.txt" 2>/dev/null
    CK=$(ls checkpoints/$run/best-*.ckpt 2>/dev/null | head -1 || true)
    [ -n "$CK" ] || CK=checkpoints/$run/last.ckpt
    [ -f "$CK" ] && $PY scripts/shrink_checkpoint.py "$CK" "$OUT/$run.ckpt"
  done
  ;;
many-holes)
  # Issue 31, the fix case: XMAEs correcting the Hermite fill, trained on one hole of the whole
  # body or a limb per window (hole_ratio 1: what fix meets, model.init_args.hole_ratio) across the
  # studios, three at once on the one GPU: the paper sizes (compiled), the cpu preset on 1-s and
  # on 2-s windows (eager). HOLES_TIME ends each (its cosine ends with it: training/time_schedule.py);
  # *_STEPS only cap them. RUNS picks some of the three.
  HOLES=("${CORPUS[@]}" --model.init_args.fill_kind hermite --model.init_args.fill_input true
    --model.init_args.hole_ratio 1.0 --model.init_args.max_hole_s 0.9 --model.init_args.gap_ratio 0
    --trainer.max_time "${HOLES_TIME:-00:00:06:10}" "${EXTRA_ARGS[@]}")
  run_holes() {  # experiment steps window_s preset [more args]
    local exp=$1 steps=$2 window=$3 preset=$4; shift 4
    $PY -m mocapfix fit --config configs/xmae_many.yaml --experiment "$exp" "${HOLES[@]}" \
      --data.window_s "$window" --model.init_args.preset "$preset" --trainer.max_steps "$steps" \
      --model.init_args.total_steps "$steps" --trainer.val_check_interval "${VAL_EVERY:-1000}" "$@" > "$OUT/$exp.txt" 2>&1
  }
  RUNS=${RUNS:-holes_paper holes_cpu holes_cpu_2s}  # which of the three
  [[ " $RUNS " == *" holes_paper "* ]] && run_holes holes_paper "${PAPER_STEPS:-100000}" 1.0 paper \
    --model.init_args.compile_model true &
  [[ " $RUNS " == *" holes_cpu "* ]] && run_holes holes_cpu "${CPU_STEPS:-100000}" 1.0 cpu \
    --model.init_args.lr 1e-3 --model.init_args.warmup_steps 300 &
  [[ " $RUNS " == *" holes_cpu_2s "* ]] && run_holes holes_cpu_2s "${CPU2_STEPS:-100000}" 2.0 cpu \
    --model.init_args.lr 1e-3 --model.init_args.warmup_steps 300 &
  wait
  for run in $RUNS; do
    grep -e "stopped" -e "Time limit" -e Error "$OUT/$run.txt" | tail -n 3 || true  # none: set -e would end the loop
    CK=$(ls checkpoints/$run/best-*.ckpt 2>/dev/null | head -1 || true)
    [ -n "$CK" ] || CK=checkpoints/$run/last.ckpt
    FP32=(); [ "$run" = holes_paper ] || FP32=(--fp32)  # the cpu preset ships in fp32 (0.7 MB)
    [ -f "$CK" ] && $PY scripts/shrink_checkpoint.py "${FP32[@]}" "$CK" "$OUT/$run.ckpt" && echo "$run: $CK"
    [ -f checkpoints/$run/last.ckpt ] && $PY -c "import torch, sys; c = torch.load(sys.argv[1], map_location='cpu', \
weights_only=True); print(sys.argv[1], 'step', c['global_step'])" checkpoints/$run/last.ckpt
  done
  (cd logs && tar czf "$OUT/holes_logs.tgz" $RUNS)
  ;;
dvae-speed)
  # a few minutes: is the prior's step faster compiled? (decides COMPILE=1 for dvae-prior)
  $PY bench/dvae_speed.py --compile --json-out "$OUT/dvae_speed-cuda.json" 2>&1 | tail -n 10
  ;;
dvae|dvae-prior|dvae-denoise)
  # The prior checkpoint (~25 MB at width 256, ~360 MB at paper width) is not brought back: prior
  # and denoising run on one warm machine, in one call (dvae) or in back-to-back calls
  # (dvae-prior [RESUME=1] ..., dvae-denoise); the denoiser comes back, weights only.
  # The prior's own test MPJPE on clean windows is the floor of the denoiser: read it first.
  C=("${COMMON[@]}" --data.path .device_data/bandai_rot30.npz)
  if [ "$PART" != dvae-denoise ]; then
    PRIOR_ARGS=()
    if [ -n "${RESUME:-}" ]; then PRIOR_ARGS+=(--ckpt_path checkpoints/motion_dvae_bvh/last.ckpt); fi
    if [ -n "${COMPILE:-}" ]; then PRIOR_ARGS+=(--model.init_args.compile_model true); fi
    $PY -m mocapfix fit --config configs/motion_dvae_bvh.yaml "${C[@]}" "${FIT_ARGS[@]}" \
      --trainer.max_time "${PRIOR_TIME:-00:00:04:45}" "${PRIOR_ARGS[@]}" 2>&1 | tail -n 5
  fi
  if [ "$PART" != dvae-prior ]; then
    $PY -m mocapfix test --config configs/motion_dvae_bvh.yaml "${C[@]}" \
      --ckpt_path checkpoints/motion_dvae_bvh/last.ckpt 2>&1 | tee "$OUT/dvae_prior_test.txt" | tail -n 15
    # where the denoising stage starts: the prior's encoder and untrained predictors on noisy windows
    $PY -m mocapfix test --config configs/motion_dvae_denoise_bvh.yaml "${C[@]}" --experiment motion_dvae_denoise_untrained \
      --model.init_args.prior_ckpt checkpoints/motion_dvae_bvh/last.ckpt --model.init_args.opt_iterations 0 2>&1 \
      | grep -v "test/" | tail -n 10 | tee "$OUT/dvae_test_untrained.txt"
    $PY -m mocapfix fit --config configs/motion_dvae_denoise_bvh.yaml "${C[@]}" \
      --model.init_args.prior_ckpt checkpoints/motion_dvae_bvh/last.ckpt \
      --trainer.max_time "${DENOISE_TIME:-00:00:02:30}" 2>&1 | tail -n 5
    $PY -m mocapfix test --config configs/motion_dvae_denoise_bvh.yaml "${C[@]}" \
      --ckpt_path checkpoints/motion_dvae_denoise_bvh/last.ckpt 2>&1 | tee "$OUT/dvae_test.txt" | grep -v "test/" | tail -n 40
    cp "$(ls -t logs/motion_dvae_denoise_bvh/version_*/eval.json | head -1)" "$OUT/dvae_eval.json"
    tar czf "$OUT/dvae_logs.tgz" logs/motion_dvae_bvh logs/motion_dvae_denoise_bvh  # TensorBoard events
    # the denoiser, weights only (it carries the prior's weights and hyperparameters): test, fix and
    # dvae_per_frame --denoiser read it here; width 256 is ~11 MB, paper width does not come back
    $PY scripts/shrink_checkpoint.py --fp32 checkpoints/motion_dvae_denoise_bvh/last.ckpt "$OUT/dvae_denoiser.ckpt"
    # where the acceleration comes from (window ends or every frame): the checkpoints do not come
    # back. Last, so a call cut at its limit has already kept the rest.
    $PY bench/dvae_per_frame.py --prior checkpoints/motion_dvae_bvh/last.ckpt --source archive \
      --denoiser checkpoints/motion_dvae_denoise_bvh/last.ckpt --path .device_data/bandai_rot30.npz \
      --first-frames predicted decoded --json-out "$OUT/dvae_per_frame-cuda.json" 2>&1 | tail -n 10
  fi
  ;;
*)
  echo "unknown part $PART (see the usage line at the top)" >&2; exit 2 ;;
esac
ls -la "$OUT"
