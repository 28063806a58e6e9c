"""The benchmark scripts run end to end (tiny sizes, CPU) and write their JSON: a GPU session is
too scarce to find out there that a script broke. Nothing here asserts a speed."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from mocapfix.models.checkpoint import xmae_checkpoint
from mocapfix.models.xmae import XMAE

REPO = Path(__file__).resolve().parents[1]
REF = REPO.parent / "shared" / "bench" / "ref_xmae.py"


def bench(script: str, *args, tmp_path: Path) -> dict:
    out = tmp_path / f"{script}.json"
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1")
    run = subprocess.run(
        [sys.executable, str(REPO / "bench" / f"{script}.py"), *map(str, args), "--json-out", str(out)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(out.read_text())


def test_train_throughput(tmp_path):
    ref = REF if REF.exists() else "none"
    r = bench(
        "train_throughput",
        "--device",
        "cpu",
        "--fps",
        "10",
        "--batch",
        "2",
        "--steps",
        "1",
        "--warmup",
        "1",
        "--synthetic-clips",
        "4",
        "--rows",
        "device,constant",
        "--ref",
        ref,
        tmp_path=tmp_path,
    )
    rows = {x["row"]: x for x in r["rows"]}
    assert {"device", "constant"} <= set(rows) and rows["device"]["seq_per_s"] > 0
    assert rows["device"]["frames"] == 10 and rows["device"]["joints"] == 22
    if ref != "none":  # the reference ran on the same shapes, and the ratios are against it
        assert rows["ref fast"]["frames"] == 10 and rows["device"]["x_ref_fast"] > 0


def test_profile_train_step(tmp_path):
    r = bench(
        "profile_train_step",
        "--device",
        "cpu",
        "--fps",
        "10",
        "--batch",
        "2",
        "--warmup",
        "1",
        "--steps",
        "2",
        "--synthetic-clips",
        "4",
        "--top",
        "5",
        tmp_path=tmp_path,
    )
    assert r["profiled_steps"] == 2 and r["frames"] == 10 and r["wall_ms_per_step"] > 0
    # the operators the profile saw: the model's matmuls are among the slowest
    assert len(r["rows"]) == 5 and any("mm" in x["name"] for x in r["rows"])


def test_profile_inference(tmp_path):
    r = bench(
        "profile_inference",
        "--device",
        "cpu",
        "--fps",
        "10",
        "--batch",
        "2",
        "--warmup",
        "1",
        "--passes",
        "2",
        "--top",
        "5",
        tmp_path=tmp_path,
    )
    assert r["profiled_passes"] == 2 and r["frames"] == 10 and r["wall_ms_per_pass"] > 0
    assert len(r["rows"]) == 5 and any("addmm" in x["name"] or "mm" in x["name"] for x in r["rows"])


def test_profile_summary_of_cuda_kernels():
    """The GPU half of profile_train_step.py on made-up kernel events: no GPU needed to check it."""
    from types import SimpleNamespace

    from torch.autograd import DeviceType

    sys.path.insert(0, str(REPO / "bench"))
    try:
        from profile_train_step import summarise
    finally:
        sys.path.remove(str(REPO / "bench"))

    def kernel(name, us, annotation=False):
        return SimpleNamespace(
            name=name,
            device_type=DeviceType.CUDA,
            is_user_annotation=annotation,
            time_range=SimpleNamespace(elapsed_us=lambda: us),
        )

    cpu_op = SimpleNamespace(name="aten::mm", device_type=DeviceType.CPU)
    # the GPU-side range of a record_function annotation spans kernels: it is not one
    step_range = kernel("Optimizer.step#Adam.step", 900.0, annotation=True)
    events = [
        kernel("sm90_xmma_gemm_bf16bf16_bf16f32", 100.0),
        kernel("sm90_xmma_gemm_bf16bf16_bf16f32", 100.0),
        kernel("flash_fwd_kernel", 50.0),
        kernel("triton_poi_fused_add_mul_0", 30.0),
        kernel("multi_tensor_apply_kernel", 20.0),
        cpu_op,
        step_range,
    ]
    summary, rows = summarise(SimpleNamespace(events=lambda: events), steps=2, wall_s=0.001, gpu=True, top=3)
    assert summary["kernel_ms_per_step"] == pytest.approx(0.15) and summary["busy"] == pytest.approx(0.3)
    assert summary["kernels_per_step"] == 2.5
    assert summary["kernel_ms_by_kind"] == pytest.approx(
        {"matmul": 0.1, "attention": 0.025, "compiled (triton)": 0.015, "optimiser": 0.01}
    )
    assert [r["kind"] for r in rows] == ["matmul", "attention", "compiled (triton)"]
    assert rows[0]["calls_per_step"] == 1 and rows[0]["share"] == pytest.approx(2 / 3)


def test_dvae_per_frame(tmp_path):
    import lightning

    from mocapfix.data.datamodule import MotionDataModule
    from mocapfix.training.denoise_module import DVAEDenoiseModule
    from mocapfix.training.dvae_module import MotionDVAEModule

    dm = MotionDataModule(
        source="synthetic", synthetic_clips=12, with_rotations=True, fps=30, window_s=1.0, cache_dir=None
    )
    dm.setup("test")  # the skeleton the script's data module will read
    torch.manual_seed(0)  # tiny untrained models: the script's plumbing, not a model's quality
    prior = MotionDVAEModule(
        latent_dim=4,
        lstm_hidden=16,
        mlp_hidden=16,
        norm_groups=4,
        skeleton=dm.skeleton.to_dict(),
        window_fps=30.0,
        window_frames=30,
    )
    denoiser = DVAEDenoiseModule(
        prior_hparams={k: v for k, v in prior.hparams.items() if not k.startswith("_")}, noise="rotation"
    )
    for name, module in (("prior", prior), ("denoiser", denoiser)):
        torch.save(
            {
                "pytorch-lightning_version": lightning.__version__,
                "hyper_parameters": dict(module.hparams),
                "state_dict": module.state_dict(),
            },
            tmp_path / f"{name}.ckpt",
        )
    r = bench(
        "dvae_per_frame",
        "--prior",
        tmp_path / "prior.ckpt",
        "--denoiser",
        tmp_path / "denoiser.ckpt",
        "--source",
        "synthetic",
        "--synthetic-clips",
        "12",
        "--sigmas",
        "0",
        "0.1",
        "--first-frames",
        "predicted",
        "decoded",
        tmp_path=tmp_path,
    )
    rows = [(x["model"].split()[0], x["sigma"], x.get("first_frame")) for x in r["rows"]]
    assert rows == [
        ("prior", 0, None),
        ("denoiser,", 0, "predicted"),
        ("denoiser,", 0, "decoded"),
        ("denoiser,", 0.1, "predicted"),
        ("denoiser,", 0.1, "decoded"),
    ]
    predicted, decoded = r["rows"][3], r["rows"][4]  # the same estimate but for frame 0
    assert predicted["error_mm_per_frame"][1:] == decoded["error_mm_per_frame"][1:]
    assert predicted["error_mm_per_frame"][0] != decoded["error_mm_per_frame"][0]
    for row in r["rows"]:  # 30 frames: an error at each, an acceleration at the 28 centre frames
        assert len(row["error_mm_per_frame"]) == 30 and len(row["accel_per_frame"]) == 28
        assert row["accel"] == pytest.approx(sum(row["accel_per_frame"]) / 28)
        assert row["accel_truth"] == pytest.approx(r["rows"][0]["accel_truth"])  # the same clean windows
    assert r["rows"][0]["error_mm_per_frame"][0] == 0.0  # the prior is given x_0
    # sigma 0 is the clean clip again (FK of the unchanged rotations: float error only)
    assert r["rows"][1]["noisy_mpjpe_mm"] < 1e-2 < r["rows"][3]["noisy_mpjpe_mm"]


def test_inference(tmp_path):
    r = bench("inference", "--device", "cpu", "--fps", "10", "--batch", "2", "--repeat", "1", tmp_path=tmp_path)
    assert [x["case"] for x in r["rows"]] == ["full", "10% missing", "full, batch 1"]
    # 22 joints x 10 frames: the counted work is the paper's architecture at 220 tokens
    assert 0.5 < r["gflop_per_window"] < 5 and r["rows"][0]["tflops"] > 0


def test_attention_backends(tmp_path):
    r = bench(
        "attention_backends",
        "--device",
        "cpu",
        "--fps",
        "10",
        "--batch",
        "2",
        "--infer-batch",
        "2",
        "--repeat",
        "1",
        "--backends",
        "auto,math",
        tmp_path=tmp_path,
    )
    calls = {(c["phase"], c["call"]): c for c in r["calls"]}
    # the shapes XMAE runs: 15 % of 220 tokens kept in training, all of them at inference
    assert calls["train", "encoder self"]["Nq"] == 33 and calls["infer", "encoder self"]["Nq"] == 220
    assert calls["train", "decoder cross"]["Nk"] == 33 and calls["train", "decoder self, first (once)"]["B"] == 1
    assert all(c["auto_ms"] > 0 and c["math_ms"] > 0 and c["fastest"] in ("auto", "math") for c in r["calls"])
    train = r["totals"][0]
    assert train["best_mix_ms"] <= min(train["auto_ms"], train["math_ms"]) + 1e-9


def test_data_pipeline(tmp_path):
    r = bench(
        "data_pipeline",
        "--device",
        "cpu",
        "--bvh",
        "none",
        "--fps",
        "10",
        "--batch",
        "4",
        "--batches",
        "2",
        "--workers",
        "0",
        tmp_path=tmp_path,
    )
    assert [x["row"] for x in r["rows"]] == ["loader", "device"] and all(x["windows_per_s"] > 0 for x in r["rows"])


@pytest.mark.slow  # a minute of CPU; `make test-all` runs it
def test_dvae_speed(tmp_path):
    r = bench(
        "dvae_speed",
        "--device",
        "cpu",
        "--batch",
        "4",
        "--steps",
        "1",
        "--warmup",
        "0",
        "--eval-batch",
        "2",
        "--opt-iterations",
        "1",
        tmp_path=tmp_path,
    )
    assert [x["row"] for x in r["rows"]][:2] == ["prior training", "regression"]
    assert all(x.get("s_per_frame", 1) > 0 for x in r["rows"])


def test_dvae_op_count(tmp_path):
    r = bench("dvae_op_count", "--batch", "4", "--lstm-hidden", "16", tmp_path=tmp_path)
    ops = {x["part"]: x["ops"] for x in r["rows"]}
    assert ops["encoder"] > 0 and ops["backward"] > ops["encoder"]
    # the state of 30 frames is whole-window arithmetic (a frame loop in unwrap_rotvec put ~740 here)
    assert ops["state"] < 400


def test_fix_speed(tmp_path):
    r = bench("fix_speed", "--seconds", "2", "--overlaps", "0.5", "--cases", "denoise,infill-gaps", tmp_path=tmp_path)
    assert [x["case"] for x in r["rows"]] == ["denoise", "infill-gaps"] and r["rows"][0]["windows"] >= 2


@pytest.mark.slow
def test_fix_library_cost(tmp_path, cmu_files):
    """Two CMU takes holed, one short take as the library: each step timed."""
    data, library = tmp_path / "data", tmp_path / "library"
    for folder, f in [(data, cmu_files[0]), (data, cmu_files[1]), (library, cmu_files[2])]:
        folder.mkdir(exist_ok=True)
        (folder / f.name).symlink_to(f)
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1")
    script = [sys.executable, str(REPO / "bench" / "fix_library_cost.py")]
    args = ["--data", data, "--library", library, "--min-seconds", "0", "--part", "leg", "--gap", "0.5"]
    run = subprocess.run(script + list(map(str, args)), env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "2 takes" in run.stdout and "library of 1 takes" in run.stdout and "total" in run.stdout


@pytest.mark.slow
def test_fix_bandai(tmp_path, bandai_dir):
    """The issue-5 scoring on Bandai's test split, with an untrained tiny model for Bandai's joints."""
    from mocapfix.data.datamodule import MotionDataModule

    dm = MotionDataModule(
        source="bvh", path=str(bandai_dir), drop_joints=["joint_Root"], fps=30, cache_dir=str(tmp_path / "cache")
    )
    skeleton = dm.load_clips()[0].skeleton
    sizes = dict(enc_dim=32, enc_depth=1, enc_mlp_dim=64, dec_dim=32, dec_depth=1, dec_mlp_dim=64, head_dim=16)
    torch.save(xmae_checkpoint(XMAE(skeleton.num_joints, 30, **sizes), skeleton, 30.0), tmp_path / "m.ckpt")
    r = bench("fix_bandai", "--ckpt", tmp_path / "m.ckpt", "--path", bandai_dir, "--device", "cpu", tmp_path=tmp_path)
    assert r["clips"] > 10 and r["nan_left"] == 0
    rows = {x["tokens"]: x for x in r["rows"]}
    # Lerp fills holes well and cannot see displaced tokens: the scoring separates the two
    assert rows["holes"]["lerp_mm"] < 200 < rows["displaced"]["lerp_mm"]


def test_units_bandai(tmp_path, bandai_dir):
    r = bench("units_bandai", "--path", bandai_dir, "--every", "192", tmp_path=tmp_path)
    rows = {x["written_in"]: x for x in r["rows"]}
    assert r["files"] == 2 and rows["inch"]["unit_found"] == "inch" and rows["mm"]["up_axis_right"] == "4 of 4"
    assert 0.95 < rows["0.0564"]["hip_ratio_min"] <= rows["0.0564"]["hip_ratio_max"] < 1.05


@pytest.mark.slow  # a minute of CPU; `make test-all` runs it
def test_fix_policy_bandai(tmp_path, bandai_dir):
    """Issue 18's denoising bars on Bandai's test split, with an untrained tiny model whose policy
    replaces nothing (a threshold no disagreement reaches): clean clips come back unchanged and
    displaced arms stay displaced."""
    from mocapfix.data.datamodule import MotionDataModule
    from mocapfix.fills.policy import FillPolicy

    skeleton = (
        MotionDataModule(source="bvh", path=str(bandai_dir), fps=30, cache_dir=str(tmp_path / "cache"))
        .load_clips()[0]
        .skeleton
    )
    sizes = dict(enc_dim=32, enc_depth=1, enc_mlp_dim=64, dec_dim=32, dec_depth=1, dec_mlp_dim=64, head_dim=16)
    ckpt = xmae_checkpoint(XMAE(skeleton.num_joints, 30, **sizes), skeleton, 30.0)
    ckpt["fill_policy"] = FillPolicy([0.5], {"full": {"xmae": [50.0], "spline": [10.0]}}, 1e4).to_dict()
    torch.save(ckpt, tmp_path / "m.ckpt")
    r = bench(
        "fix_policy_bandai",
        "--ckpt",
        tmp_path / "m.ckpt",
        "--path",
        bandai_dir,
        "--device",
        "cpu",
        "--max-clips",
        "4",
        "--cache-dir",
        tmp_path / "cache",
        tmp_path=tmp_path,
    )
    rows = {x["case"]: x for x in r["rows"]}
    assert r["clips"] == 4 and rows["clean clips"]["changed_pct"] == 0.0
    assert rows["displaced arm tokens"]["after_mm"] == pytest.approx(rows["displaced arm tokens"]["before_mm"])
    assert 500 <= rows["displaced arm tokens"]["before_mm"] <= 1000


@pytest.mark.slow
def test_fix_overlap_bandai(tmp_path, bandai_dir):
    """The overlap table with the shipped model on two test clips: the first row is its own
    baseline, fewer windows at a smaller overlap, and errors of a working model (the clean clips
    come back within a few mm; the displaced arms, 500-1000 mm off, well below that)."""
    r = bench(
        "fix_overlap_bandai",
        "--model",
        "xmae-cpu-bandai",
        "--path",
        bandai_dir,
        "--device",
        "cpu",
        "--overlaps",
        "0.5,0",
        "--max-clips",
        "2",
        "--cache-dir",
        tmp_path / "cache",
        tmp_path=tmp_path,
    )
    first, last = r["rows"]
    assert r["clips"] == 2 and r["policy"] and first["speedup"] == 1.0 and first["clean_change_mm"] == 0.0
    assert last["windows"] < first["windows"]
    assert first["clean_mm"] < 5 and first["displaced arms_mm"] < 100


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_inference_cuda_graphs(tmp_path):
    r = bench(
        "inference", "--device", "cuda", "--fps", "10", "--batch", "8", "--repeat", "2", "--compile", tmp_path=tmp_path
    )
    assert {x["net"] for x in r["rows"]} == {"eager", "compiled"}


@pytest.mark.slow
def test_fast_path_accuracy_runs_fit_and_test_per_seed(tmp_path):
    """Plumbing only (the plain path, two seeds of two steps, tiny model): each run's eval.json
    comes back and the table compares paths by case."""
    from cli_utils import SMALL_DATA, TINY

    r = bench(
        "fast_path_accuracy",
        "--device",
        "cpu",
        "--config",
        REPO / "configs" / "xmae.yaml",
        "--paths",
        "plain",
        "--seeds",
        "0,1",
        "--jobs",
        "2",
        "--steps",
        "2",
        "--batch",
        "4",
        "--data-source",
        "synthetic",
        "--data-path",
        "none",
        "--workdir",
        tmp_path / "runs",
        *TINY,
        *SMALL_DATA,
        "--model.init_args.eval_gaps_s",
        "[0.3]",
        tmp_path=tmp_path,
    )
    assert [(run["path"], run["seed"]) for run in r["runs"]] == [("plain", 0), ("plain", 1)]
    cases = {row["case"]: row for row in r["table"]}
    assert "infill full 0.3 s" in cases and "noise full 2 cm" in cases
    row = cases["infill full 0.3 s"]
    assert len(row["plain"]) == 2 and row["plain_range"] == round(max(row["plain"]) - min(row["plain"]), 2)
    assert (tmp_path / "runs" / "plain-seed1" / "checkpoints" / "run" / "last.ckpt").is_file()


def test_fast_path_accuracy_compares_against_the_seed_range():
    sys.path.insert(0, str(REPO / "bench"))
    try:
        from fast_path_accuracy import compare
    finally:
        sys.path.remove(str(REPO / "bench"))

    def rows(value):
        return [
            {"task": "infill", "part": "full", "gap_s": 0.5, "method": m, "mpjpe_mm": value} for m in ("xmae", "lerp")
        ]

    runs = [
        {"path": "plain", "rows": rows(20.0)},
        {"path": "plain", "rows": rows(22.0)},
        {"path": "fast", "rows": rows(23.0)},
        {"path": "fast", "rows": rows(24.0)},
    ]
    (row,) = compare(runs, ["plain", "fast"])
    assert row["case"] == "infill full 0.5 s" and row["plain_mean"] == 21.0 and row["fast_mean"] == 23.5
    assert row["difference"] == 2.5 and row["plain_range"] == 2.0 and not row["within_seed_range"]
    runs[0]["rows"] = rows(19.0)  # a wider spread between seeds: the same difference is noise
    assert compare(runs, ["plain", "fast"])[0]["within_seed_range"]
    assert compare(runs[1:], ["plain", "fast"])[0]["within_seed_range"] is None  # one plain seed: no verdict


def _one_take(folder: Path, cmu_files: list[Path], seconds: float = 4.0) -> Path:
    """folder/ with a link to the CMU take nearest `seconds` long (120 fps; the header says)."""

    def frames(f: Path) -> int:
        with f.open() as lines:
            return next(int(line.split()[1]) for line in lines if line.startswith("Frames:"))

    take = min(cmu_files, key=lambda f: abs(frames(f) - 120 * seconds))
    folder.mkdir()
    (folder / take.name).symlink_to(take)
    return folder


def test_fix_both_strangers(tmp_path, cmu_files):
    """One CMU take through the shipped model: clean, then with an arm displaced every 2 s
    (evaluation/recording.py: displace_arms); the displaced error comes down."""
    _one_take(tmp_path / "takes", cmu_files)
    r = bench("fix_both_strangers", "--data", tmp_path / "takes", tmp_path=tmp_path)
    rows = {x["case"]: x for x in r["rows"]}
    assert r["takes"] == 1 and rows["displaced arm tokens"]["tokens"] > 0
    assert rows["displaced arm tokens"]["after_mm"] < rows["displaced arm tokens"]["before_mm"]


def test_fix_strangers_cmu_fills_only(tmp_path, cmu_files):
    """The classical and motion-matching fills on one CMU take's evenly spread holes
    (evaluation/recording.py: spread_holes), every part and length: a cell each."""
    _one_take(tmp_path / "takes", cmu_files)
    r = bench(
        "fix_strangers_cmu",
        "--data",
        tmp_path / "takes",
        "--min-seconds",
        "0",
        "--model-only",
        "--no-model",
        tmp_path=tmp_path,
    )
    cells = {(x["part"], x["method"]): x for x in r["rows"]}
    assert r["takes"] == 1 and {"full", "arm", "leg"} == {p for p, _ in cells}
    assert 0 < cells["full", "limb"]["0.1s"] < cells["full", "limb"]["0.9s"] < 1000


def test_fix_scaling(tmp_path, cmu_files):
    """One holed CMU take, copied once and twice into a folder, each folder fixed by its own
    `mocapfix fix` process: CPU seconds, the slope between the two, peak memory."""
    _one_take(tmp_path / "takes", cmu_files)
    r = bench("fix_scaling", "--data", tmp_path / "takes", "--min-seconds", "0", "--copies", "1,2", tmp_path=tmp_path)
    one, two = r["rows"]
    assert (one["files"], two["files"]) == (1, 2) and abs(two["minutes"] - 2 * one["minutes"]) < 0.02
    assert one["cpu_s"] > 0 and one["peak_mb"] > 50 and "marginal_cpu_s_per_min" in two
    # with --library read once into an index, which the timed run reads
    args = ["--copies", "1", "--library", tmp_path / "takes", "--library-index"]
    r = bench("fix_scaling", "--data", tmp_path / "takes", "--min-seconds", "0", *args, tmp_path=tmp_path)
    assert r["index_build"]["cpu_s"] > 0 and len(r["rows"]) == 1


def test_match_search(tmp_path, cmu_files):
    """Motion matching's library searched three ways (every start, the proxy, the frame index) on
    one CMU take, every cell."""
    _one_take(tmp_path / "takes", cmu_files)
    r = bench("match_search", "--data", tmp_path / "takes", "--min-seconds", "0", tmp_path=tmp_path)
    assert len(r["rows"]) == 12 and r["queried"] == 1
    for row in r["rows"]:
        assert all(0 < row[f"match_delta {way}"] < 1000 for way in ("exact", "proxy", "index"))
        assert row["largest difference mm proxy"] >= 0 and row["largest difference mm index"] >= 0


def test_keypoints_real(tmp_path, bandai_files):
    """Two of the sets, made from a Bandai walk with bones that breathe by 2 cm: a Kinect v1 SDK
    log (timestamps in ms, a tracking flag per joint; a 2-s gap where the person left splits it
    in two takes) and a lifter's unnamed npz in the Human3.6M layout."""
    from test_keypoints import in_layout
    from test_limbs import ALL, BODY, breathing

    from mocapfix.fix.limbs import limb_bones
    from mocapfix.io import read_motion
    from mocapfix.io.conventions import from_z_up
    from mocapfix.io.layouts import LAYOUTS
    from mocapfix.rig.mapping import onto_skeleton

    walk = next(f for f in bandai_files if f.name == "dataset-2_walk_elderly_002.bvh")
    clip = onto_skeleton(read_motion(walk)[0], BODY)
    body = breathing(clip.positions.astype(np.float64) + clip.origin, limb_bones(BODY, ALL), 0.02, seed=4)
    kinect = from_z_up(in_layout("kinect20", body), "y")  # (T, 20, 3), a camera's y up
    names = LAYOUTS["kinect20"].joint_names
    header = ["timestamp", "framenum"] + [f"{n}_{c}" for n in names for c in ("X", "Y", "Z", "tracked")]
    stamps = np.arange(len(kinect)) * 1000 / 30 + np.where(np.arange(len(kinect)) >= 200, 2000, 0)
    rows = [[t, i] + [v for j in range(len(names)) for v in (*kinect[i, j], 2)] for i, t in enumerate(stamps)]
    (tmp_path / "root" / "gaitkinect").mkdir(parents=True)
    lines = ["\t".join(header)] + ["\t".join(f"{v:.6f}" for v in r) for r in rows]
    (tmp_path / "root" / "gaitkinect" / "inputs__miky__walk.skl").write_text("\n".join(lines) + "\n")
    (tmp_path / "root" / "vp3d_skating").mkdir()
    np.savez(tmp_path / "root" / "vp3d_skating" / "out_3D_vp3d.npz", from_z_up(in_layout("h36m17", body), "y"))
    r = bench("keypoints_real", "--root", tmp_path / "root", tmp_path=tmp_path)
    rows = {x["set"]: x for x in r["rows"]}
    assert set(rows) == {"GaitKinect v1 gait (Kinect v1)", "VideoPose3D skating (video)"}
    assert rows["GaitKinect v1 gait (Kinect v1)"]["takes"] == 2  # split at the gap
    for row in rows.values():
        assert row["input_limb_sigma_mm"] > 5 and row["fix_sigma_cut"] > 0.5 > row["butterworth_sigma_cut"]
