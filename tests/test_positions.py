"""Positions files (.npz, .csv): layouts, units, axes, skeletons, missing data and round trips."""

import numpy as np
import pytest

from mocapfix.core.clip import MotionFileError
from mocapfix.core.skeleton import PRESETS
from mocapfix.io import read_motion
from mocapfix.io.positions import from_z_up, read_positions, to_z_up, write_clips, write_positions

H36M = PRESETS["h36m17"]
CHAIN_PARENTS = [-1, 0, 1, 1]  # root, spine, left_arm, right_arm


# A standing adult on the h36m17 skeleton (metres, z up): the readers measure the body for the unit.
_STANDING = np.array(
    [
        [0, 0, 1.0],
        [-0.13, 0, 1.0],
        [-0.13, 0, 0.55],
        [-0.13, 0, 0.1],
        [0.13, 0, 1.0],
        [0.13, 0, 0.55],
        [0.13, 0, 0.1],
        [0, 0, 1.23],
        [0, 0, 1.48],
        [0, -0.05, 1.58],
        [0, 0, 1.7],
        [0.17, 0, 1.45],
        [0.17, 0, 1.17],
        [0.17, 0, 0.92],
        [-0.17, 0, 1.45],
        [-0.17, 0, 1.17],
        [-0.17, 0, 0.92],
    ]
)


def _motion(P=2, T=6, J=17, seed=0):
    """(P, T, J, 3) a standing body with 2 cm of noise per coordinate, moved per person."""
    rng = np.random.default_rng(seed)
    pos = _STANDING[None, None, :J] + rng.normal(scale=0.02, size=(P, T, J, 3))
    pos[..., :2] += rng.normal(size=(P, 1, 1, 2))
    return pos.astype(np.float32)


def test_npz_single_person_preset_by_names(tmp_path):
    pos = _motion(P=1)[0]
    f = tmp_path / "take.npz"
    np.savez(f, positions=pos, fps=50, joint_names=np.array(H36M.joint_names))
    [clip] = read_positions(f)
    assert clip.skeleton == H36M  # names alone pick the preset, with its limb groups
    assert clip.name == "take" and clip.fps == 50.0 and clip.source == str(f)
    np.testing.assert_array_equal(clip.positions, pos)
    assert clip.meta["format"] == "positions-npz" and clip.meta["people"] == 1 and clip.meta["person"] == 0
    assert clip.meta["unit"] == "m" and clip.meta["up_axis"] == "z" and clip.meta["squeeze"] is True


def test_npz_people_mm_y_up(tmp_path):
    """(P, T, J, 3) in mm, y up -> P clips in metres, z up: y becomes z and z becomes -y."""
    raw = np.zeros((3, 2, 4, 3))
    raw[:, :, :, 1] = 1000.0 * np.arange(4)[None, None, :]  # height along y, mm
    raw[1, 0, 2] = [100.0, 2000.0, 300.0]
    f = tmp_path / "track.npz"
    np.savez(f, positions=raw, fps=np.float64(25), parents=np.array(CHAIN_PARENTS), unit="mm", up_axis="y")
    clips = read_positions(f)
    assert [c.name for c in clips] == ["track#p0", "track#p1", "track#p2"]
    assert [c.meta["person"] for c in clips] == [0, 1, 2] and all(c.meta["people"] == 3 for c in clips)
    np.testing.assert_allclose(clips[1].positions[0, 2], [0.1, -0.3, 2.0], atol=1e-6)
    np.testing.assert_allclose(clips[0].positions[1, :, 2], [0.0, 1.0, 2.0, 3.0], atol=1e-6)
    assert clips[0].skeleton.joint_names == ("joint0", "joint1", "joint2", "joint3")
    assert clips[0].meta["unit"] == "mm" and clips[0].meta["unit_source"] == "file"


@pytest.mark.parametrize("up", ["y", "-y", "-z"])
def test_axis_conversion_is_a_rotation_and_inverts(up):
    x = np.random.default_rng(1).normal(size=(10, 3))
    z = to_z_up(x, up)
    np.testing.assert_allclose(np.linalg.norm(z, axis=-1), np.linalg.norm(x, axis=-1))
    np.testing.assert_allclose(np.cross(z[0], z[1]), to_z_up(np.cross(x[0], x[1])[None], up)[0])  # det +1
    np.testing.assert_array_equal(from_z_up(z, up), x)
    axis = {"y": 1, "-y": 1, "-z": 2}[up]
    sign = -1.0 if up.startswith("-") else 1.0
    np.testing.assert_array_equal(to_z_up(np.eye(3)[axis] * sign, up), [0.0, 0.0, 1.0])  # up is up


@pytest.mark.parametrize("unit,scale", [("mm", 1000.0), ("cm", 100.0), ("m", 1.0)])
def test_unit_guessed_when_the_file_has_none(tmp_path, unit, scale):
    pos = _motion(P=1)[0] * scale
    f = tmp_path / "x.npz"
    np.savez(f, positions=pos, fps=30, parents=np.array(H36M.parents))
    [clip] = read_positions(f)
    assert clip.meta["unit"] == unit and clip.meta["unit_source"].startswith("auto")
    np.testing.assert_allclose(clip.positions, pos / scale, rtol=1e-5, atol=1e-6)
    # an explicit option wins over the guess
    [clip] = read_positions(f, unit="cm")
    assert clip.meta["unit"] == "cm" and clip.meta["unit_source"] == "option"


def test_names_without_parents_must_match_a_preset(tmp_path):
    f = tmp_path / "x.npz"
    np.savez(f, positions=_motion(P=1, J=4)[0], fps=30, joint_names=np.array(["a", "b", "c", "d"]))
    with pytest.raises(MotionFileError, match="match no preset"):
        read_positions(f)
    np.savez(f, positions=_motion(P=1, J=4)[0], fps=30)
    with pytest.raises(MotionFileError, match="parents and/or joint_names"):
        read_positions(f)


def test_custom_names_get_guessed_groups_and_groups_option(tmp_path):
    names = ["Hips", "Spine", "LeftArm", "RightArm"]
    f = tmp_path / "x.npz"
    np.savez(f, positions=_motion(P=1, J=4)[0], fps=30, joint_names=np.array(names), parents=np.array(CHAIN_PARENTS))
    [clip] = read_positions(f)
    assert clip.skeleton.groups == {"left_arm": (2,), "right_arm": (3,)}
    [clip] = read_motion(f, groups={"left_arm": ["LeftArm", "Spine"]})
    assert clip.skeleton.groups == {"left_arm": (2, 1)}


def test_all_missing_person_is_still_a_clip(tmp_path):
    pos = _motion(P=2)
    pos[1] = np.nan
    f = tmp_path / "x.npz"
    np.savez(f, positions=pos, fps=30, joint_names=np.array(H36M.joint_names))
    clips = read_positions(f)
    assert len(clips) == 2 and clips[1].missing_mask().all() and not clips[0].missing_mask().any()


def test_csv_hand_written(tmp_path):
    """Comments, header, a missing frame (2), an empty cell and 'nan': all become missing joints."""
    f = tmp_path / "cam.csv"
    f.write_text(
        "# exported by some tracker\n"
        "# unit=cm up_axis=z\n"
        "# parents=-1,0,1,1\n"
        "frame,time,Hips_x,Hips_y,Hips_z,Spine_x,Spine_y,Spine_z,LeftArm_x,LeftArm_y,LeftArm_z,"
        "RightArm_x,RightArm_y,RightArm_z\n"
        "10,0.0,0,0,90,0,0,120,10,0,140,-10,0,140\n"
        "11,0.04,1,0,90,1,0,120,11,,140,-9,0,140\n"
        "13,0.12,3,0,90,3,0,120,13,0,140,nan,nan,nan\n"
    )
    [clip] = read_positions(f)
    assert clip.fps == pytest.approx(25.0)  # from the time column
    assert clip.num_frames == 4 and clip.meta["first_frame"] == 10
    assert clip.meta["format"] == "positions-csv" and clip.meta["unit"] == "cm"
    missing = clip.missing_mask()
    assert missing[2].all()  # frame 12 has no row
    assert missing[1].tolist() == [False, False, True, False]
    assert missing[3].tolist() == [False, False, False, True]
    np.testing.assert_allclose(clip.positions[0, 1], [0.0, 0.0, 1.2], atol=1e-6)
    assert clip.skeleton.joint_names == ("Hips", "Spine", "LeftArm", "RightArm")


def test_csv_without_frame_column_and_fps_comment(tmp_path):
    f = tmp_path / "c.csv"
    f.write_text(
        "# fps=60 parents=-1,0\nperson,Hip_x,Hip_y,Hip_z,Knee_x,Knee_y,Knee_z\n"
        "b,0,0,1,0,0,0.5\na,5,0,1,5,0,0.5\nb,1,0,1,1,0,0.5\n"
    )
    clips = read_positions(f, fps=None, unit="m")
    assert [c.meta["person_id"] for c in clips] == ["a", "b"] and [c.name for c in clips] == ["c#p0", "c#p1"]
    assert clips[0].fps == 60.0 and clips[0].num_frames == 2 and clips[1].num_frames == 2
    assert clips[0].missing_mask()[1].all()  # person a has one row only
    np.testing.assert_allclose(clips[1].positions[:, 0, 0], [0.0, 1.0])


def test_csv_needs_fps(tmp_path):
    f = tmp_path / "c.csv"
    f.write_text("# parents=-1\nframe,Hip_x,Hip_y,Hip_z\n0,0,0,1\n")
    with pytest.raises(MotionFileError, match="fps"):
        read_positions(f)
    assert read_positions(f, fps=30)[0].fps == 30.0


@pytest.mark.parametrize("ext", ["npz", "csv"])
@pytest.mark.parametrize("unit,up", [("m", "z"), ("mm", "y"), ("cm", "z"), ("m", "-y")])
def test_round_trip_in_the_input_layout(tmp_path, ext, unit, up):
    pos = _motion(P=2, T=5)
    pos[0, 1, 3] = np.nan
    pos[1, 4] = np.nan
    f = tmp_path / f"a.{ext}"
    write_positions(f, pos, 30, H36M, unit=unit, up_axis=up)
    clips = read_positions(f)
    assert [c.meta["unit"] for c in clips] == [unit] * 2 and clips[0].meta["up_axis"] == up
    back = np.stack([c.positions for c in clips])
    assert np.array_equal(np.isnan(back), np.isnan(pos))
    np.testing.assert_allclose(back, pos, atol=1e-6, rtol=1e-6)
    # write what was read: same layout, same numbers; csv text identical
    g = tmp_path / f"b.{ext}"
    write_clips(g, clips)
    again = read_positions(g)
    assert [c.meta for c in again] == [c.meta for c in clips]
    if ext == "csv":  # 9 digits of the converted value read back as the same float32
        np.testing.assert_array_equal(np.stack([c.positions for c in again]), back)
        assert g.read_text() == f.read_text()
    else:  # float32 in the file's unit: a unit conversion may move the last bit
        np.testing.assert_allclose(np.stack([c.positions for c in again]), back, rtol=3e-7, atol=1e-7)


@pytest.mark.parametrize("save", [np.savez, np.savez_compressed])
def test_an_npz_is_written_back_deflated_or_stored_as_it_was_read(tmp_path, save):
    """A folder of np.savez takes is fixed into np.savez files (deflating float32 positions costs
    14x the write for a fifth of the size: the user chose the other side of that)."""
    import zipfile

    save(tmp_path / "a.npz", positions=_motion(P=1)[0], fps=np.float64(30), joint_names=np.array(H36M.joint_names))
    write_clips(tmp_path / "b.npz", read_positions(tmp_path / "a.npz"))
    with zipfile.ZipFile(tmp_path / "b.npz") as z:
        kinds = {member.compress_type for member in z.infolist()}
    assert kinds == ({zipfile.ZIP_STORED} if save is np.savez else {zipfile.ZIP_DEFLATED})


def test_write_keeps_single_person_squeezed_and_csv_ids(tmp_path):
    f = tmp_path / "one.npz"
    write_positions(f, _motion(P=1)[0], 30, H36M)
    with np.load(f) as z:
        assert z["positions"].shape == (6, 17, 3) and str(z["unit"]) == "m"
    c = tmp_path / "two.csv"
    c.write_text("# fps=30 parents=-1,0\nperson,frame,A_x,A_y,A_z,B_x,B_y,B_z\n7,3,0,0,1,0,0,0\n12,4,1,1,1,0,0,0\n")
    clips = read_positions(c)
    out = tmp_path / "out.csv"
    write_clips(out, clips)
    lines = out.read_text().splitlines()
    assert lines[2] == "person,frame,A_x,A_y,A_z,B_x,B_y,B_z"  # no time column in, none out
    assert [ln.split(",")[:2] for ln in lines[3:]] == [["7", "3"], ["7", "4"], ["12", "3"], ["12", "4"]]


def test_atomic_write_leaves_the_old_file_on_failure(tmp_path, monkeypatch):
    f = tmp_path / "a.npz"
    write_positions(f, _motion(P=1)[0], 30, H36M)
    before = f.read_bytes()

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", boom)
    with pytest.raises(OSError):
        write_positions(f, _motion(P=1, seed=3)[0], 30, H36M)
    assert f.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz"]  # no temp file left


def _chain_csv(path, frames, times, comment="# parents=-1,0,1,1 unit=m\n"):
    """A 4-joint csv with the given frame numbers (None: no frame column) and time cells (text)."""
    head = (
        ("frame," if frames is not None else "")
        + "time,"
        + ",".join(f"{n}_{a}" for n in ("Hips", "Spine", "LeftArm", "RightArm") for a in "xyz")
    )
    rows = []
    for k, t in enumerate(times):
        xyz = [round(0.01 * k, 4), 0, 0.9, 0, 0, 1.2, 0.1, 0, 1.4, -0.1, 0, 1.4]
        rows.append(([str(frames[k])] if frames is not None else []) + [t] + [repr(v) for v in xyz])
    path.write_text(comment + head + "\n" + "\n".join(",".join(r) for r in rows) + "\n")
    return path


def _written_times(path) -> list[str]:
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    col = lines[0].split(",").index("time")
    return [ln.split(",")[col] for ln in lines[1:]]


def test_csv_keeps_its_times_through_the_fix_writer(tmp_path):
    """Frame numbers from 100 with times from 0: `fix` writes the input's times, not (100 + t) / fps;
    a skipped frame (103) gets a time between its neighbours'."""
    from mocapfix.fix.output import write_output  # what `fix` writes its output with

    frames = [100, 101, 102, 104, 105]
    times = ["0.000", "0.033", "0.067", "0.133", "0.167"]
    f = _chain_csv(tmp_path / "take.csv", frames, times)
    clips = read_positions(f)
    assert clips[0].meta["first_frame"] == 100 and clips[0].num_frames == 6
    out = tmp_path / "take.fixed.csv"
    write_output(out, clips, clips, f)
    written = _written_times(out)
    assert [float(t) for t in written] == [0.0, 0.033, 0.067, 0.1, 0.133, 0.167]  # 103: midway, linear
    assert [written[i] for i in (0, 1, 2, 4, 5)] == ["0", "0.033", "0.067", "0.133", "0.167"]
    again = read_positions(out)
    assert again[0].meta["times"] == clips[0].meta["times"]
    np.testing.assert_array_equal(again[0].positions, clips[0].positions)


def test_csv_unix_times_and_per_person_times_survive_write_clips(tmp_path):
    times = [f"{1700000000 + k / 30:.4f}" for k in range(40)]
    f = _chain_csv(tmp_path / "unix.csv", None, times)
    [clip] = read_positions(f)
    assert clip.fps == 30.0
    out = write_clips(tmp_path / "out.csv", [clip])
    assert [float(t) for t in _written_times(out)] == [float(t) for t in times]
    # two people: each row keeps its own time; a frame one person lacks takes the other's
    c = tmp_path / "two.csv"
    c.write_text(
        "# fps=30 parents=-1\nperson,frame,time,A_x,A_y,A_z\n"
        "a,0,10.5,0,0,1\na,1,10.533,0,0,1\nb,0,10.501,1,0,1\nb,2,10.567,1,0,1\n"
    )
    clips = read_positions(c)
    out = write_clips(tmp_path / "two_out.csv", clips)
    assert _written_times(out) == ["10.5", "10.533", "10.567", "10.501", "10.533", "10.567"]


@pytest.mark.parametrize("seconds", [2.0, 10.0])
@pytest.mark.parametrize("frame_column", [False, True])
def test_fps_from_millisecond_times(tmp_path, seconds, frame_column):
    """30 fps times rounded to ms (0.033, 0.067, 0.100, ...): 30, not 1 / 0.033 = 30.3."""
    n = int(seconds * 30)
    times = [f"{k / 30:.3f}" for k in range(n)]
    [clip] = read_positions(_chain_csv(tmp_path / "ms.csv", list(range(n)) if frame_column else None, times))
    assert abs(clip.fps - 30.0) < 0.01
    assert clip.fps == 30.0  # and snapped: the ms rounding cannot tell it from 30


@pytest.mark.parametrize("frame_column", [False, True])
def test_fps_with_a_dropped_frame(tmp_path, frame_column):
    keep = [k for k in range(60) if k != 17]  # one step twice as long
    times = [f"{k / 30:.3f}" for k in keep]
    [clip] = read_positions(_chain_csv(tmp_path / "drop.csv", keep if frame_column else None, times))
    assert clip.fps == 30.0
    assert clip.num_frames == (60 if frame_column else 59)


def test_fps_from_times_keeps_exact_rates(tmp_path):
    for fps in (25.0, 29.97, 50.0):
        times = [repr(k / fps) for k in range(90)]
        [clip] = read_positions(_chain_csv(tmp_path / "x.csv", None, times))
        assert clip.fps == pytest.approx(fps, rel=1e-9)
    with pytest.raises(MotionFileError, match="too few times"):
        read_positions(_chain_csv(tmp_path / "y.csv", None, ["0.5", "0.5", "0.5"]))


def test_csv_numbers_come_back_as_written(tmp_path):
    """Each number is written with the fewest digits that read back as the same float32 metres."""
    c = tmp_path / "cm.csv"
    c.write_text(
        "# fps=30 parents=-1,0 unit=cm up_axis=y\nA_x,A_y,A_z,B_x,B_y,B_z\n"
        "-13.7228,90,0.1,1234.567,4.5,3\n0.333333,-0.5,7,1e-05,,3\n"
    )
    clips = read_positions(c)
    out = write_clips(tmp_path / "out.csv", clips)
    rows = [ln.split(",") for ln in out.read_text().splitlines()[3:]]
    assert rows == [["-13.7228", "90", "0.1", "1234.567", "4.5", "3"], ["0.333333", "-0.5", "7", "", "", ""]]
    np.testing.assert_array_equal(read_positions(out)[0].positions, clips[0].positions)
    # any float32 metres (a model's estimate): read back bit for bit, in every unit and axis
    pos = np.random.default_rng(5).normal(size=(50, 17, 3)).astype(np.float32)
    for unit, up in (("m", "z"), ("mm", "y"), ("cm", "z")):
        write_positions(tmp_path / "r.csv", pos, 30, H36M, unit=unit, up_axis=up)
        np.testing.assert_array_equal(read_positions(tmp_path / "r.csv")[0].positions, pos)


def test_written_files_get_the_usual_mode(tmp_path):
    """Outputs are readable as any file the user writes (0666 less the umask), not mkstemp's private 0600."""
    import os

    mask = os.umask(0o022)
    os.umask(mask)
    out = write_positions(tmp_path / "out.npz", np.zeros((2, 17, 3)), 30, H36M)
    assert out.stat().st_mode & 0o777 == 0o666 & ~mask
