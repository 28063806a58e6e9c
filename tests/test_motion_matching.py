"""The motion-matching fills (fills/motion_matching.py): a hole filled from the moments of the
library that look most like its surroundings, turned and shifted onto them."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch

from mocapfix.core.skeleton import preset
from mocapfix.data.augment import mirror_index
from mocapfix.fills.classical import hermite_infill
from mocapfix.fills.motion_matching import (
    LIBRARY_S,
    TEMPOS,
    MotionLibrary,
    _search,
    _upsampled,
    _weights,
    match_fills,
    mirrored,
    search_step,
    searchable,
    torso_of,
)

BODY = preset("body21")


def _walk(
    seconds: float, fps: float, seed: int, heading: float = 0.0, start=(0.0, 0.0), wobble: float = 0.0
) -> np.ndarray:
    """(T, 21, 3) a body that walks: joints swing on a 1.1-s cycle (each its own phase and size,
    harmonics included, so no cubic draws a cycle) while the body travels 1.2 m/s along `heading`.
    wobble: seconds the walk runs ahead of or behind its clock (on a 7.3-s cycle), so that no
    step is an exact copy of another."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(seconds * fps))[:, None, None] / fps
    t = t + wobble * np.sin(2 * np.pi * t / 7.3)
    rest = rng.normal(0, 0.3, (1, BODY.num_joints, 3)) + [0, 0, 1.0]
    size, phase = rng.uniform(0.05, 0.3, (2, 1, BODY.num_joints, 3))
    w = 2 * np.pi / 1.1
    local = rest + size * np.sin(w * t + 6 * phase) + 0.3 * size * np.sin(2 * w * t + 3 * phase)
    local[..., 0] += 1.2 * t[..., 0]
    c, s = np.cos(heading), np.sin(heading)
    out = local.copy()
    out[..., 0] = c * local[..., 0] - s * local[..., 1] + start[0]
    out[..., 1] = s * local[..., 0] + c * local[..., 1] + start[1]
    return out


def _hole(x: np.ndarray, frames: slice, joints=None) -> tuple[np.ndarray, np.ndarray]:
    holed = x.copy()
    holed[frames, slice(None) if joints is None else list(joints)] = np.nan
    return holed, np.isfinite(holed).all(-1)


def _hermite(x: np.ndarray, observed: np.ndarray) -> np.ndarray:
    return hermite_infill(torch.from_numpy(x)[None], torch.from_numpy(observed)[None])[0].numpy()


def test_the_same_motion_elsewhere_turned_and_shifted_fills_the_hole_exactly():
    """The library holds the take itself, turned 40 degrees and moved 5 m: both fills find it
    (the turn and shift come out of the closed-form alignment) and put it back exactly."""
    x = _walk(6.0, 30.0, seed=0)
    library = _walk(6.0, 30.0, seed=0, heading=0.7, start=(3.0, -4.0))
    holed, observed = _hole(x, slice(80, 107))  # 0.9 s of the whole body
    hermite = _hermite(holed, observed)
    fills = match_fills(holed, observed, hermite, library.astype(np.float32))
    hole = ~observed
    assert np.abs(hermite[hole] - x[hole]).max() > 0.05  # the cubic does not know the walk
    for name, fill in fills.items():
        assert np.abs(fill[hole] - x[hole]).max() < 1e-4, name


def test_the_walk_of_the_take_itself_beats_the_cubic_over_a_long_hole():
    """No library: the take's own other steps (observed around and away from the hole) fill a
    0.9-s hole of the whole body far better than the cubic Hermite, and a 0.7-s hole of one leg
    (the rest of the body, observed inside the hole, is matched too)."""
    x = _walk(10.0, 60.0, seed=1)
    for frames, joints in ((slice(300, 354), None), (slice(200, 242), BODY.groups["left_leg"])):
        holed, observed = _hole(x, frames, joints)
        hermite = _hermite(holed, observed)
        fills = match_fills(holed, observed, hermite)
        err = {name: np.linalg.norm(f[~observed] - x[~observed], axis=-1).mean() for name, f in fills.items()}
        cubic = np.linalg.norm(hermite[~observed] - x[~observed], axis=-1).mean()
        assert err["match"] < 0.2 * cubic and err["match_delta"] < 0.5 * cubic, (err, cubic)


def test_what_is_observed_stays_and_what_cannot_be_matched_keeps_the_cubic():
    x = _walk(4.0, 30.0, seed=2)
    holed, observed = _hole(x, slice(0, 10))  # at the start: no data on one side
    holed[50:60, BODY.groups["right_arm"]] = np.nan  # an ordinary arm hole
    holed[:, 4] = np.nan  # the head never observed: nothing to match it with
    observed = np.isfinite(holed).all(-1)
    hermite = _hermite(holed, observed)
    for name, fill in match_fills(holed, observed, hermite).items():
        assert np.array_equal(fill[observed], holed[observed]), name
        assert np.array_equal(fill[:10], hermite[:10]), name  # the border hole
        assert np.array_equal(fill[:, 4], hermite[:, 4]), name  # the joint never seen
        assert np.isfinite(fill[50:60]).all() and not np.array_equal(fill[50:60], hermite[50:60]), name


def test_the_frames_between_searched_ones_come_from_a_cubic_through_them():
    """_upsampled: every step-th frame -> all of them; exact on a quadratic away from the ends
    (central differences are its slopes), the searched frames themselves unchanged."""
    t = np.arange(0, 41, dtype=np.float64)  # 41 frames, every 4th searched: 11
    path = np.stack([0.01 * t**2, 0.5 * t, np.full_like(t, 1.0)], -1)[:, None, :]  # (41, 1, 3)
    up = _upsampled(path[::4], 4)
    assert up.shape == path.shape and np.array_equal(up[::4], path[::4])
    np.testing.assert_allclose(up[4:-4], path[4:-4], atol=1e-12)
    assert _upsampled(path, 1) is path
    assert [search_step(f) for f in (24.0, 25.0, 30.0, 50.0, 59.94, 100.0, 120.0, 240.0)] == [1, 1, 1, 2, 2, 3, 4, 8]


def test_a_120_fps_take_is_searched_at_30_fps_and_filled_at_its_own_rate():
    """A 120-fps take's library is searched at 30 fps (a quarter of the frames in memory and in
    every product), and the neighbours' motion, put back on the take's frames, still fills a
    0.9-s hole far better than the cubic and within 2 mm of searching every frame (the cubic
    between 30-fps frames); the fills meet the data at the hole's ends."""
    x = _walk(8.0, 120.0, seed=5)
    library = MotionLibrary([(_walk(8.0, 120.0, seed=5, heading=0.7, start=(3.0, -4.0)), 120.0)])
    searched = library.without(None, 120.0)
    assert searched.num_frames < 1.1 * sum(round(len(x) / 4 / tempo) for tempo in TEMPOS)
    holed, observed = _hole(x, slice(403, 511))  # 0.9 s of the whole body
    hermite = _hermite(holed, observed)
    hole = ~observed

    def error(fills):
        return {name: float(np.linalg.norm(f[hole] - x[hole], axis=-1).mean()) for name, f in fills.items()}

    at_30 = match_fills(holed, observed, hermite, searched, 120.0)
    every = error(match_fills(holed, observed, hermite, library.frames(120.0)[0]))  # fps None: every frame
    cubic = float(np.linalg.norm(hermite[hole] - x[hole], axis=-1).mean())
    for name, err in error(at_30).items():
        assert err < 0.02 * cubic and err < every[name] + 0.002, (name, err, every, cubic)  # the cubic: 136 mm
        assert np.array_equal(at_30[name][observed], holed[observed])
        step = np.linalg.norm(np.diff(at_30[name][400:515], axis=0), axis=-1).max()  # no jump at the ends
        assert step < 1.5 * np.linalg.norm(np.diff(x[400:515], axis=0), axis=-1).max()


def test_a_library_hides_the_take_it_is_asked_for_and_keeps_its_budget():
    a, b = _walk(2.0, 30.0, seed=3), _walk(3.0, 60.0, seed=4)
    library = MotionLibrary([(a, 30.0), (b, 60.0)], keys=["a", "b"])
    searched, spans = library.frames(30.0)
    frames = searched.stretch(0, searched.num_frames)
    # a at 30 fps played at TEMPOS 1, 0.85, 1.15: 60 + 70 + 52 frames, a NaN frame after each copy
    assert TEMPOS == (1.0, 0.85, 1.15) and spans == [(0, 184), (185, 461)]
    assert np.isnan(frames[60]).all() and np.isnan(frames[184]).all()
    np.testing.assert_allclose(frames[:60], a, atol=1e-6)
    np.testing.assert_allclose(frames[185:275], b[::2], atol=1e-6)  # resampled to the asked fps
    np.testing.assert_allclose(frames[61], a[0], atol=1e-6)  # slower: the same start, more frames
    assert library.without("a", 30.0).hidden == (0, 184) and library.without("c", 30.0).hidden == (0, 0)
    sent = pickle.loads(pickle.dumps(library))  # to a worker: the takes, not the searched frames
    assert len(pickle.dumps(library)) < 1.2 * (a.nbytes + b.nbytes) / 2  # float64 walks -> float32 takes
    again = sent.frames(30.0)[0]
    np.testing.assert_array_equal(again.stretch(0, again.num_frames), frames)

    # the hidden take is never matched: its exact copy fills the hole only when it is not hidden
    holed, observed = _hole(a, slice(25, 40))
    hermite = _hermite(holed, observed)
    hole = ~observed
    found = match_fills(holed, observed, hermite, library.without("c", 30.0))["match"][hole]
    hidden = match_fills(holed, observed, hermite, library.without("a", 30.0))["match"][hole]
    assert np.abs(found - a[hole]).max() < 1e-4 < np.abs(hidden - a[hole]).max()

    many = MotionLibrary([(a, 30.0)] * int(2 * LIBRARY_S / 2.0))  # twice the budget
    assert sum(len(x) / fps for x, fps in many.takes) <= LIBRARY_S
    assert len(many.takes) >= LIBRARY_S / 2.0 - 1


def test_a_mirrored_library_fills_from_the_mirror_image():
    """The library holds only the take's mirror image (left and right swapped), turned and moved:
    mirrored back by the library it fills a hole of the left leg exactly; not mirrored, it
    cannot (the take never repeats: every joint on its own random path)."""
    partner = mirror_index(BODY)
    rng = np.random.default_rng(1)
    x = rng.normal(0, 0.004, (180, BODY.num_joints, 3)).cumsum(0).cumsum(0) + rng.normal(0, 0.3, (BODY.num_joints, 3))
    c, s = np.cos(2.0), np.sin(2.0)
    image = mirrored(x @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) + [1.0, 2.0, 0.0], partner)
    holed, observed = _hole(x, slice(80, 101), BODY.groups["left_leg"])
    hermite = _hermite(holed, observed)
    hole = ~observed
    with_mirror = MotionLibrary([(image, 30.0)], mirror=partner).without(None, 30.0)
    plain = MotionLibrary([(image, 30.0)]).without(None, 30.0)
    for name in ("match", "match_delta"):
        assert np.abs(match_fills(holed, observed, hermite, with_mirror)[name][hole] - x[hole]).max() < 1e-4
        assert np.abs(match_fills(holed, observed, hermite, plain)[name][hole] - x[hole]).max() > 1e-2


def test_the_search_scores_every_start_as_a_brute_force_alignment_does():
    """_search's distances (correlations, read every step-th frame, then refined) against each
    stretch gathered and aligned by brute force (every turn about z, 0.05 degrees apart)."""
    rng = np.random.default_rng(8)
    J, width = 5, 12
    frames = rng.normal(0, 1.0, (300, J, 3)).cumsum(0) * 0.1 + [20.0, -30.0, 1.0]  # far from the origin
    frames[[40, 41, 200]] = np.nan
    frames[120, 2] = np.nan
    offsets = np.array([0, 1, 3, 4, 7, 10, 11])
    pts_f = np.repeat(offsets, J)
    pts_j = np.tile(np.arange(J), len(offsets))
    keep = rng.random(len(pts_f)) < 0.8
    pts_f, pts_j = pts_f[keep], pts_j[keep]
    query = frames[150 + pts_f, pts_j] + rng.normal(0, 0.05, (len(pts_f), 3))
    need = np.zeros(J, bool)
    need[2] = True
    library = searchable(frames.astype(np.float32))
    w = _weights(pts_f, pts_j, query, J)

    angles = np.radians(np.arange(0, 360, 0.05))
    q_xy = query[:, :2] - query[:, :2].mean(0)
    brute = np.full(len(frames) - width + 1, np.inf)
    for start in range(len(brute)):
        if not np.isfinite(frames[start : start + width, 2]).all():
            continue
        c = frames[start + pts_f, pts_j]
        if not np.isfinite(c).all():
            continue
        c_xy = c[:, :2] - c[:, :2].mean(0)
        turned = np.stack(
            [
                np.cos(angles)[:, None] * c_xy[:, 0] - np.sin(angles)[:, None] * c_xy[:, 1],
                np.sin(angles)[:, None] * c_xy[:, 0] + np.cos(angles)[:, None] * c_xy[:, 1],
            ],
            -1,
        )
        xy = ((turned - q_xy) ** 2).sum((1, 2)).min()
        brute[start] = (xy + ((c[:, 2] - query[:, 2]) ** 2).sum()) / len(query)
    for step in (1, 4):
        found = _search(library, w, need, width, k=5, apart=6, step=step)
        assert found[0][1] == int(np.argmin(brute)), step  # the best start, refined from the coarse grid
        for d, start, _, _ in found:
            np.testing.assert_allclose(d, brute[start], rtol=1e-4, atol=1e-7)
        starts = [f[1] for f in found]
        assert all(abs(p - q) > 6 for i, p in enumerate(starts) for q in starts[:i])  # apart


def test_a_source_is_kept_joints_first_and_frame_by_frame_each_laid_out_as_read():
    """The search's products read a source joints first, (J, N) per coordinate; its gathers of a
    start's frames read it frame by frame, (5, N, J): each row of J values side by side in memory
    (stacked from the joints-first arrays' transposes, np.stack kept their layout, and a gathered
    row read J values N apart). The same numbers either way, the missing ones at zero."""
    rng = np.random.default_rng(3)
    frames = rng.normal(0, 1.0, (50, 6, 3)) + [100.0, -40.0, 1.0]
    frames[rng.random((50, 6)) < 0.2] = np.nan
    c = searchable(frames[::2]).coordinates  # a strided view, as a take's searched frames are
    assert c.by_frame.flags.c_contiguous and c.by_frame.shape == (5, 25, 6)
    for k, name in enumerate(("x", "y", "z", "squared", "missing")):
        values = getattr(c, name)
        assert values.flags.c_contiguous and values.shape == (6, 25)
        np.testing.assert_array_equal(c.by_frame[k], values.T)
    missing = np.isnan(frames[::2]).any(-1).T  # (J, N)
    assert np.array_equal(c.missing > 0, missing) and not c.x[missing].any() and not c.squared[missing].any()
    seen = frames[::2][~np.isnan(frames[::2]).any(-1)]
    np.testing.assert_allclose(c.middle, seen[:, :2].mean(0))
    np.testing.assert_allclose(c.x.T[~missing.T] + c.middle[0], seen[:, 0], atol=1e-4)


def test_the_recording_policy_never_searches_the_truth_of_its_cut_holes():
    """A take that never repeats (every joint on its own random path): the motion-matching fills
    of the holes cut into it cannot be exact, as they would be if the take's uncut copy in the
    library were searched."""
    from mocapfix.fills.errors import measure_on_takes

    rng = np.random.default_rng(5)
    steps = rng.normal(0, 0.004, (600, BODY.num_joints, 3)).cumsum(0).cumsum(0) * 0.05
    x = steps + rng.normal(0, 0.3, (1, BODY.num_joints, 3)) + [0, 0, 1.0]
    errors, holes = measure_on_takes([(x, 30.0), (x + [5.0, 0.0, 0.0], 30.0)], BODY, (0.5,), {("full", 0.5)})
    table = errors.tables()
    assert holes[("full", 0.5)] >= 8
    full = {m: e[0] for m, e in table["full"].items()}
    # the second take is the first moved 5 m: each one's cut holes are found in the other, uncut
    assert full["match"] < 0.01 * full["hermite"]
    one, _ = measure_on_takes([(x, 30.0)], BODY, (0.5,), {("full", 0.5)})
    alone = {m: e[0] for m, e in one.tables()["full"].items()}
    assert alone["match"] > 0.3 * alone["hermite"] and alone["hermite"] > 1.0


@pytest.mark.parametrize("fps", [30.0, 120.0])
def test_holes_of_any_length_and_frame_rate_come_out_finite(fps):
    x = _walk(5.0, fps, seed=6)
    rng = np.random.default_rng(7)
    holed = x.copy()
    for _ in range(12):
        s, n = int(rng.integers(1, len(x) - 40)), int(rng.integers(1, round(fps)))
        holed[s : s + n, rng.choice(BODY.num_joints, 5, replace=False)] = np.nan
    observed = np.isfinite(holed).all(-1)
    hermite = _hermite(holed, observed)
    for name, fill in match_fills(holed, observed, hermite).items():
        assert np.isfinite(fill[1:-1]).all(), name


def test_holes_shorter_than_the_minimum_keep_the_cubic_when_the_frame_rate_is_known():
    x = _walk(6.0, 30.0, seed=8)
    holed, observed = _hole(x, slice(40, 43))  # 0.1 s
    holed[100:127] = np.nan  # 0.9 s
    observed = np.isfinite(holed).all(-1)
    hermite = _hermite(holed, observed)
    with_fps, without = match_fills(holed, observed, hermite, fps=30.0), match_fills(holed, observed, hermite)
    for name in with_fps:
        assert np.array_equal(with_fps[name][40:43], hermite[40:43]), name
        assert not np.array_equal(without[name][40:43], hermite[40:43]), name
        assert np.array_equal(with_fps[name][100:127], without[name][100:127]), name


def test_a_hole_not_asked_for_is_not_searched_and_an_asked_one_comes_out_the_same():
    """The recording's policy asks for the holes it cut, not the take's own: those keep the
    cubic (no search), the asked hole's fills are those of the whole take's search."""
    x = _walk(8.0, 30.0, seed=9)
    holed, _ = _hole(x, slice(60, 81), BODY.groups["left_leg"])  # the take's own hole
    holed[150:177] = np.nan  # a cut hole
    observed = np.isfinite(holed).all(-1)
    asked = np.zeros_like(observed)
    asked[150:177] = True
    hermite = _hermite(holed, observed)
    every = match_fills(holed, observed, hermite, fps=30.0)
    some = match_fills(holed, observed, hermite, None, 30.0, asked)
    for name in every:
        assert np.array_equal(some[name][60:81], hermite[60:81]), name
        assert not np.array_equal(every[name][60:81], hermite[60:81]), name
        assert np.array_equal(some[name][150:177], every[name][150:177]), name


def test_a_long_library_scored_first_by_the_proxy_finds_what_the_exact_search_finds(monkeypatch):
    """A library long enough for the proxy (PROXY_BASINS) to score its grid first, 150 s of other
    walks with the take itself turned and moved among them: the fills of a full-body and a leg
    hole are those of scoring every start with the whole query, and the take's own motion."""
    import mocapfix.fills.motion_matching as mm

    x = _walk(10.0, 30.0, seed=11)
    others = [_walk(50.0, 30.0, seed=s, heading=0.3 * s) for s in (20, 21, 22)]
    library = np.concatenate(others[:2] + [_walk(10.0, 30.0, seed=11, heading=0.7, start=(3.0, -4.0))] + others[2:])
    holed, _ = _hole(x, slice(100, 127))
    holed[200:221, BODY.groups["left_leg"]] = np.nan
    observed = np.isfinite(holed).all(-1)
    hermite = _hermite(holed, observed)
    source = searchable(library.astype(np.float32))
    # the grid's starts (step 1 at 30 fps) beyond what _search scores exactly, for both holes
    assert len(library) - 40 > 4 * mm.PROXY_BASINS * (27 // 2)
    proxied = match_fills(holed, observed, hermite, source, 30.0)
    monkeypatch.setattr(mm, "PROXY_BASINS", 10**9)  # no source is long enough: every start scored
    exact = match_fills(holed, observed, hermite, source, 30.0)
    for name in exact:
        np.testing.assert_allclose(proxied[name], exact[name], atol=1e-6)
    assert np.abs(exact["match"][~observed] - x[~observed]).max() < 1e-4  # found the take itself


def test_the_index_describes_a_frame_the_same_however_the_body_is_turned_and_moved():
    """MotionIndex: a frame of the take and the same frame turned about z and moved over the floor
    are described alike (distance ~0), a third of a step later they are not, a frame with a joint
    missing is never a candidate, and a take's edge with a joint missing asks for no index; the
    same for a frame inside a leg's hole, over the joints it has."""
    from mocapfix.fills.motion_index import MotionIndex

    x = _walk(8.0, 30.0, seed=4)
    moved = _walk(8.0, 30.0, seed=4, heading=2.0, start=(-7.0, 3.0))
    frames = np.concatenate([x, moved]).astype(np.float32)
    frames[30, 5] = np.nan
    c = searchable(frames).coordinates
    index = MotionIndex(c.x, c.y, c.z, c.missing, mirror_index(BODY), torso_of(BODY))
    T = len(x)
    legless = x[100].copy()
    legless[list(BODY.groups["left_leg"])] = np.nan  # the middle of a leg's hole
    for side, d in ((-1, index.distances(x, 100, -1)), (1, index.distances(x, 100, 1)), (0, None)):
        d = index.distances_inside(legless) if side == 0 else d
        assert d[100] < 1e-5 and d[T + 100] < 1e-5, side  # itself, and turned and moved
        assert min(d[111], d[T + 111]) > 1e-2, side
        assert np.isinf(d[30]), side  # a joint missing there
    holed = x.copy()
    holed[99, 3] = np.nan
    assert index.distances(holed, 99, -1) is None


def test_a_long_library_with_an_index_finds_the_take_itself_as_the_exact_search_does(monkeypatch):
    """A library with an index (its skeleton's sides pair up), long enough that its starts are
    not all scored: a full-body and a leg hole of a take hidden among 150 s of other walks, turned
    and moved, are filled from it as scoring every start fills them; the take's own copy in the
    library (its key) is never found; a limb's hole is looked up by the body it leaves too."""
    import mocapfix.fills.motion_matching as mm

    x = _walk(10.0, 30.0, seed=11, wobble=0.4)  # no step of it fills another exactly
    others = [(_walk(50.0, 30.0, seed=s, heading=0.3 * s), 30.0) for s in (20, 21, 22)]
    turned = (_walk(10.0, 30.0, seed=11, heading=0.7, start=(3.0, -4.0), wobble=0.4), 30.0)
    takes, keys = others[:2] + [turned] + others[2:] + [(x, 30.0)], [0, 1, 2, 3, "own"]
    library = MotionLibrary(takes, keys, mirror_index(BODY), torso_of(BODY))
    holed, _ = _hole(x, slice(100, 127))
    holed[200:221, BODY.groups["left_leg"]] = np.nan
    observed = np.isfinite(holed).all(-1)
    hermite = _hermite(holed, observed)
    source = library.without("own", 30.0)
    assert source.index is not None
    calls = []
    monkeypatch.setattr(mm, "_index_places", lambda *a, f=mm._index_places: calls.append(f(*a)) or calls[-1])
    indexed = match_fills(holed, observed, hermite, source, 30.0)
    indexed_calls = [c for c in calls if c is not None]  # the library's, not the take's own (short)
    assert len(indexed_calls) == 2 and all(len(c) < source.num_frames / 20 for c in indexed_calls)
    monkeypatch.setattr(mm, "PROXY_BASINS", 10**9)  # no source is long enough: every start scored
    exact = match_fills(holed, observed, hermite, source, 30.0)
    for name in exact:
        np.testing.assert_allclose(indexed[name], exact[name], atol=1e-5)  # the other neighbours weigh ~1e-5
    for found in (indexed, exact):
        assert np.abs(found["match"][~observed] - x[~observed]).max() < 1e-4  # the turned copy


def test_the_best_starts_apart_are_those_of_a_pick_at_a_time():
    """_best_apart sorts only the lowest distances; it must pick what taking the argmin, ruling
    out its neighbourhood and taking the argmin again picks, ties and unscored starts included."""
    from mocapfix.fills.motion_matching import _best_apart

    def one_at_a_time(of, n, apart):
        left, out = of.copy(), []
        for _ in range(n):
            i = int(np.argmin(left))
            if not np.isfinite(left[i]):
                break
            out.append(i)
            left[max(0, i - apart) : i + apart + 1] = np.inf
        return out

    rng = np.random.default_rng(3)
    for trial in range(200):
        N = int(rng.integers(1, 400))
        of = rng.integers(0, 6, N).astype(float) if trial % 2 else rng.random(N)  # many ties, or none
        of[rng.random(N) < 0.2] = np.inf
        n, apart = int(rng.integers(1, 20)), int(rng.integers(0, 12))
        assert _best_apart(of, n, apart) == one_at_a_time(of, n, apart)
