"""How many operations one Motion-DVAE prior training step runs, by part.

On a GPU the prior's step is bound by launching kernels, not by arithmetic (benchmark 4: 100 ms a
step on an H100 for a few ms of matrix work), so the number of operations is what to cut. This
counts them with torch.profiler on the CPU: ATen operations that do work (leaves of the call
tree; views, allocations and reshapes left out), per part of the step. Eager CUDA runs about one
kernel per counted operation (cuDNN's LSTM and the fused LSTM cell run fewer than the CPU
decomposition counted here; the optimiser is one foreach group on CUDA, so it is listed apart).

    python bench/dvae_op_count.py                     # paper sizes do not change the count
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter

import torch
from common import describe, print_table, write_result
from torch.profiler import ProfilerActivity, profile, record_function

from mocapfix.data.datamodule import MotionDataModule  # noqa: E402
from mocapfix.training.dvae_module import MotionDVAEModule  # noqa: E402

NOT_WORK = {
    "view",
    "reshape",
    "select",
    "slice",
    "unsqueeze",
    "squeeze",
    "t",
    "transpose",
    "expand",
    "as_strided",
    "permute",
    "_reshape_alias",
    "alias",
    "detach",
    "unbind",
    "split",
    "chunk",
    "narrow",
    "flatten",
    "contiguous",
    "empty",
    "empty_like",
    "empty_strided",
    "resolve_conj",
    "resolve_neg",
    "lift_fresh",
    "_unsafe_view",
    "view_as",
    "result_type",
}
PARTS = ("state", "encoder", "generative", "body model", "rest of the loss", "backward", "optimiser")


def _labelled(fn, label):
    def wrapped(*args, **kwargs):
        with record_function(label):
            return fn(*args, **kwargs)

    return wrapped


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument(
        "--lstm-hidden", type=int, default=64, help="width of LSTMs and MLPs (the count does not depend on it)"
    )
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    torch.manual_seed(0)
    dm = MotionDataModule(
        source="synthetic",
        with_rotations=True,
        fps=30,
        window_s=1.0,
        stride_s=0.5,
        synthetic_clips=16,
        cache_dir=None,
        val_fraction=0.0,
        test_fraction=0.0,
    )
    dm.setup("fit")
    model = MotionDVAEModule(
        state="rotations",
        body_model="skeleton",
        lstm_hidden=args.lstm_hidden,
        mlp_hidden=args.lstm_hidden,
        skeleton=dm.skeleton.to_dict(),
        window_fps=30.0,
        window_frames=dm.window_frames,
    )
    net = model.net
    net.enc.forward = _labelled(net.enc.forward, "P:encoder")
    net.gen.forward = _labelled(net.gen.forward, "P:generative")
    model.codec.points = _labelled(model.codec.points, "P:body model")
    opt = model.configure_optimizers()["optimizer"]  # the module's own (Adamax by default)
    batch = dm.datasets["train"].__getitems__(list(range(args.batch)))

    def step():
        with record_function("P:state"):
            x, shape = model.encode_batch(batch)
        with record_function("P:rest of the loss"):
            terms, _, _ = model.elbo_terms(x, shape)
            loss = terms.rec + terms.kl + terms.reg
        with record_function("P:backward"):
            opt.zero_grad()
            loss.backward()
        with record_function("P:optimiser"):
            opt.step()

    step()  # first-call work (lazy initialisation) stays out of the count
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        step()

    def part(event):
        while event is not None:
            if event.name.startswith("P:"):
                return event.name[2:]
            event = event.cpu_parent
        return "backward"  # autograd's engine runs outside the Python-side labels

    counts = Counter()
    for e in prof.events():
        name = e.name.removeprefix("aten::")
        if (
            e.name.startswith("aten::")
            and name not in NOT_WORK
            and not any(c.name.startswith("aten::") for c in e.cpu_children)
        ):
            counts[part(e)] += 1
    rows = [{"part": p, "ops": counts[p]} for p in PARTS]
    rows.append({"part": "total without the optimiser", "ops": sum(counts[p] for p in PARTS if p != "optimiser")})
    result = {
        "benchmark": "dvae_op_count",
        "env": describe(torch.device("cpu")),
        "command": " ".join(sys.argv),
        "torch": torch.__version__,
        "batch": args.batch,
        "frames": dm.window_frames,
        "joints": dm.skeleton.num_joints,
        "rows": rows,
    }
    path = write_result("dvae_op_count", result, args.json_out)
    print_table(
        f"Motion-DVAE prior training step, operations by part ({dm.skeleton.num_joints} joints, "
        f"{dm.window_frames} frames, batch {args.batch})",
        rows,
        [("part", "part"), ("ops", "operations")],
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
