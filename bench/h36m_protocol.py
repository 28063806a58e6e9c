"""The XMAE paper's Table 2 protocol on Human3.6M as the motion-prediction papers mirror it (the
exponential-map files, io/h36m_expmap.py), with the classical fills: is our protocol the paper's?

Full-skeleton, arm and leg infilling over a gap centred in 1-s windows at 50 Hz (non-overlapping,
as `mocapfix test` cuts the test split), 17 joints, MPJPE mm over the hidden tokens, global and
root-relative, left and right limbs averaged: the rows of evaluation/tasks.py, every classical
fill, the paper's Lerp and XMAE rows beside. The held-out subjects are a choice the paper leaves
to "the standard split" of the work it compares with: S9 S11 (3D pose, mocapfix's default) and
S5 (motion prediction) are both measured here.

    python bench/h36m_protocol.py --data /path/to/h3.6m/dataset            # ~2 min on 2 cores
    python bench/h36m_protocol.py --data ... --ckpt checkpoints/correction_h36m/last.ckpt   # its row too
    (several --ckpt: a row each, named by the fill each corrects: "correction(hermite)")
"""

from __future__ import annotations

import argparse
import time

import torch
from common import describe, write_result

from mocapfix.data.datamodule import WindowDataset
from mocapfix.evaluation.metrics import MPJPE
from mocapfix.evaluation.tasks import paper_tasks
from mocapfix.fills.classical import CLASSICAL, classical_fills
from mocapfix.fills.fill import made
from mocapfix.io import list_motion_files, read_motion
from mocapfix.models.build import build_model
from mocapfix.models.checkpoint import model_kind, network_weights, read_checkpoint, stored_config
from mocapfix.models.correction import correction_fill

GAPS_S = (0.1, 0.3, 0.5, 0.7, 0.9)
# XMAE's Table 2 (full skeleton, Human3.6M), mm at GAPS_S
PAPER = {
    ("lerp", "rel"): (2.1, 9.5, 18.5, 27.5, 35.8),
    ("xmae", "rel"): (3.9, 6.7, 11.1, 17.2, 26.5),
    ("xmae", "global"): (3.9, 6.7, 11.5, 19.1, 30.2),
}


def correction_net(path: str):
    """A learned correction's network (configs/correction_h36m.yaml), ready to fill."""
    ckpt = read_checkpoint(path)
    if model_kind(ckpt) != "correction":
        raise SystemExit(f"--ckpt {path}: not a learned correction (its kind: {model_kind(ckpt)})")
    net = build_model("correction", stored_config(path, ckpt))
    net.load_state_dict(network_weights(ckpt))
    return net.eval()


def table(clips, fps: float, nets=()) -> dict:
    """-> {(part, method, "global"|"rel"): [mm per gap]} over the clips' 1-s windows; nets:
    learned corrections, a row each ("correction(<its base fill>)")."""
    windows = WindowDataset(clips, int(round(fps)), int(round(fps)))
    positions = windows.__getitems__(list(range(len(windows))))["positions"].double()  # (B, T, J, 3)
    skeleton = clips[0].skeleton
    sums: dict[tuple, list[float]] = {}
    for t in paper_tasks(skeleton, GAPS_S, ()):
        if t.task != "infill":
            continue
        c = t.corrupt(positions, fps, skeleton, None)
        scored = t.evaluated(c, positions)
        preds = made(classical_fills(), c.positions, c.observed, fps, skeleton)
        for net in nets:
            with torch.no_grad():
                preds[f"correction({net.config.base})"] = correction_fill(net, c.positions.float(), c.observed).double()
        for method, pred in preds.items():
            for label, rel in (("global", False), ("rel", True)):
                metric = MPJPE(root_relative=rel)
                metric.update(pred, positions, scored)
                sums.setdefault((t.part.split("_")[-1], method, label, t.gap_s), []).append(float(metric.compute()))
    out: dict[tuple, list[float]] = {}
    for (part, method, label, _gap), values in sums.items():  # left and right averaged, gaps in order
        out.setdefault((part, method, label), []).append(round(sum(values) / len(values), 2))
    return {"windows": len(windows), "rows": out}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="the folder of S*/<action>_<trial>.txt files")
    ap.add_argument("--ckpt", nargs="*", default=[], help="learned corrections' checkpoints: a row each")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    files = list_motion_files(args.data, "h36m")
    clips = [c for f in files for c in read_motion(f, "h36m")]
    subjects = sorted({c.meta["subject"] for c in clips}, key=lambda s: int(s[1:]))
    counts = {s: sum(c.meta["subject"] == s for c in clips) for s in subjects}
    print(f"{len(files)} files read (" + ", ".join(f"{s} {n}" for s, n in counts.items()) + ")")
    nets = [correction_net(path) for path in args.ckpt]
    result = {"env": describe(torch.device("cpu")), "data": str(args.data), "files": len(files), "splits": {}}
    result["ckpt"] = args.ckpt
    for held_out in (("S9", "S11"), ("S5",)):
        test = [c for c in clips if c.meta["subject"] in held_out]
        if not test:
            continue
        fps = test[0].fps
        # the correction's row only on the subjects it was not trained on (configs/correction_h36m.yaml)
        measured = table(test, fps, nets if held_out == ("S9", "S11") else ())
        name = "+".join(held_out)
        result["splits"][name] = {
            "windows": measured["windows"],
            "rows": {"/".join(k): v for k, v in measured["rows"].items()},
        }
        print(f"\nheld out {name}: {len(test)} sequences, {measured['windows']} windows of 1 s at {fps:g} Hz")
        print(f"{'part':5s} {'method':20s} {'':7s}" + "".join(f"{g:>7g}" for g in GAPS_S) + "   <- gap (s), MPJPE mm")
        for part in ("full", "arm", "leg"):
            for method in (*CLASSICAL, *(f"correction({net.config.base})" for net in nets)):
                for label in ("global", "rel"):
                    row = measured["rows"].get((part, method, label))
                    if row:
                        print(f"{part:5s} {method:20s} {label:7s}" + "".join(f"{v:7.1f}" for v in row))
            if part == "full":
                for (method, label), row in PAPER.items():
                    print(f"{part:5s} {'paper ' + method:20s} {label:7s}" + "".join(f"{v:7.1f}" for v in row))
        lerp = measured["rows"][("full", "lerp", "rel")]
        ratio = [m / p for m, p in zip(lerp, PAPER[("lerp", "rel")])]
        print("Lerp rel / paper's: " + " ".join(f"{r:.2f}" for r in ratio))
        result["splits"][name]["lerp_rel_over_paper"] = [round(r, 3) for r in ratio]
    result["seconds"] = round(time.perf_counter() - t0, 1)
    print(f"\n{result['seconds']:.0f} s; written {write_result('h36m_protocol', result, args.json_out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
