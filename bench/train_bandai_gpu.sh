#!/usr/bin/env bash
# The issue-3 Bandai run on one GPU: XMAE (paper sizes) trained on the Bandai Namco train split,
# then `test` (the paper's tables, XMAE vs Lerp) on its test split.
# Expects the parsed dataset as an archive (no raw BVH needed on the GPU machine):
#   python -c "from mocapfix.data.datamodule import MotionDataModule as M; from mocapfix.data.windows import save_clips; \
#     from pathlib import Path; save_clips(Path('.device_data/bandai_pos30.npz'), \
#     M(source='bvh', path='../shared/data/bandai-namco', drop_joints=['joint_Root'], fps=30).load_clips())"
# Usage: bash bench/train_bandai_gpu.sh [MAX_STEPS] [OUT_DIR]
set -euo pipefail
STEPS=${1:-15000}
OUT_DIR=${2:-.}
ARCHIVE=${ARCHIVE:-.device_data/bandai_pos30.npz}
EXP=${EXP:-xmae_bandai_gpu}
START=$(date +%s)
python3 -m mocapfix fit --config configs/xmae_bvh.yaml --experiment "$EXP" \
  --data.source archive --data.path "$ARCHIVE" --data.cache_dir null \
  --trainer.max_steps "$STEPS" --model.init_args.total_steps "$STEPS" \
  --trainer.max_time "${MAX_TIME:-00:00:06:30}" --trainer.val_check_interval 1000 --trainer.enable_progress_bar false
FIT_END=$(date +%s)
python3 -m mocapfix test --config configs/xmae_bvh.yaml --experiment "$EXP" \
  --data.source archive --data.path "$ARCHIVE" --data.cache_dir null \
  --ckpt_path "$(ls checkpoints/$EXP/best-*.ckpt | head -1)" --trainer.enable_progress_bar false
echo "fit wall time: $((FIT_END - START)) s; total: $(( $(date +%s) - START )) s"
