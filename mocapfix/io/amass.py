"""AMASS (.npz of SMPL-family parameters) -> joint positions through the user's body model.

An AMASS file holds poses (T, 156) axis-angles [root 3 | body 63 | hands 90] (72 for SMPL,
165 for SMPL-X), trans (T, 3), betas, gender and mocap_framerate (mocap_frame_rate in the SMPL-X
release). Already metres, z up.

Only the first 22 joints (pelvis + 21 body joints, preset smpl22) are kept. Their positions
do not depend on pose blend shapes or hands: SMPL regresses the rest joints from the shaped
template, J_rest = J_regressor (v_template + shapedirs betas), and poses them by plain forward
kinematics. So the clip carries the exact rotation form: rotations = the 22 axis-angles,
offsets[j] = J_rest[j] - J_rest[parent[j]], root_translation = trans + J_rest[0] (smplx adds
trans to every joint, and the rest pelvis is not at the origin).

The model files are the user's (licensed; never shipped). smplx (pip install 'mocapfix[smpl]')
does the body-model math; we read the model file ourselves because smplx's classes keep at
most 10 betas of a model with fewer than 300 shape components (AMASS uses 16) and print to
stdout.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.skeleton import PRESETS
from mocapfix.io.npz import load_npz, npz_array, npz_object, one_line
from mocapfix.io.restricted_pickle import RefusedPickle, load_arrays
from mocapfix.io.untrusted import open_regular, quoted

NUM_BODY_JOINTS = 22
# Standard AMASS split (sub-dataset folder names; newer releases renamed some: both listed).
AMASS_SPLIT = {
    "train": [
        "CMU",
        "MPI_Limits",
        "PosePrior",
        "TotalCapture",
        "Eyes_Japan_Dataset",
        "KIT",
        "BioMotionLab_NTroje",
        "BMLrub",
        "BMLmovi",
        "EKUT",
        "ACCAD",
    ],
    "val": ["MPI_HDM05", "HDM05", "SFU", "MPI_mosh", "MoSh"],
    "test": ["Transitions_mocap", "Transitions", "HumanEva"],
}


def amass_split_of(path) -> str | None:
    """ "train" / "val" / "test" from the AMASS sub-dataset folder in the path, None if none matches."""
    parts = set(Path(path).parts)
    for split, names in AMASS_SPLIT.items():
        if parts & set(names):
            return split
    return None


def _import_smplx(path):
    try:
        import smplx  # optional extra: heavy (torch) and only needed for AMASS
    except ImportError:
        raise MotionFileError(path, "reading AMASS needs the smplx package: pip install 'mocapfix[smpl]'") from None
    return smplx


def _str(a) -> str:
    v = np.asarray(a).reshape(-1)[0] if np.asarray(a).size else ""
    return (v.decode() if isinstance(v, bytes) else str(v)).strip().lower()


def _npz_str(path: Path, data, key: str) -> str | None:
    if key not in data.files:
        return None
    try:
        return _str(data[key])
    except ValueError:
        # Some AMASS releases pickled the gender string: an object array, read without running it.
        return _str(npz_object(path, key))


def find_body_model(body_model_path, model_type: str, gender: str) -> Path:
    """A model file, or a folder in the smplx layout (smplh/SMPLH_MALE.pkl) or the AMASS one
    (smplh/male/model.npz) -> the model file for model_type and gender."""
    root = Path(body_model_path).expanduser()
    if root.is_file():
        return root
    if not root.is_dir():
        raise MotionFileError(root, "body model path does not exist")
    t, T, g, G = model_type.lower(), model_type.upper(), gender.lower(), gender.upper()
    names = [
        f"{t}/{T}_{G}.pkl",
        f"{t}/{T}_{G}.npz",
        f"{T}_{G}.pkl",
        f"{T}_{G}.npz",
        f"{t}/{g}/model.npz",
        f"{g}/model.npz",
        f"{t}/{g}/model.pkl",
        f"{g}/model.pkl",
    ]
    for n in names:
        if (root / n).is_file():
            return root / n
    raise MotionFileError(root, f"no {T} model for gender {g!r} (looked for {', '.join(names)})")


def read_model_arrays(model_file: Path, keys: tuple[str, ...]) -> dict:
    """The arrays `keys` (those present) of an SMPL-family model file, .npz or .pkl, read without
    running code from it (io/restricted_pickle.py): a model file is a dict of arrays, and one
    that imports anything else (the chumpy objects of the official SMPL pickles, or a payload)
    is a MotionFileError saying so."""
    model_file = Path(model_file)
    if model_file.suffix.lower() == ".npz":
        with load_npz(model_file) as z:
            present = [k for k in keys if k in z.files]
        return {k: npz_object(model_file, k, encoding="latin1") for k in present}
    try:
        with open_regular(model_file, "body model file") as f:
            raw = load_arrays(f, encoding="latin1")  # the official SMPL pickles are Python 2's
    except RefusedPickle as e:
        chumpy = "chumpy" in str(e)
        hint = " (the official SMPL pickles hold chumpy arrays: convert the model to .npz)" if chumpy else ""
        raise MotionFileError(
            model_file,
            f"a pickle that imports {quoted(str(e), 80)}, not a dict of arrays: refused, nothing was run{hint}",
        ) from None
    except MotionFileError:
        raise
    except Exception as e:
        raise MotionFileError(model_file, f"not a readable body model ({one_line(e)})") from None
    if not isinstance(raw, dict):
        raise MotionFileError(model_file, "not an SMPL-family model (not a dict of arrays)")
    return {k: raw[k] for k in keys if k in raw}


def load_body_model(model_file: Path) -> dict:
    """SMPL-family model file (.pkl or .npz) -> numpy arrays v_template (V, 3), shapedirs (V, 3, B),
    J_regressor (J, V), parents (J,)."""
    raw = read_model_arrays(model_file, ("v_template", "shapedirs", "J_regressor", "kintree_table"))
    missing = [k for k in ("v_template", "shapedirs", "J_regressor", "kintree_table") if k not in raw]
    if missing:
        raise MotionFileError(model_file, f"not an SMPL-family model: no {', '.join(missing)}")
    J_regressor = raw["J_regressor"]
    if hasattr(J_regressor, "toarray"):  # scipy.sparse in the official SMPL pickles
        J_regressor = J_regressor.toarray()
    out = {
        "v_template": np.asarray(raw["v_template"], dtype=np.float64),
        "shapedirs": np.asarray(raw["shapedirs"], dtype=np.float64),
        "J_regressor": np.asarray(J_regressor, dtype=np.float64),
    }
    parents = np.asarray(raw["kintree_table"])[0].astype(np.int64)
    parents[0] = -1  # stored as 2**32 - 1
    out["parents"] = parents
    V = out["v_template"].shape[0]
    if (
        out["shapedirs"].ndim != 3
        or out["shapedirs"].shape[:2] != (V, 3)
        or out["J_regressor"].shape[1] != V
        or out["J_regressor"].shape[0] != len(parents)
    ):
        raise MotionFileError(model_file, "inconsistent body model arrays")
    if len(parents) < NUM_BODY_JOINTS or tuple(parents[:NUM_BODY_JOINTS]) != PRESETS["smpl22"].parents:
        raise MotionFileError(model_file, "not an SMPL-family model: its first 22 joints are not the SMPL body tree")
    return out


def _body_shape(path, betas: np.ndarray) -> np.ndarray:
    """betas as one (B,) vector. Some exports repeat it on every frame, (T, B): one body shape
    still, as long as the rows agree (flattening would read row 0 plus part of row 1)."""
    if betas.dtype.kind not in "iuf":
        raise MotionFileError(path, f"betas must be numbers, got dtype {betas.dtype}")
    if betas.ndim == 2 and len(betas) > 1:
        if not np.allclose(betas, betas[:1], rtol=0, atol=1e-6, equal_nan=True):
            raise MotionFileError(
                path, f"betas {betas.shape} change from frame to frame: one body shape per file is supported"
            )
        betas = betas[:1]
    if betas.ndim > 2 or betas.size == 0:
        raise MotionFileError(path, f"betas must be (B,) or (frames, B), got {betas.shape}")
    betas = betas.astype(np.float64).reshape(-1)
    if not np.isfinite(betas).all():
        raise MotionFileError(path, "betas (body shape) are not all finite")
    return betas


def read_amass(path, body_model_path: str | None = None, gender: str | None = None, groups=None) -> list[Clip]:
    """AMASS .npz -> one Clip (22 joints, metres, z up) with the rotations that reproduce it.

    body_model_path: an SMPL(-H/-X) model file or a folder of them (smplx layout
    smplh/SMPLH_MALE.pkl, or AMASS's smplh/male/model.npz); the model type follows the poses
    (72 SMPL, 156 SMPL-H, 165 SMPL-X) and the gender the file's, unless `gender` is given."""
    path = Path(path)
    if body_model_path is None:
        raise MotionFileError(
            path,
            "AMASS positions need an SMPL-H body model: give its path (--body-model "
            "for inspect and fix, data.body_model_path for training: your model file "
            "or the folder holding smplh/SMPLH_<GENDER>.pkl)",
        )
    smplx = _import_smplx(path)
    import torch  # after smplx: a clear message when the extra is missing

    with load_npz(path) as data:
        missing = [k for k in ("poses", "trans") if k not in data.files]
        if missing:
            raise MotionFileError(path, f"not an AMASS file: no {', '.join(missing)} (keys: {', '.join(data.files)})")
        poses = npz_array(path, data, "poses")
        trans = npz_array(path, data, "trans")
        rate_key = next((k for k in ("mocap_framerate", "mocap_frame_rate") if k in data.files), None)
        if rate_key is None:
            raise MotionFileError(path, "no mocap_framerate")
        fps = npz_array(path, data, rate_key)
        betas = npz_array(path, data, "betas") if "betas" in data.files else None
        file_gender = _npz_str(path, data, "gender")
        surface = _npz_str(path, data, "surface_model_type")
    if poses.dtype.kind not in "iuf":
        raise MotionFileError(path, f"poses must be numbers (axis-angle, radians), got dtype {poses.dtype}")
    if poses.ndim != 2 or poses.shape[1] < 3 * NUM_BODY_JOINTS or poses.shape[1] % 3 or poses.shape[0] == 0:
        raise MotionFileError(path, f"poses must be (frames, 3 x joints) with at least 22 joints, got {poses.shape}")
    T = poses.shape[0]
    if trans.dtype.kind not in "iuf" or trans.shape != (T, 3):
        raise MotionFileError(path, f"trans must be ({T}, 3), got {trans.shape}")
    if fps.size != 1 or fps.dtype.kind not in "iuf" or not float(fps.reshape(())) > 0:
        raise MotionFileError(
            path, f"mocap framerate must be one positive number, got {fps.dtype} of shape {fps.shape}"
        )
    if betas is None:
        raise MotionFileError(path, "no betas (body shape)")
    betas = _body_shape(path, betas)
    gender = (gender or file_gender or "").lower()
    if not gender:
        raise MotionFileError(path, "no gender in the file: pass gender= ('male', 'female' or 'neutral')")
    if not re.fullmatch(r"[a-z]{1,20}", gender):  # it becomes part of a model file's path: a word, no "../"
        raise MotionFileError(path, f"gender {quoted(gender)} is not a word such as 'male', 'female' or 'neutral'")
    model_type = (
        surface
        if surface in ("smpl", "smplh", "smplx")
        else {72: "smpl", 156: "smplh", 165: "smplx"}.get(poses.shape[1], "smplh")
    )

    model_file = find_body_model(body_model_path, model_type, gender)
    model = load_body_model(model_file)
    nb = min(len(betas), model["shapedirs"].shape[-1])

    t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    # J_rest: (J, 3) rest joints of this body shape; only the first 22 matter.
    v_shaped = t(model["v_template"])[None] + smplx.lbs.blend_shapes(
        t(betas[:nb])[None], t(model["shapedirs"][..., :nb])
    )  # (1, V, 3)
    J_rest = smplx.lbs.vertices2joints(t(model["J_regressor"]), v_shaped)[0, :NUM_BODY_JOINTS]
    aa = t(poses[:, : 3 * NUM_BODY_JOINTS]).reshape(T, NUM_BODY_JOINTS, 3)
    rotmats = smplx.lbs.batch_rodrigues(aa.reshape(-1, 3)).reshape(T, NUM_BODY_JOINTS, 3, 3)
    parents = torch.as_tensor(model["parents"][:NUM_BODY_JOINTS])
    posed, _ = smplx.lbs.batch_rigid_transform(rotmats, J_rest.expand(T, -1, -1), parents, dtype=torch.float64)
    positions = posed + t(trans)[:, None]  # (T, 22, 3)

    J_rest = J_rest.numpy()
    offsets = np.zeros_like(J_rest)  # row 0 unused by FK
    offsets[1:] = J_rest[1:] - J_rest[model["parents"][1:NUM_BODY_JOINTS]]
    skel = PRESETS["smpl22"]
    if groups:
        try:
            skel = skel.with_groups(groups)
        except (KeyError, ValueError) as e:
            raise MotionFileError(path, f"bad groups: {e}") from None
    meta = {
        "format": "amass",
        "unit": "m",
        "up_axis": "z",
        "gender": gender,
        "model_type": model_type,
        "body_model": str(model_file),
        "betas_used": nb,
        "betas_in_file": len(betas),
        "dataset": path.parent.parent.name,
        "split": amass_split_of(path),
    }
    return [
        Clip(
            positions.numpy().astype(np.float32),
            float(fps.reshape(())),
            skel,
            name=f"{path.parent.name}/{path.stem}",
            source=str(path),
            rotations=aa.numpy().astype(np.float32),
            root_translation=(np.asarray(trans, dtype=np.float64) + J_rest[0]).astype(np.float32),
            offsets=offsets.astype(np.float32),
            meta=meta,
        )
    ]
