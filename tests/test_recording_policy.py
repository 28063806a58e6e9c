"""The fill policy is measured on the recording being fixed (FillPolicy.fit, fills/errors.py): a model
that its own val split believes in, and that is bad on this recording, does not fill its holes.
Real motion (Bandai Namco takes); the model is the shipped one, or the shipped one broken."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mocapfix.apps.main import main
from mocapfix.fills.classical import CLASSICAL
from mocapfix.io import read_motion
from mocapfix.io.positions import write_positions
from mocapfix.pretrained import pretrained_path


@pytest.fixture(scope="module")
def takes(bandai_files):
    """Two Bandai takes of 8 s or more (a dance, a run), on the model's joints."""
    long = [f for f in bandai_files if f.stat().st_size > 400_000][:2]
    return [read_motion(f, drop_joints=["joint_Root"])[0] for f in long]


@pytest.fixture(scope="module")
def bad_model(tmp_path_factory):
    """The shipped XMAE with its weights scrambled, and a val-split policy that says it wins every
    cell: a model that believes in itself and is bad on every recording."""
    ck = torch.load(pretrained_path("xmae-cpu-bandai"), map_location="cpu", weights_only=True)
    g = torch.Generator().manual_seed(0)
    ck["state_dict"] = {
        k: v + 0.5 * torch.randn(v.shape, generator=g) if k.startswith("net.") and v.is_floating_point() else v
        for k, v in ck["state_dict"].items()
    }
    for table in ck["fill_policy"]["error_mm"].values():
        for method, errors in table.items():
            table[method] = [0.1 if method == "xmae" else 100.0 for _ in errors]
    path = tmp_path_factory.mktemp("bad") / "bad.ckpt"
    torch.save(ck, path)
    return path


def _holes(clip, seconds=0.7):
    """The take with full-body holes of `seconds` every 3 s; -> (holed positions, hole mask)."""
    pos = clip.positions.copy()
    T, n = len(pos), int(round(seconds * clip.fps))
    holes = np.zeros(pos.shape[:2], dtype=bool)
    for start in range(int(clip.fps), T - n - int(clip.fps), int(3 * clip.fps)):
        holes[start : start + n] = True
    pos[holes] = np.nan
    return pos, holes


def test_a_bad_model_that_believes_in_itself_never_fills_worse_than_the_spline(tmp_path, takes, bad_model, capsys):
    def err(p, truth, holes):  # mm over the holes
        return 1000 * np.linalg.norm(p[holes] - truth[holes], axis=-1).mean()

    for i, clip in enumerate(takes):
        holed, holes = _holes(clip)
        f = tmp_path / f"take{i}.npz"
        write_positions(f, holed, clip.fps, clip.skeleton)
        capsys.readouterr()
        assert main(["fix", str(f), "--ckpt", str(bad_model)]) == 0
        out = capsys.readouterr().out
        assert "fill policy measured on this recording" in out and "xmae" not in out.split("filled by")[1].split(";")[0]
        [fixed] = read_motion(tmp_path / f"take{i}.fixed.npz")
        x = torch.from_numpy(holed.astype(np.float64))[None]
        spline = CLASSICAL["spline"](x, ~torch.isnan(x).any(-1), clip.skeleton.parents)[0].numpy()
        ours, theirs = err(fixed.positions, clip.positions, holes), err(spline, clip.positions, holes)
        assert ours <= theirs + 0.5, (ours, theirs)


def test_the_bad_model_is_bad_where_its_own_policy_is_trusted(tmp_path, takes, bad_model):
    """The check above means something: the broken model's own fill is far worse than the spline."""
    from mocapfix.fix.fixers import load_fixer

    fixer = load_fixer(str(bad_model))
    clip = takes[0]
    windows = torch.from_numpy(np.stack([clip.positions[s : s + fixer.window] for s in range(0, 240, 30)]))
    observed = torch.ones(windows.shape[:3], dtype=torch.bool)
    observed[:, 5:25] = False  # a 0.67-s full-body hole in each window
    estimate = fixer.estimate(windows, observed)
    holed = torch.where(observed[..., None], windows, np.nan).double()
    spline = CLASSICAL["spline"](holed, observed, clip.skeleton.parents)
    err = lambda p: float((p.float() - windows).norm(dim=-1)[~observed].mean())  # noqa: E731
    assert err(estimate) > 3 * err(spline)


def test_too_little_to_measure_the_model_on_gets_the_classical_fills(tmp_path, takes, bad_model, capsys):
    """A model must earn its place on the recording: where it cannot be measured there (too few
    places to cut a hole of the kind with data around it), the classical fills only, even for a
    model whose val split says it wins every cell."""
    clip = takes[0]
    holed = clip.positions[:150].copy()  # 5 s with a 0.5-s hole every 0.8 s: no room for another
    for start in range(5, 150, 24):
        holed[start : start + 15] = np.nan
    write_positions(tmp_path / "holey.npz", holed, clip.fps, clip.skeleton)
    capsys.readouterr()
    assert main(["fix", str(tmp_path / "holey.npz"), "--ckpt", str(bad_model)]) == 0
    out = capsys.readouterr().out
    assert "classical fills only" in out
    assert "xmae" not in out.split("filled by")[1].split(";")[0]


def test_holes_are_cut_only_where_there_is_data_around_them():
    from mocapfix.fills.holes import cut_holes

    observed = np.ones((120, 4), dtype=bool)
    observed[40:52] = False  # the recording's own hole
    observed[90:, 3] = False
    hidden = cut_holes(observed, [[0, 1], [2, 3]], frames=6, budget=8, margin=3)
    assert hidden[:, :2].any() and hidden[:, 2:].any()  # both options, in turn
    assert not (hidden & ~observed).any()
    starts = np.nonzero(np.diff(hidden.any(-1).astype(int), prepend=0) == 1)[0]
    assert 2 <= len(starts) <= 8
    for s in starts:
        joints = hidden[s]
        around = np.r_[s - 3 : s, s + 6 : s + 9]
        assert (hidden[s : s + 6] == joints).all()  # one hole: its joints for its 6 frames
        assert observed[np.ix_(around, joints)].all() and not hidden[around].any()


def test_a_folder_of_crowded_takes_still_gets_its_holes_cut_where_there_is_room():
    """Each take's share of the holes to cut, and what a take crowded with its own holes cannot
    cut moved to takes with room: a folder of short, holed takes is measured on as many holes as
    a folder of long ones (Bandai's 4-15-s takes with four 0.9-s holes each: 19 of 64 before)."""
    from mocapfix.fills.holes import cut_holes, room_for_holes, share_holes

    assert share_holes([10, 10, 10, 10], 16) == [4, 4, 4, 4]  # room everywhere: equal shares, as before
    assert share_holes([1, 0, 30, 30], 64) == [1, 0, 30, 30]  # less room than holes: all of it
    budget = share_holes([1, 0, 40, 40], 64)
    assert budget[:2] == [1, 0] and sum(budget) == 64 and abs(budget[2] - budget[3]) <= 1
    assert share_holes([], 64) == []

    observed = np.ones((100, 2), dtype=bool)
    observed[30:40] = False
    room = room_for_holes(observed, [[0, 1]], frames=10, margin=2)
    # greedy from the start: 2..12, 14..24 before the own hole; 42..52, 54..64, 66..76, 78..88 after
    assert room == 6
    hidden = cut_holes(observed, [[0, 1]], frames=10, budget=room, margin=2)
    assert np.count_nonzero(np.diff(hidden.any(-1).astype(int), prepend=0) == 1) <= room


def test_the_classical_fills_are_ranked_on_the_take_itself():
    """A take whose joints move on cubics: the spline fills its holes exactly, Lerp does not; the
    val split's ranking (here: Lerp first) is not what the take says."""
    from mocapfix.core.skeleton import preset
    from mocapfix.fills.errors import measure_on_takes

    body = preset("body21")
    t = np.linspace(0, 4, 120)[:, None, None]
    rng = np.random.default_rng(0)
    a, b, c = (rng.normal(size=(1, body.num_joints, 3)) * s for s in (0.3, 0.1, 0.02))
    x = (a * t + b * t**2 + c * t**3).astype(np.float64)
    x[50:60] = np.nan
    errors, holes = measure_on_takes([(x, 30.0)], body, (0.3, 0.5), {("full", 0.5), ("arm", 0.3)})
    table = errors.tables()
    assert holes[("full", 0.5)] >= 4 and set(holes) == {("full", 0.5), ("arm", 0.3)}
    full = {m: e[1] for m, e in table["full"].items()}
    assert full["spline"] < 0.01 * full["lerp"] and full["lerp"] > 1.0
    assert np.isfinite(table["arm"]["spline"][0])  # (arm, 0.3 s) was asked for
    assert not np.isfinite(table["full"]["spline"][0])  # (full, 0.3 s) was not asked for


def test_a_folder_is_measured_once_over_its_files(tmp_path, takes, capsys):
    folder = tmp_path / "takes"
    folder.mkdir()
    for i, clip in enumerate(takes):
        holed, _ = _holes(clip, 0.5)
        write_positions(folder / f"take{i}.npz", holed, clip.fps, clip.skeleton)
    capsys.readouterr()
    assert main(["fix", str(folder), "--model", "xmae-cpu-bandai"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith(f"fill policy measured on the {len(takes)} files of this run")
    assert len(lines) == 1 + len(takes)
    assert all("fill policy measured over this run's files (above)" in line for line in lines[1:])
    for i, clip in enumerate(takes):
        [fixed] = read_motion(folder / f"take{i}.fixed.npz")
        holed, holes = _holes(clip, 0.5)
        assert np.isfinite(fixed.positions).all()
        assert np.array_equal(fixed.positions[~holes], holed[~holes])


def test_a_perfect_model_needs_as_many_cut_holes_as_a_classical_fill_to_take_a_kind():
    """The model takes a kind of hole from the preferred classical fill only on TRUSTED_HOLES cut
    holes, as another classical fill must: fewer, and even a model exact on every cut hole is not
    chosen (one 12-s take let XMAE's blend win a leg cell it then lost on the take's own hole)."""
    from mocapfix.core.skeleton import preset
    from mocapfix.fills.fill import Made
    from mocapfix.fills.policy import TRUSTED_HOLES, FillPolicy, is_learned
    from mocapfix.io.synthetic import generate_clips
    from mocapfix.rig.mapping import onto_skeleton

    body = preset("body21")

    def policy_for(seconds: float) -> tuple[str, int]:
        x = onto_skeleton(generate_clips(1, seconds, 30.0, seed=5)[0], body).positions.astype(np.float64)
        truth = x.copy()
        x[60:81, list(body.groups["right_leg"])] = np.nan  # one 0.7-s leg hole
        gaps = [0.1, 0.3, 0.5, 0.7, 0.9]
        val = {p: {m: [50.0] * 5 for m in ("lerp", "limb", "spline", "pchip", "xmae")} for p in ("full", "arm", "leg")}
        oracle = Made("xmae", torch.from_numpy(truth)[None])  # exact on every cut hole
        policy, note = FillPolicy(gaps, val, None).fit([(x, 30.0)], body, oracle, holes_of=([x], 30.0))
        return policy.choose("leg", 0.7), int(note.split("(")[1].split(" holes")[0])

    short, cut_short = policy_for(12.0)
    assert cut_short < TRUSTED_HOLES and not is_learned(short)
    long, cut_long = policy_for(120.0)
    assert cut_long >= TRUSTED_HOLES and is_learned(long)


def test_fix_library_takes_are_searched_and_the_recording_says_when_to_use_them(tmp_path, cmu_files, capsys):
    """fix --library: the user's other takes. Here one of them is the take itself, turned 90
    degrees and moved 4 m: the motion-matching fill finds it, the holes cut into the recording
    (a 40-s CMU take: enough of them to overrule the preferred fill) say it is the best fill,
    and the take's own holes come back within a few mm (the 120-fps take is searched at 30 fps:
    its copy is met within 1/60 s; motion_matching.SEARCH_FPS); without it, not."""
    from mocapfix.fix import load_fixer, map_joints

    [clip] = read_motion(next(f for f in cmu_files if f.name == "06_13.bvh"))
    holes = np.zeros(clip.positions.shape[:2], dtype=bool)
    for start in range(5 * int(clip.fps), clip.num_frames - 60, 10 * int(clip.fps)):  # 0.5 s every 10 s
        holes[start : start + 60] = True
    holed = np.where(holes[..., None], np.nan, clip.positions)
    write_positions(tmp_path / "take.npz", holed, clip.fps, clip.skeleton)
    library = tmp_path / "library"
    library.mkdir()
    turned = clip.positions.copy()
    turned[..., 0], turned[..., 1] = -clip.positions[..., 1] + 4.0, clip.positions[..., 0]
    write_positions(library / "other.npz", turned, clip.fps, clip.skeleton)

    fixer = load_fixer(str(pretrained_path("xmae-cpu-bandai")), "cpu")
    used = map_joints(clip.skeleton, fixer.skeleton, "take", None, allow_missing=True)  # the model's joints
    scored = holes.copy()
    scored[:, np.setdiff1d(np.arange(clip.skeleton.num_joints), used)] = False  # the others follow the skeleton

    def fix(*extra: str) -> tuple[float, str]:
        out = tmp_path / "fixed.npz"
        capsys.readouterr()
        argv = ["fix", str(tmp_path / "take.npz"), "-o", str(out), "--force", "--model", "xmae-cpu-bandai"]
        assert main(argv + list(extra)) == 0
        [fixed] = read_motion(out)
        assert np.array_equal(fixed.positions[~holes], holed[~holes])
        error = np.linalg.norm(fixed.positions[scored] - clip.positions[scored], axis=-1).mean()
        return 1000 * float(error), capsys.readouterr().out

    error, report = fix()
    assert error > 10.0, report
    error, report = fix("--library", str(library))
    assert error < 8.0 and "full 0.5s match" in report, report  # 5.8 mm


def test_library_files_past_what_the_search_keeps_are_not_read(tmp_path, monkeypatch):
    """fix --library reads takes until the search's budget (LIBRARY_S) is spent, in the order the
    search keeps them, and says how many it did not read."""
    import io

    from mocapfix.apps import fix_run
    from mocapfix.io.synthetic import generate_clips

    for i, clip in enumerate(generate_clips(3, 4.0, 30.0, seed=2)):
        write_positions(tmp_path / f"take{i}.npz", clip.positions, clip.fps, clip.skeleton)
    monkeypatch.setattr(fix_run, "LIBRARY_S", 6.0)
    err = io.StringIO()
    read, unread = fix_run._library_takes(fix_run._library_files([str(tmp_path)], "auto", err), "auto", err, {})
    assert [c[0].source.endswith(f"take{i}.npz") for i, c in enumerate(read)] == [True, True] and unread == 1
    assert "2 files (0 min) read; 1 more not read" in err.getvalue()


def test_a_costly_fill_that_cannot_win_a_kind_is_screened_out_and_one_that_can_is_kept():
    """hopeless: paired per-hole errors against what choose() asks (MODEL_MARGIN / PREFERRED_MARGIN
    x the preferred fill's): clearly above it, or ahead of it by less than SCREEN_TOLERANCE of it, the
    fill stops measuring that kind; ahead by more, or too uncertain to tell, not."""
    from mocapfix.fills.errors import ErrorSums
    from mocapfix.fills.policy import SCREEN_TOLERANCE, hopeless

    rng = np.random.default_rng(0)
    limb = 0.010 + 0.004 * rng.random(16)  # the holes differ far more than the fills on one hole
    errors = ErrorSums([0.5, 0.7, 0.9])
    errors.holes = {
        ("full", 0.5, "limb"): list(limb),
        ("full", 0.5, "match"): list(1.5 * limb),  # far behind
        ("full", 0.5, "limb+match"): list(1.2 * limb),
        ("full", 0.5, "xmae"): list(0.99 * limb + 1e-5 * rng.random(16)),  # ahead, but not by 2 %
        # ahead of 0.95 x the limb fill, but by far less than the tolerance: not worth measuring
        ("full", 0.7, "limb"): list(limb),
        ("full", 0.7, "match"): list((0.95 - 0.1 * SCREEN_TOLERANCE) * limb + 1e-5 * rng.random(16)),
        ("full", 0.9, "limb"): list(limb),
        ("full", 0.9, "match"): list(1.5 * limb),
        ("full", 0.9, "limb+match"): list(0.85 * limb + 0.002 * rng.standard_normal(16)),  # may win
        ("full", 0.9, "xmae"): list(0.9 * limb),
    }
    out = hopeless(errors, [("match", "match_delta"), ("xmae",)])
    assert out == {("full", 0.5): {"match", "match_delta", "xmae"}, ("full", 0.7): {"match", "match_delta"}}


def test_the_screen_drops_only_fills_that_choose_would_not_pick(monkeypatch):
    """hopeless's bars are necessary conditions of choose(): on holes whose paired differences all
    have one sign (each hole the candidates' means times one factor), with no tolerance, a fill
    it drops is never in the candidate choose() picks from the means; and a model behind a
    classical candidate far ahead of the limb fill is dropped though it is ahead of the limb fill."""
    from mocapfix.fills import policy as policy_module
    from mocapfix.fills.errors import ErrorSums
    from mocapfix.fills.fill import components
    from mocapfix.fills.policy import FillPolicy, hopeless

    monkeypatch.setattr(policy_module, "SCREEN_TOLERANCE", 0.0)
    rng = np.random.default_rng(0)
    singles = ["limb", "spline", "pchip", "match", "xmae"]
    names = singles + [a + "+" + b for i, a in enumerate(sorted(singles)) for b in sorted(singles)[i + 1 :]]
    fills = [("spline",), ("pchip",), ("match", "match_delta"), ("xmae",)]
    dropped = 0
    for _ in range(400):
        means = dict(zip(names, 0.01 * (0.8 + 0.4 * rng.random(len(names)))))
        scale = 1 + 0.2 * rng.standard_normal(16)  # (holes,) the holes differ, the order on each does not
        errors = ErrorSums([0.5])
        errors.holes = {("full", 0.5, m): list(e * scale) for m, e in means.items()}
        table = FillPolicy([0.5], {"full": {m: [e] for m, e in means.items()}}, preferred=("limb", 0.95))
        chosen = set(components(table.choose("full", 0.5)))
        out = hopeless(errors, fills).get(("full", 0.5), set())
        assert not out & chosen, (out, table.choose("full", 0.5))
        dropped += len(out)
    assert dropped > 0
    # the model 10 % ahead of the limb fill, motion matching 30 % ahead: choose() asks the model
    # for 2 % below what it picks among the classical candidates (at most motion matching's)
    limb = 0.010 + 0.004 * rng.random(16)
    errors = ErrorSums([0.5])
    errors.holes = {("full", 0.5, "limb"): list(limb), ("full", 0.5, "match"): list(0.7 * limb)}
    errors.holes[("full", 0.5, "xmae")] = list(0.9 * limb)
    errors.holes[("full", 0.5, "limb+xmae")] = list(0.95 * limb)
    assert hopeless(errors, [("match", "match_delta"), ("xmae",)]) == {("full", 0.5): {"xmae"}}


def test_the_takes_are_measured_in_phases_of_sixteen_more_holes_of_each_kind_spread_over_the_folder():
    """screening_phases: every fourth take first; a kind's holes in a take go to the first phase
    where the kind has fewer than 16 more planned (a take's other kinds wait for a later phase);
    takes with no hole to cut are not visited."""
    from mocapfix.fills.errors import SCREEN_HOLES, screening_phases

    assert SCREEN_HOLES == 16
    full, arm = ("full", 0.5), ("arm", 0.3)
    budgets = [{full: 4} for _ in range(8)] + [{full: 0}] * 2  # 32 holes
    # visited in the order 0 4 (8) 1 5 | (9) 2 6 3 7
    assert screening_phases(budgets) == [[(i, {full: 4}) for i in (0, 1, 4, 5)], [(i, {full: 4}) for i in (2, 3, 6, 7)]]
    spread = [{full: 0 if i % 4 == 3 else 4, arm: int(i == 0)} for i in range(12)]  # 36 and 1
    # 0 4 8 1 | 5 9 2 6 | 10 (3 7 11: nothing to cut)
    assert screening_phases(spread) == [
        [(0, {full: 4, arm: 1}), (1, {full: 4}), (4, {full: 4}), (8, {full: 4})],
        [(i, {full: 4}) for i in (2, 5, 6, 9)],
        [(10, {full: 4})],
    ]
    # take 0 brings the arm's 16 at once: the arm holes of the others wait for the next phase
    crowded = [{arm: 16, full: 4}] + [{arm: 4, full: 4}] * 3
    assert screening_phases(crowded) == [
        [(0, {arm: 16, full: 4}), (1, {full: 4}), (2, {full: 4}), (3, {full: 4})],
        [(1, {arm: 4}), (2, {arm: 4}), (3, {arm: 4})],
    ]
    # one take brings 40 of a kind: no empty phase while the count catches up with it
    assert screening_phases([{arm: 40}, {arm: 4}]) == [[(0, {arm: 40})], [(1, {arm: 4})]]


def test_fills_screened_out_after_the_first_takes_are_not_run_on_the_others():
    """measure_on_takes asks its screen after the first phase of takes; a fill it names
    is not run again on that kind, and its candidates are inf in the tables (not the val split's)."""
    from mocapfix.core.skeleton import preset
    from mocapfix.fills.errors import measure_on_takes, screening_phases
    from mocapfix.fills.fill import Fill
    from mocapfix.io.synthetic import generate_clips
    from mocapfix.rig.mapping import onto_skeleton

    body = preset("body21")
    takes = [(onto_skeleton(c, body).positions.astype(np.float64), 30.0) for c in generate_clips(8, 8.0, 30.0, seed=2)]

    class Counted(Fill):
        names, calls = ("xmae",), 0

        def fill(self, positions, observed, fps, skeleton, asked=None, shared=None):
            Counted.calls += 1
            return {"xmae": positions.nan_to_num()}

    cells = {("full", 0.5)}
    errors, cut = measure_on_takes(takes, body, (0.5,), cells, Counted(), screen=lambda e, fills: {})
    every = Counted.calls
    assert every == len(takes) and np.isfinite(errors.tables()["full"]["xmae"][0])
    Counted.calls = 0
    seen = []
    screened, cut2 = measure_on_takes(
        takes, body, (0.5,), cells, Counted(), screen=lambda e, fills: seen.append(fills) or {("full", 0.5): {"xmae"}}
    )
    first = screening_phases([{("full", 0.5): cut[("full", 0.5)] // len(takes)}] * len(takes))[0]
    assert Counted.calls == len(first) < len(takes) and ("xmae",) in seen[0]
    assert cut2 == cut  # the same holes cut
    table = screened.tables()["full"]
    assert table["xmae"][0] == float("inf") and table["limb+xmae"][0] == float("inf")
    assert np.isfinite(table["limb"][0])


def test_a_kind_every_other_fill_left_is_settled_and_cuts_no_more_holes():
    """A kind whose screen leaves the preferred fill alone has nothing left to rank: the later
    takes cut none of its holes (the costly work saved is theirs), and its table holds that fill."""
    from mocapfix.core.skeleton import preset
    from mocapfix.fills.errors import measure_on_takes, screening_phases
    from mocapfix.fills.policy import PREFERRED
    from mocapfix.io.synthetic import generate_clips
    from mocapfix.rig.mapping import onto_skeleton

    body = preset("body21")
    takes = [(onto_skeleton(c, body).positions.astype(np.float64), 30.0) for c in generate_clips(8, 8.0, 30.0, seed=2)]
    cells = {("full", 0.5), ("arm", 0.5)}
    _, cut = measure_on_takes(takes, body, (0.5,), cells, screen=lambda e, fills: {})
    asked = []

    def all_but_preferred(errors, fills):
        asked.append(fills)
        return {("full", 0.5): {n for names in fills for n in names if n != PREFERRED}}

    settled, cut2 = measure_on_takes(takes, body, (0.5,), cells, screen=all_but_preferred)
    first = screening_phases([{("full", 0.5): cut[("full", 0.5)] // len(takes)}] * len(takes))[0]
    assert ("spline",) in asked[0] and len(first) < len(takes)
    assert cut2[("arm", 0.5)] == cut[("arm", 0.5)] and 0 < cut2[("full", 0.5)] < cut[("full", 0.5)]
    assert [m for m, e in settled.tables()["full"].items() if np.isfinite(e[0])] == [PREFERRED]


def test_the_kinds_of_a_take_filled_together_measure_what_each_filled_alone_measures(monkeypatch):
    """measure_take fills a take's kinds of hole in one batch of the take's copies (each fill
    called once, a model's windows in full batches): every fill must give each copy what it gives
    that kind alone, and each kind's errors come out the same."""
    from mocapfix.core.skeleton import preset
    from mocapfix.fills import errors as errors_module
    from mocapfix.fills.errors import measure_on_takes
    from mocapfix.fills.motion_matching import MotionLibrary
    from mocapfix.io.synthetic import generate_clips
    from mocapfix.rig.mapping import onto_skeleton

    body = preset("body21")
    takes = [(onto_skeleton(c, body).positions.astype(np.float64), 30.0) for c in generate_clips(3, 8.0, 30.0, seed=5)]
    library = MotionLibrary(takes[1:], ["a", "b"])
    together, _ = measure_on_takes(takes[:1], body, (0.3, 0.7), None, keys=["own"], library=library)
    monkeypatch.setattr(errors_module, "BATCH_FRAMES", 1)  # one kind a call
    alone, _ = measure_on_takes(takes[:1], body, (0.3, 0.7), None, keys=["own"], library=library)
    assert len(together.sums) >= 6 * 2 * 3 and together.sums.keys() == alone.sums.keys()
    for key, (total, count) in alone.sums.items():
        assert together.sums[key][1] == count and together.sums[key][0] == pytest.approx(total, rel=1e-9)


def test_a_model_screened_out_on_the_recording_is_not_taken_on_its_val_split_numbers():
    """A kind the recording measured keeps the recording's verdict: a model screened out there is
    inf in the policy's tables, whatever its checkpoint's val split says."""
    from mocapfix.core.skeleton import preset
    from mocapfix.fills.fill import Made
    from mocapfix.fills.policy import FillPolicy, is_learned
    from mocapfix.io.synthetic import generate_clips
    from mocapfix.rig.mapping import onto_skeleton

    body = preset("body21")
    takes = [(onto_skeleton(c, body).positions.astype(np.float64), 30.0) for c in generate_clips(8, 8.0, 30.0, seed=4)]

    far = Made("xmae", torch.zeros(1, len(takes[0][0]), body.num_joints, 3, dtype=torch.float64))  # metres off
    gaps = [0.1, 0.3, 0.5, 0.7, 0.9]
    val = {
        p: {m: [50.0] * 5 for m in ("lerp", "limb", "spline", "pchip")} | {"xmae": [1.0] * 5}
        for p in ("full", "arm", "leg")
    }
    x = takes[0][0].copy()
    x[60:75] = np.nan  # one 0.5-s full-body hole of its own
    policy, note = FillPolicy(gaps, val, None).fit(takes, body, far, holes_of=([x], 30.0))
    assert "stopped measuring a fill early" in note
    assert policy.error_mm["full"]["xmae"][2] == float("inf") and not is_learned(policy.choose("full", 0.5))


def test_a_candidate_ahead_take_by_take_over_many_takes_is_proven_on_few_holes_and_not_on_one_take():
    """proven(): the per-take mean of (error - margin x the preferred fill's), below 0 by TRUST_Z
    standard errors over TRUST_TAKES takes or more. Holes of one take never prove anything,
    however many; a candidate ahead on average but behind in many takes is not proven."""
    from mocapfix.fills.errors import ErrorSums
    from mocapfix.fills.policy import TRUST_TAKES, proven

    rng = np.random.default_rng(0)

    def sums(takes: list, model_ratio: np.ndarray) -> ErrorSums:
        e = ErrorSums([0.9])
        limb = 0.05 + 0.03 * rng.random(len(takes))
        e.holes = {("full", 0.9, "limb"): list(limb), ("full", 0.9, "correction"): list(model_ratio * limb)}
        e.hole_takes = {("full", 0.9): takes}
        return e

    many = [k // 2 for k in range(2 * TRUST_TAKES + 4)]  # two holes in each of 10 takes
    assert proven(sums(many, np.full(len(many), 0.8))) == {("full", 0.9, "correction")}
    one = ["take"] * 60
    assert proven(sums(one, np.full(60, 0.5))) == set()  # one take, however many holes
    mixed = np.where(np.arange(len(many)) % 4 < 2, 0.6, 1.2)  # -20 % on average, +20 % in half the takes
    assert proven(sums(many, mixed)) == set()
    few = many[: 2 * (TRUST_TAKES - 1)]  # ahead everywhere, but in fewer than TRUST_TAKES takes
    assert proven(sums(few, np.full(len(few), 0.5))) == set()


def test_a_model_ahead_in_every_take_of_a_folder_takes_a_kind_with_fewer_cut_holes_than_trusted():
    """Ten 4-s takes have room for fewer than TRUSTED_HOLES cut 0.9-s holes; a model exact on each
    of them (ahead take by take) takes the kind, and the report says on what evidence."""
    from mocapfix.core.skeleton import preset
    from mocapfix.fills.fill import Fill
    from mocapfix.fills.policy import TRUSTED_HOLES, FillPolicy
    from mocapfix.io.synthetic import generate_clips
    from mocapfix.rig.mapping import onto_skeleton

    body = preset("body21")
    takes = [(onto_skeleton(c, body).positions.astype(np.float64), 30.0) for c in generate_clips(10, 4.0, 30.0, seed=8)]

    class Oracle(Fill):  # the take's truth, found by its observed tokens
        names = ("xmae",)

        def fill(self, positions, observed, fps, skeleton, asked=None, shared=None):
            out = []
            for x, o in zip(positions, observed):
                truth = next(t for t, _ in takes if len(t) == len(x) and np.allclose(t[o.numpy()], x[o].numpy()))
                out.append(torch.from_numpy(truth))
            return {"xmae": torch.stack(out)}

    x = takes[0][0].copy()
    x[40:67] = np.nan  # a 0.9-s full-body hole of its own
    val = {p: {m: [50.0] * 5 for m in ("lerp", "limb", "spline", "pchip", "xmae")} for p in ("full", "arm", "leg")}
    policy, note = FillPolicy([0.1, 0.3, 0.5, 0.7, 0.9], val, None).fit(takes, body, Oracle(), holes_of=([x], 30.0))
    cut = int(note.split("(")[1].split(" holes")[0])
    assert cut < TRUSTED_HOLES and policy.choose("full", 0.9) == "xmae"
    assert "taken on fewer holes, ahead take by take" in note and "full 0.9s" in note
