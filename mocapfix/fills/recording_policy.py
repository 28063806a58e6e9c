"""The fill policy measured on the recording being fixed, not only on the model's val split.

A model's val split shares performers, motions and the studio with its training split, so the
policy calibrated there (fills/policy.py) believes the model where it has learned a studio,
not human motion: a paper-sized XMAE trained on 70 CMU takes beat the classical fills on its val
split and was 2.5x worse than a cubic spline on other performers. The recording itself is the
only evidence about the recording: holes of the kinds it has (body part and length) are cut into
it where the part is observed, the model and every classical fill fill them exactly as fix fills
the recording's own holes (the model through its windows, blended and anchored on the data; the
classical fills with the take's whole context), and the policy is the one those errors give.
A kind of hole with too few places to cut it gets the classical fills only: the model has not
earned its place there. The val split ranks the classical fills otherwise (1-s windows leave
0.05 s of context around a 0.9-s hole, and Lerp wins there; on whole CMU takes it is the worst
of the four, 94 mm against the limb fill's 68), and the model against them (the stretches of an
earlier version, 2 s with 0.5 s of context, let a model win cells it lost on the take's holes,
where the classical fills had seconds of context).
"""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.fills.classical import CLASSICAL
from mocapfix.fills.motion_matching import MotionLibrary, match_fills, mirror_of
from mocapfix.fills.policy import (
    PARTS,
    Calibration,
    FillPolicy,
    hole_frames,
    is_learned,
    token_parts,
)

HOLES_PER_CELL = 64  # the budget of holes cut into the recording per (part, gap): a model pass each kind
# A hole is cut only where its joints are observed this long on both sides. Cut right next to
# one of the recording's own holes, it is a hole twice as long for the classical fills, and the
# fills that need the least context win (measured on CMU takes with 0.7-s holes: with a frame of
# context each side the mean of the limb fill and PCHIP came out 3 % ahead of the limb fill,
# and was 2 % behind it on the recording's holes; with 0.1 s the limb fill ranked first, as there).
CONTEXT_S = 0.1
# The classical fill kept unless another classical candidate measures PREFERRED_MARGIN better:
# the limb fill (bone lengths kept, the parent followed) was the best classical fill in 14 of 15
# cells on CMU takes (PCHIP by 0.01 mm at 0.1 s) and at 0.3-0.9 s on Bandai, while the ranking
# of near-ties changes from one set of holes to another (a blend measured 3 % ahead on the cut
# holes was 9 % behind on the take's own 0.5-s leg holes). A fill much better here still wins.
PREFERRED = "limb"
PREFERRED_MARGIN = 0.95
# Fewer holes of a kind than this (one short take): the preferred fill only among the classical
# ones. Within one take the motion differs from place to place: on 14 CMU takes, each measured
# alone on its 10-20 cut holes, PCHIP came out 20 % ahead of the limb fill in one take and was
# twice as bad on that take's own 0.5-s leg holes; over a folder's takes the ranking held.
# The model takes a kind of hole on the same evidence: on one 12-s take, 8-39 cut holes of a kind
# let XMAE's blend win a 0.7-s leg cell it then lost on the take's own hole (`mocapfix demo`, its
# synthetic take: 123.6 mm against the limb fill's 92.4).
TRUSTED_HOLES = 40


def hole_kinds(tracks: list[np.ndarray], skeleton, fps: float, gaps_s) -> set[tuple[str, float]]:
    """The (part, measured gap) cells the recording's holes fall in (as apply_fill_policy reads them)."""
    kinds = set()
    for x in tracks:
        observed = torch.from_numpy(np.isfinite(x).all(-1))[None]  # (1, K, J)
        if observed.all():
            continue
        seconds = hole_frames(observed).float() / fps
        parts = token_parts(observed, skeleton)
        for part, s in zip(parts[~observed].tolist(), seconds[~observed].tolist()):
            kinds.add((PARTS[part], min(gaps_s, key=lambda g: abs(g - s))))
    return kinds


def cut_holes(observed: np.ndarray, options: list[list[int]], frames: int, budget: int, margin: int = 1) -> np.ndarray:
    """observed: (T, J) bool -> (T, J) bool, up to `budget` holes of `frames` frames, spread over
    the take, each over the joints of one of `options` in turn (left and right alternate), only
    where those joints are observed for `margin` frames before and after the hole, margins
    included in no other cut hole (each has data at both ends, as the recording's own holes)."""
    T = len(observed)
    hidden = np.zeros_like(observed)
    taken = np.zeros(T, dtype=bool)  # frames in a cut hole
    valid = []
    for joints in options:
        seen = observed[:, joints].all(-1).astype(np.int64)
        run = np.convolve(seen, np.ones(frames + 2 * margin, dtype=np.int64), mode="valid")
        valid.append(np.nonzero(run == frames + 2 * margin)[0] + margin)  # hole starts
    for k in range(budget):
        starts = valid[k % len(options)]
        # the k-th hole of this option near its share of the take, the nearest free place
        want = (k // len(options) + 0.5) / -(-budget // len(options)) * T
        for s in starts[np.argsort(np.abs(starts - want))]:
            if not taken[s - margin : s + frames + margin].any():
                hidden[s : s + frames, options[k % len(options)]] = True
                taken[s : s + frames] = True
                break
    return hidden


def measure_on_takes(
    takes: list[tuple[np.ndarray, float]],
    skeleton,
    gaps_s,
    cells=None,
    model_fill=None,
    map_takes=None,
    keys=None,
    library: MotionLibrary | None = None,
) -> tuple[FillPolicy | None, dict[tuple[str, float], int]]:
    """takes: (x (T, J, 3) NaN = missing, fps) per clip, at the model's joints and the input's fps;
    model_fill(x, fps) -> (T, J, 3) the model's fill as fix makes it (None: classical fills only)
    -> (every fill and the mean of every two, by part and gap, over holes cut into the takes,
    inf where none could be cut; the holes cut per (part, gap)). cells: only these (part, gap),
    None: all. map_takes(jobs) -> results: how the takes' measure_take(*job) calls run (default:
    one after another here; fix --jobs hands them to its workers); each take is measured alone
    and the sums are added up in the takes' order, so the result is the same either way.
    The motion-matching fills search the takes (keys: one per take, as fix names them to its
    MotionLibrary; default their order), each take's own with its holes cut, and `library`
    (the user's other takes, fix --library)."""
    calibration = Calibration(gaps_s)
    budget = -(-HOLES_PER_CELL // max(1, len(takes)))
    keys = list(range(len(takes))) if keys is None else list(keys)
    library = MotionLibrary(takes, keys, mirror_of(skeleton)) if library is None else library.including(takes, keys)
    gaps = tuple(calibration.gaps_s)
    jobs = [(x, fps, skeleton, gaps, cells, budget, library, key) for (x, fps), key in zip(takes, keys)]
    if map_takes is None:
        results = [measure_take(*job, model_fill=model_fill) for job in jobs]
    else:
        results = map_takes(jobs)
    cut: dict[tuple[str, float], int] = {}
    for sums, take_cut in results:
        for key, (total, count) in sums.items():
            s = calibration.sums.setdefault(key, [0.0, 0])
            s[0] += total
            s[1] += count
        for cell, n in take_cut.items():
            cut[cell] = cut.get(cell, 0) + n
    return calibration.compute(), cut


def measure_take(
    x: np.ndarray, fps: float, skeleton, gaps_s, cells, budget: int, library=None, key=None, model_fill=None
):
    """One take's share of measure_on_takes: up to `budget` holes of each kind cut into x (T, J, 3)
    and every fill's error there -> (Calibration sums, holes cut per (part, gap)). library: a
    MotionLibrary (its take `key` left out: this one is searched with its holes cut), None: no
    motion-matching fills."""
    calibration = Calibration(gaps_s)
    options = {"full": [list(range(skeleton.num_joints))]}
    for group, members in sorted(skeleton.groups.items()):
        options.setdefault(group.split("_")[-1], []).append(list(members))
    observed = np.isfinite(x).all(-1)
    truth = torch.from_numpy(x.astype(np.float64))[None]
    searched = None if library is None else library.without(key, fps)  # this take: searched with its holes cut
    cut: dict[tuple[str, float], int] = {}
    for part in PARTS:
        for gap in gaps_s:
            if part not in options or (cells is not None and (part, gap) not in cells):
                continue
            hidden = cut_holes(
                observed, options[part], max(1, round(gap * fps)), budget, max(1, round(CONTEXT_S * fps))
            )
            if not hidden.any():
                continue
            cut[(part, gap)] = int((np.diff(hidden.any(-1).astype(np.int64), prepend=0) == 1).sum())
            holed = truth.masked_fill(torch.from_numpy(hidden)[None, ..., None], float("nan"))
            obs = torch.from_numpy(observed & ~hidden)[None]
            fills = {name: fill(holed, obs, skeleton.parents) for name, fill in CLASSICAL.items()}
            if searched is not None:
                found = match_fills(holed[0].numpy(), obs[0].numpy(), fills["hermite"][0].numpy(), searched, fps)
                fills.update({name: torch.from_numpy(f)[None] for name, f in found.items()})
            if model_fill is not None:
                fills["xmae"] = torch.from_numpy(model_fill(holed[0].numpy(), fps)).double()[None]
            calibration.add_fills(part, gap, fills, truth, torch.from_numpy(hidden)[None])
    return calibration.sums, cut


def measure_policy(
    fixer,
    tracks: list[np.ndarray],
    takes: list[tuple[np.ndarray, float]],
    fallback: FillPolicy | None,
    model_fill,
    every_cell: bool = False,
    map_takes=None,
    keys=None,
    library: MotionLibrary | None = None,
) -> tuple[FillPolicy | None, str | None]:
    """The fill policy of this recording for a positions fixer (.skeleton, .fps); tracks: its clips
    at the model's joints and fps (the kinds of hole it has, as apply_fill_policy reads them);
    takes: (x, fps) the same at the input's fps; model_fill(x, fps) -> the model's fill as fix
    makes it; map_takes, keys, library: measure_on_takes'. -> (policy, a line for the report).
    Only the kinds of hole the recording has are measured (every_cell: all, for a run's policy in
    --mode both, whose jumps make holes of any kind); the others keep the fallback's numbers, the
    classical ones only where nothing of the recording could be measured. A kind with fewer than
    TRUSTED_HOLES cut holes gets the preferred classical fill (neither the model nor another
    classical fill has earned its place there). Nothing is measured for
    a checkpoint without a policy (its model fills every hole, as documented)."""
    if fallback is None:
        return None, None
    gaps = tuple(fallback.gaps_s)
    cells = None if every_cell else hole_kinds(tracks, fixer.skeleton, fixer.fps, gaps)
    if cells is not None and not cells:  # no hole to fill
        return fallback, None
    measured, cut = measure_on_takes(takes, fixer.skeleton, gaps, cells, model_fill, map_takes, keys, library)
    asked = sorted(cells) if cells is not None else [(p, g) for p in PARTS for g in gaps]
    earned = {cell for cell in asked if cut.get(cell, 0) >= TRUSTED_HOLES}

    # Per method and cell: what the recording measured, else the val split's number; the model's
    # candidates only in cells with TRUSTED_HOLES holes measured.
    base = fallback if earned else _classical_only(fallback)
    tables = {part: {m: list(e) for m, e in t.items()} for part, t in base.error_mm.items()}
    for part, here in (measured.error_mm if measured is not None else {}).items():
        for method, errors in here.items():  # fills the checkpoint's policy did not measure (older ones)
            tables.setdefault(part, {}).setdefault(method, list(errors))
    for part, table in tables.items():
        here = measured.error_mm.get(part, {}) if measured is not None else {}
        for method, errors in table.items():
            for i, g in enumerate(gaps):
                if is_learned(method) and (part, g) in asked and (part, g) not in earned:
                    errors[i] = float("inf")
                elif (
                    not is_learned(method)
                    and method != PREFERRED
                    and PREFERRED in table
                    and 0 < cut.get((part, g), 0) < TRUSTED_HOLES
                ):
                    errors[i] = float("inf")  # too few holes to overrule the preferred fill
                elif method in here and np.isfinite(here[method][i]):
                    errors[i] = here[method][i]
    out = FillPolicy(
        gaps,
        tables,
        fallback.replace_threshold_m,
        fallback.windows,
        ["measured on the recording"],
        (PREFERRED, PREFERRED_MARGIN),
    )
    chosen = ", ".join(f"{p} {g:g}s {out.best(p, g)}" for p, g in asked if (p, g) in cut)
    holes = sum(cut.values())
    evidence = f"{holes} holes cut into it" + (
        "" if earned else f"; classical fills only: fewer than {TRUSTED_HOLES} holes of a kind"
    )
    return out, f"fill policy measured on this recording ({evidence}): {chosen or 'nothing could be cut'}"


def _classical_only(policy: FillPolicy) -> FillPolicy:
    """The policy with the model's candidates taken out: the classical fills as it ranks them."""
    tables = {part: {m: e for m, e in t.items() if not is_learned(m)} for part, t in policy.error_mm.items()}
    return FillPolicy(policy.gaps_s, tables, policy.replace_threshold_m, policy.windows, ["classical only"])
