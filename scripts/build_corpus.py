"""The many-people training corpus: public motion-capture collections, each take in a folder per
performer (what data.split_by folder and val_patterns hold out), mapped onto the shipped models'
21 joints (body21) at 30 fps, written as one compact archive (positions to the millimetre, ~17 MB
for 4.6 h of motion) that training reads with --data.source archive and that travels to a GPU.
Human3.6M's exponential-map files (--h36m) add its training subjects (S1, S5, S6, S7, S8, the
paper's); S9 and S11, its test subjects, are never read. Its 17 joints have no clavicles or toes:
those are missing (NaN) in its takes, so training scores them nowhere there.

The collections come from public repositories you clone yourself (docs/data.md says where, with
their licences); nothing is downloaded here and nothing is committed. Bandai Namco takes that are
in ../shared/data/bandai-namco's val or test split (seeded hash, seed 0, 10 % / 10 %) are left
out, so the Bandai test table stays a table of takes the model never saw.

    python scripts/build_corpus.py --bandai ~/Bandai-Namco-Research-Motiondataset \\
        --reactidle ~/ReActIdle --cmu ~/PFNN-Project/animations --out .device_data/corpus_body21.npz \\
        [--h36m ~/DMGNN/data/h3.6m/dataset]
"""

from __future__ import annotations

import argparse
import re
import tempfile
import time
from pathlib import Path

from mocapfix.data.datamodule import MotionDataModule
from mocapfix.data.windows import save_clips, split_of

SHARED_BANDAI = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai-namco"
# CMU subjects kept for checks (never trained, tuned or chosen on), and the stranger benchmark's
CMU_NEVER = {"01", "02", "03", "05", "06", "07", "08", "09"}
# Human3.6M's training subjects (the XMAE paper's protocol tests on S9 and S11)
H36M_TRAIN = ("S1", "S5", "S6", "S7", "S8")


def performer_folders(args, root: Path) -> int:
    """Links to every take under root/<performer>/; returns how many."""
    n = 0

    def link(src: Path, performer: str) -> None:
        nonlocal n
        (root / performer).mkdir(exist_ok=True)
        (root / performer / src.name).symlink_to(src.resolve())
        n += 1

    if args.bandai:
        held = {f.name for f in SHARED_BANDAI.rglob("*.bvh") if split_of(str(f), 0.1, 0.1, 0) != "train"}
        for f in sorted(Path(args.bandai).rglob("*.bvh")):
            if f.name not in held:  # Bandai's files do not name the actor: one folder per dataset
                link(f, "bandai" + ("1" if "dataset-1" in f.name else "2"))
    if args.reactidle:
        for f in sorted(Path(args.reactidle).rglob("*.bvh")):  # 000_acted.bvh: person 000
            link(f, "reactidle" + f.name.split("_")[0])
    if args.cmu:
        for f in sorted(Path(args.cmu).rglob("*.bvh")):  # 35_01.bvh: subject 35
            subject = re.match(r"(\d+)_", f.name)
            if subject and subject.group(1).zfill(2) not in CMU_NEVER:
                link(f, "cmu" + subject.group(1))
    return n


def h36m_folders(h36m: str, root: Path) -> int:
    """Links to the training subjects' exponential-map files under root/h36m_s<k>/; returns how many."""
    n = 0
    for subject in H36M_TRAIN:
        files = sorted((Path(h36m) / subject).glob("*.txt"))
        if files:
            (root / f"h36m_{subject.lower()}").mkdir()
        for f in files:
            (root / f"h36m_{subject.lower()}" / f.name).symlink_to(f.resolve())
            n += 1
    return n


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bandai", help="a clone of BandaiNamcoResearchInc/Bandai-Namco-Research-Motiondataset")
    ap.add_argument("--reactidle", help="a clone of Enekoassets/ReActIdle")
    ap.add_argument("--cmu", help="CMU takes named <subject>_<take>.bvh (e.g. CeciliaZ030/PFNN-Project/animations)")
    ap.add_argument("--h36m", help="Human3.6M's exponential maps, S<k>/<name>.txt (DMGNN's data/h3.6m/dataset)")
    ap.add_argument("--out", default=".device_data/corpus_body21.npz")
    ap.add_argument("--cache-dir", default=".cache/mocapfix")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        root, h36m_root = Path(tmp) / "bvh", Path(tmp) / "h36m"
        root.mkdir()
        h36m_root.mkdir()
        found = (performer_folders(args, root), h36m_folders(args.h36m, h36m_root) if args.h36m else 0)
        if not sum(found):
            raise SystemExit("no takes found: give --bandai, --reactidle, --cmu and/or --h36m")
        t0 = time.perf_counter()
        clips = []
        for source, folder, count in (("bvh", root, found[0]), ("h36m", h36m_root, found[1])):
            if count:
                path = sorted(str(p) for p in folder.iterdir())
                dm = MotionDataModule(source=source, path=path, body="body21", fps=30, cache_dir=args.cache_dir)
                clips += dm.load_clips()
        # sources as corpus/<performer>/<file>, not the temporary path (nor an earlier run's, which
        # the cache keeps): patterns such as "*/cmu39/*" (val_patterns, source_weights) and
        # split_by folder read them
        clips = [c.replace(source=str(Path("corpus", *Path(c.source).parts[-2:]))) for c in clips]
    out = Path(args.out)
    save_clips(out, clips, compact=True)
    frames = sum(c.num_frames for c in clips)
    print(
        f"{len(clips)} takes, {frames / 30 / 3600:.2f} h at 30 fps, parsed in {time.perf_counter() - t0:.0f} s -> "
        f"{out} ({out.stat().st_size / 1e6:.1f} MB)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
