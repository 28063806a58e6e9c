"""The fill policy: which fill fills each hole, and which observed tokens a model may replace,
decided on held-out data so that mocapfix never outputs worse than the best classical fill.
An estimator with scikit-learn's shape, its fitted state plain values (to_dict / from_dict: a
checkpoint's `fill_policy`, models/checkpoint.py): fit (on the val split's windows, Calibration;
on holes cut into recordings, FillPolicy.fit), then choose (the candidate for a kind of hole) and
transform (a take's holes filled by the Fills handed in, fills/fill.py).

A small model can lose to a cubic spline on short holes and win on long ones; a large one can
lose at 0.1 s and win everywhere else. So the model's error and each classical fill's error are
measured per hole length and body part on the validation split (Calibration, from a training
module's validation) and stored in the checkpoint (FillPolicy.to_dict). `fix` and the test
tables then fill each hole with the method that was best for holes of its length and part, and
replace an observed token only where the model disagrees with it by more than the model ever
does with clean data (replace_threshold_m).

A candidate is a single method ("spline") or the mean of two ("limb+spline"): two fills that err
in different directions average to a smaller error than either (a spline overshoots where the
limb fill bends), and which pair that is differs by hole length and part, so it is measured too.
A stack ("correction*match_delta", fill.py STACK) goes further where both fills step from the
same Hermite fill: each step weighted by least squares on the recording's cut holes (errors.py,
held out by take), the weights kept per kind of hole (`stacks`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache

import numpy as np
import torch
from scipy.special import stdtrit

from mocapfix.core.skeleton import Skeleton
from mocapfix.fills.errors import ErrorSums, measure_on_takes, take_numbers
from mocapfix.fills.fill import BLEND, STACK, Fill, components, made_for_choice, pick, stacked
from mocapfix.fills.holes import PARTS, hole_kinds, token_cells, token_choice

LEARNED = ("xmae", "correction")  # the candidates that are models; every other is a classical fill
CLEAN_QUANTILE = 0.995  # of the model's disagreement with clean observed tokens: above it, a token is suspect
MODEL_MARGIN = 0.98  # a model fills a hole only where its val error is 2 % below the best classical fill's
BLEND_MARGIN = 0.99  # a blend of classical fills only where 1 % below the best single one (in doubt, the simpler)

# RECORDINGS: the policy fitted again on the recording being fixed, not only on the val split.
# A model's val split shares performers, motions and the studio with its training split, so the
# policy calibrated there believes the model where it has learned a studio, not human motion: a
# paper-sized XMAE trained on 70 CMU takes beat the classical fills on its val split and was 2.5x
# worse than a cubic spline on other performers. The recording itself is the only evidence about
# the recording: holes of the kinds it has (body part and length) are cut into it where the part
# is observed, the model and every classical fill fill them exactly as fix fills the recording's
# own holes (errors.py), and the policy is the one those errors give. A kind of hole with too few
# places to cut it gets the classical fills only: the model has not earned its place there. The
# val split ranks the classical fills otherwise (1-s windows leave 0.05 s of context around a
# 0.9-s hole, and Lerp wins there; on whole CMU takes it is the worst of the four, 94 mm against
# the limb fill's 68), and the model against them (the stretches of an earlier version, 2 s with
# 0.5 s of context, let a model win cells it lost on the take's holes, where the classical fills
# had seconds of context).
#
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
# Fewer holes than that still let another candidate take a kind where the evidence comes from
# many takes: below its margin times the preferred fill's error take by take (each take's holes
# averaged: holes of one take share its motion, and one take's cut holes can mislead about its
# own, as above), a one-sided t-test over TRUST_TAKES takes or more at TRUST_CONFIDENCE (the
# usual 95 % two-sided level; proven). Bandai's 30 test takes have room for 29 cut 0.9-s holes
# (in 8 of them), where a correction trained on the capture is 20 % below the best classical fill.
TRUST_TAKES = 8
TRUST_CONFIDENCE = 0.975


@cache  # asked of the same few dozen names for every cell of every file's policy
def is_learned(method: str) -> bool:
    """A candidate with a model in it (a model alone, or a model averaged or stacked with other fills)."""
    return any(m in LEARNED for m in components(method))


@dataclass
class FillPolicy:
    gaps_s: list[float]  # the hole lengths measured, ascending
    error_mm: dict[str, dict[str, list[float]]]  # part -> method -> MPJPE per gap (val split)
    replace_threshold_m: float | None = None  # None: never replace an observed token
    windows: int = 0  # val windows it was measured on
    notes: list[str] = field(default_factory=list)
    # (method, margin): this classical fill unless another classical candidate's error is below
    # margin x its error (near-ties rank differently on other holes); None: the lowest error
    preferred: tuple[str, float] | None = None
    # part -> stack (fill.py STACK) -> per gap its weights, one per step (None: not measured there)
    stacks: dict[str, dict[str, list[list[float] | None]]] = field(default_factory=dict)

    @classmethod
    def preferred_only(cls, gaps_s) -> FillPolicy:
        """A policy with nothing measured yet: the preferred classical fill for every hole until
        holes cut into the recording say otherwise (fit). A model without a val-split policy
        (a learned correction) has earned no hole before the recording measures it."""
        gaps = sorted(float(g) for g in gaps_s)
        tables = {part: {PREFERRED: [float("inf")] * len(gaps)} for part in PARTS}
        return cls(gaps, tables, None, 0, ["nothing measured"], (PREFERRED, PREFERRED_MARGIN))

    def choose(self, part: str, gap_s: float) -> str:
        """The method with the lowest error for holes of this part, at the measured length nearest
        gap_s; a blend of classical fills only where it beats the best single one by BLEND_MARGIN,
        the model (or a blend with it) only where it beats the best classical fill by MODEL_MARGIN
        (in doubt, the fill whose behaviour a user knows); the preferred classical fill, where one
        is set, unless another classical candidate beats it by its margin."""
        table = self.error_mm.get(part) or self.error_mm["full"]
        i = min(range(len(self.gaps_s)), key=lambda k: abs(self.gaps_s[k] - gap_s))
        singles = [m for m in table if not is_learned(m) and BLEND not in m]
        mixed = [m for m in table if not is_learned(m) and BLEND in m]
        best = min(singles, key=lambda m: table[m][i]) if singles else None
        blend = min(mixed, key=lambda m: table[m][i]) if mixed else None
        if best is None or (blend is not None and table[blend][i] < BLEND_MARGIN * table[best][i]):
            best = blend
        if self.preferred is not None and self.preferred[0] in table:
            keep, margin = self.preferred
            if best is None or table[best][i] >= margin * table[keep][i]:
                best = keep
        model = min((m for m in table if is_learned(m)), key=lambda m: table[m][i], default=None)
        if best is None or (model is not None and table[model][i] < MODEL_MARGIN * table[best][i]):
            return model
        return best

    def methods(self) -> list[str]:
        """The single fills its candidates are made of (those it measured)."""
        return sorted({c for table in self.error_mm.values() for m in table for c in m.split(BLEND)})

    def chosen(self) -> list[str]:
        """The candidates it chooses for some kind of hole (those transform makes), sorted."""
        return sorted({self.choose(p, g) for p in PARTS for g in self.gaps_s})

    def table(self, names: list[str]) -> torch.Tensor:
        """(parts, gaps) long: the index into names of the candidate chosen for each cell."""
        return torch.tensor([[names.index(self.choose(p, g)) for g in self.gaps_s] for p in PARTS])

    def transform(
        self,
        positions: torch.Tensor,
        observed: torch.Tensor,
        fps: float,
        skeleton: Skeleton,
        fills: list[Fill],
        counted: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, dict[str, int]]:
        """positions (B, T, J, 3), observed (B, T, J) -> each hole filled by the candidate chosen
        for its part and length (observed tokens as given), and the tokens each candidate filled
        in the joints `counted` ((J,) bool; None: all of them). fills: the Fills it may take them
        from; only those it chooses are run."""
        names = self.chosen()
        table = self.table(names)
        cells = token_cells(observed, fps, skeleton, self.gaps_s)  # ((B, T, J) part, (B, T, J) gap)
        choice = table.to(observed.device)[cells]
        candidates = made_for_choice(fills, positions, observed, fps, skeleton, names, choice)
        for name in [m for m in names if STACK in m]:
            origin, *steps = components(name)
            weights = self._stack_weights(name).to(positions.device, candidates[origin].dtype)[cells]  # (B, T, J, K)
            candidates[name] = stacked(candidates[origin], [candidates[m] for m in steps], weights)
        out, chosen = pick(candidates, names, choice, positions, observed)
        chosen = chosen if counted is None else chosen[..., counted]
        counts = torch.bincount(chosen[chosen >= 0], minlength=len(names)).tolist()
        return out, {names[i]: n for i, n in enumerate(counts) if n}

    def fit(
        self,
        takes: list[tuple[np.ndarray, float]],
        skeleton: Skeleton,
        model_fill: Fill | None,
        holes_of: tuple[list[np.ndarray], float] | None = None,
        map_takes=None,
        keys=None,
        library=None,
    ) -> tuple[FillPolicy, str | None]:
        """This policy fitted again on holes cut into recordings (see RECORDINGS below) -> (the
        policy, a line for the report). takes: (x (T, J, 3) at the skeleton's joints, NaN =
        missing, fps); model_fill: the model's Fill as fix fills (None: none); holes_of: (the
        takes at the model's frames, its fps): only the kinds of hole they have are measured (None:
        every kind, for a run's policy in --mode both, whose jumps make holes of any kind), the
        others keep this policy's numbers, the classical ones only where nothing of the recording
        could be measured. A kind with fewer than TRUSTED_HOLES cut holes gets the preferred
        classical fill (neither the model nor another classical fill has earned its place there)
        unless a candidate is ahead of it take by take (proven); every candidate but the preferred
        fill is screened after the first holes (hopeless), and a kind left with the preferred fill
        alone is settled (no more of its holes cut; it counts as earned).
        map_takes, keys, library: errors.measure_on_takes'."""
        gaps = tuple(self.gaps_s)
        cells = None if holes_of is None else hole_kinds(holes_of[0], skeleton, holes_of[1], gaps)
        if cells is not None and not cells:  # no hole to fill
            return self, None
        errors, cut = measure_on_takes(takes, skeleton, gaps, cells, model_fill, map_takes, keys, library, hopeless)
        measured = errors.tables() if errors.sums else None
        asked = sorted(cells) if cells is not None else [(p, g) for p in PARTS for g in gaps]
        # a kind every other fill left early (hopeless) has its choice, the preferred fill, on
        # fewer holes: what the others' holes would have told is that they are behind
        screened = {(p, g) for p, g, _ in errors.dropped}
        settled = {cell for cell in screened if {m for p, g, m in errors.sums if (p, g) == cell} == {PREFERRED}}
        earned = {cell for cell in asked if cut.get(cell, 0) >= TRUSTED_HOLES or cell in settled}
        ahead = proven(errors)
        base = self if earned or ahead else self._classical_only()
        tables = _with_measured(base.error_mm, measured or {}, gaps, asked, earned, cut, ahead)
        stacks: dict[str, dict[str, list[list[float] | None]]] = {}
        for (part, gap, name), weights in errors.stack_weights.items():
            stacks.setdefault(part, {}).setdefault(name, [None] * len(gaps))[gaps.index(gap)] = weights
        out = FillPolicy(
            gaps,
            tables,
            self.replace_threshold_m,
            self.windows,
            ["measured on the recording"],
            (PREFERRED, PREFERRED_MARGIN),
            stacks,
        )
        chosen = ", ".join(f"{p} {g:g}s {out.choose(p, g)}" for p, g in asked if (p, g) in cut)
        evidence = f"{sum(cut.values())} holes cut into it" + (
            "" if earned else f"; classical fills only: fewer than {TRUSTED_HOLES} holes of a kind"
        )
        few = [f"{p} {g:g}s" for p, g in asked if (p, g) not in earned and (p, g, out.choose(p, g)) in ahead]
        if few:
            evidence += f"; taken on fewer holes, ahead take by take over {TRUST_TAKES}+ takes: {', '.join(few)}"
        if screened - settled:
            evidence += f"; {len(screened - settled)} kinds stopped measuring a fill early"
        if settled:
            evidence += f"; {len(settled)} kinds settled early (every other fill behind the {PREFERRED} fill)"
        return out, f"fill policy measured on this recording ({evidence}): {chosen or 'nothing could be cut'}"

    def _stack_weights(self, name: str) -> torch.Tensor:
        """(parts, gaps, K) float64: a stack's weights per cell (zero where it was not measured: its
        origin, which it is chosen nowhere there)."""
        steps = len(components(name)) - 1
        out = torch.zeros(len(PARTS), len(self.gaps_s), steps, dtype=torch.float64)
        for p, part in enumerate(PARTS):
            for i, w in enumerate(self.stacks.get(part, {}).get(name, [None] * len(self.gaps_s))):
                if w is not None:
                    out[p, i] = torch.tensor(w, dtype=torch.float64)
        return out

    def _classical_only(self) -> FillPolicy:
        """This policy with the model's candidates taken out: the classical fills as it ranks them."""
        tables = {part: {m: e for m, e in t.items() if not is_learned(m)} for part, t in self.error_mm.items()}
        return FillPolicy(self.gaps_s, tables, self.replace_threshold_m, self.windows, ["classical only"])

    def describe(self) -> list[str]:
        """One line per part: the method chosen at each measured gap, with its error and the best
        classical fill's."""
        lines = []
        for part, table in self.error_mm.items():
            cells = []
            for i, g in enumerate(self.gaps_s):
                m = self.choose(part, g)
                classical = min(v[i] for k, v in table.items() if not is_learned(k))
                cells.append(f"{g:g}s {m} {table[m][i]:.1f} (classical {classical:.1f})")
            lines.append(f"{part}: " + ", ".join(cells))
        if self.replace_threshold_m is not None:
            lines.append(
                f"observed tokens replaced where the model disagrees by more than "
                f"{1000 * self.replace_threshold_m:.0f} mm"
            )
        return lines

    def to_dict(self) -> dict:
        """Plain values (a checkpoint loaded with weights_only=True holds nothing else)."""
        return {
            "gaps_s": list(self.gaps_s),
            "error_mm": self.error_mm,
            "replace_threshold_m": self.replace_threshold_m,
            "windows": self.windows,
            "notes": list(self.notes),
            "preferred": list(self.preferred) if self.preferred else None,
            "stacks": self.stacks,
        }

    @classmethod
    def from_dict(cls, d: dict) -> FillPolicy:
        return cls(
            [float(g) for g in d["gaps_s"]],
            d["error_mm"],
            d.get("replace_threshold_m"),
            int(d.get("windows", 0)),
            list(d.get("notes", [])),
            (str(d["preferred"][0]), float(d["preferred"][1])) if d.get("preferred") else None,
            d.get("stacks") or {},
        )


def _with_measured(base: dict, measured: dict, gaps, asked, earned, cut, ahead=frozenset()) -> dict:
    """A policy's error tables with what the recording measured (FillPolicy.fit): per candidate
    and cell the recording's number, else the val split's; the model's candidates only in cells
    with TRUSTED_HOLES holes measured, the classical ones other than the preferred fill only in
    cells where none or TRUSTED_HOLES holes could be cut; either where it is proven (`ahead`:
    (part, gap, method), proven())."""
    tables = {part: {m: list(e) for m, e in t.items()} for part, t in base.items()}
    for part, here in measured.items():
        for method, errors in here.items():  # fills the checkpoint's policy did not measure (older ones)
            tables.setdefault(part, {}).setdefault(method, list(errors))
    for part, table in tables.items():
        here = measured.get(part, {})
        for method, errors in table.items():
            for i, g in enumerate(gaps):
                if (
                    is_learned(method)
                    and (part, g) in asked
                    and (part, g) not in earned
                    and (part, g, method) not in ahead
                ):
                    errors[i] = float("inf")
                elif (
                    not is_learned(method)
                    and method != PREFERRED
                    and PREFERRED in table
                    and 0 < cut.get((part, g), 0) < TRUSTED_HOLES
                    and (part, g, method) not in ahead
                ):
                    errors[i] = float("inf")  # too few holes to overrule the preferred fill
                elif method in here and (np.isfinite(here[method][i]) or cut.get((part, g), 0) > 0):
                    errors[i] = here[method][i]  # where holes were cut, inf too: screened out (hopeless)
    return tables


# A candidate is screened out of a kind of hole (hopeless) where, by its holes so far, what
# it could gain over what it must beat is below SCREEN_TOLERANCE of the preferred fill's error at
# SCREEN_Z standard errors of the paired per-hole differences: it is either behind, or so near
# that choosing it would change the fill's error by less than that. On the 16 holed CMU takes and
# 200 Bandai takes (every kind measured on all its holes, then screened after every 16 as fix
# does) this changed no kind's choice and ran motion matching on 12-24 % fewer holes, the model on
# 24-25 % fewer, than one screen after 16 holes at 3 standard errors with no tolerance. (An
# absolute tolerance, 0.5 mm, screened a correction out of Human3.6M's 0.3-s arm holes, where it
# was 15 % ahead of the limb fill by 0.4 mm.) Besides the preferred fill's margin, a candidate must
# beat the others choose() would take over it (_bars), with no tolerance there (near-ties between
# two candidates are choose()'s to settle: with the 1 % a 0.1-s cell of the 16 CMU copies moved
# from hermite+pchip to pchip). Each kind is screened on its own first 16 holes (screening_phases:
# on the 16 CMU copies the arm and leg kinds' first screen came at 13-17 holes, where every kind's
# came at 26-31 when a phase waited for the slowest kind; the full-body kinds' still at 28-30, a
# take's share of them coming at once); the 16 holed CMU takes and 200 Bandai takes kept every
# choice, the copies all but a 0.1-s cell (hermite+pchip -> pchip; no hole of that kind in them).
SCREEN_Z = 2.0
SCREEN_TOLERANCE = 0.01


def hopeless(errors: ErrorSums, fills: list[tuple[str, ...]]) -> dict[tuple[str, float], set[str]]:
    """The fills (each a tuple of candidate names: motion matching's, a model's, a classical
    fill's) that a kind of hole can stop measuring (errors.measure_on_takes' screen) -> {(part,
    gap): names}; never the preferred fill. A fill goes where every candidate with it in (blends
    too), hole by hole over the holes measured so far, cannot gain more than SCREEN_TOLERANCE of
    the preferred fill's error over one of the bars choose() sets it (_bars: the preferred fill's
    error times a margin, or another candidate's that it would have to beat), but for a
    SCREEN_Z-standard-error chance. Paired per hole: the holes differ far more from each other than
    the fills on one hole do. A kind every other fill has left is settled: the preferred fill is
    its choice, and no more holes of it are cut."""
    out: dict[tuple[str, float], set[str]] = {}
    for part, gap in sorted({(p, g) for p, g, _ in errors.holes}):
        preferred = np.array(errors.holes.get((part, gap, PREFERRED), []))
        if len(preferred) < 3:
            continue
        kind = {m: e for (p, g, m), e in errors.holes.items() if (p, g) == (part, gap)}
        here = {m: e for m, e in kind.items() if len(e) == len(preferred)}  # measured on every hole
        names = list(here)
        errs = np.array([here[m] for m in names])  # (C, H)
        factor = _bars(names, errs, preferred)  # (C, C + 1)
        bars = np.concatenate([errs, preferred[None]])  # (C + 1, H)
        d = errs[:, None] - factor[..., None] * bars[None]  # (C, C + 1, H) positive: behind the bar
        gain = _upper(-d)  # (C, C + 1)
        tol = np.where(np.arange(factor.shape[1]) == len(names), SCREEN_TOLERANCE * preferred.mean(), 0.0)
        behind = {m for m, row in zip(names, (gain < tol) & (factor > 0)) if row.any()}
        for fill in fills:
            if PREFERRED in fill:
                continue
            candidates = [m for m in kind if set(components(m)) & set(fill)]
            if candidates and all(m in behind for m in candidates):
                out.setdefault((part, gap), set()).update(fill)
    return out


def _bars(names: list[str], errors: np.ndarray, preferred: np.ndarray) -> np.ndarray:
    """What choose() asks of each candidate before it can be chosen: names (C,) the candidates
    measured on a kind's holes, errors (C, H) their per-hole errors, preferred (H,) the preferred
    fill's -> (C, C + 1) factors: candidate m is never chosen where its error is at or above factor
    [m, c] times candidate c's (column C: the preferred fill's); 0: no bar. Necessary conditions:
    - a model (or a blend with it) below MODEL_MARGIN times the chosen classical candidate's, which
      is at most the preferred fill's, and at most a classical single fill's that is below
      PREFERRED_MARGIN times the preferred fill's (then no fallback to it; a blend's, 1 /
      BLEND_MARGIN times it), such a candidate found at SCREEN_Z standard errors;
    - a classical candidate below PREFERRED_MARGIN times the preferred fill's, and below every other
      classical single fill's (a single) or blend's (a blend) error; a single below 1 / BLEND_MARGIN
      times every blend's (else the blend is chosen), a blend below BLEND_MARGIN times every single's."""
    learned = np.array([is_learned(m) for m in names])
    blend = np.array([BLEND in m for m in names])
    factor = np.zeros((len(names), len(names) + 1))
    factor[:, -1] = [_margin(m) for m in names]
    same = blend[:, None] == blend[None, :]
    classical = ~learned[:, None] & ~learned[None, :] & ~np.eye(len(names), dtype=bool)
    factor[:, :-1] = np.where(
        classical, np.where(same, 1.0, np.where(blend[:, None], BLEND_MARGIN, 1 / BLEND_MARGIN)), 0
    )
    # the classical candidates surely below the preferred fill's margin: a bound on the chosen one's error
    ceiling = np.where(blend, 1 / BLEND_MARGIN, 1.0)  # (C,) the chosen classical candidate's error <= this x theirs
    d = ceiling[:, None] * errors - PREFERRED_MARGIN * preferred  # (C, H)
    sure = ~learned & (_upper(d) < 0)
    factor[:, :-1] += np.where(learned[:, None] & sure[None, :], MODEL_MARGIN * ceiling[None, :], 0)
    return factor


def _upper(d: np.ndarray) -> np.ndarray:
    """(..., H) paired per-hole differences -> (...) their mean's bound SCREEN_Z standard errors
    above it."""
    return d.mean(-1) + SCREEN_Z * d.std(-1, ddof=1) / np.sqrt(d.shape[-1])


def proven(errors: ErrorSums) -> set[tuple[str, float, str]]:
    """The (part, gap, method) whose per-hole errors (errors.holes, with the take of each hole)
    are below MODEL_MARGIN (a model) or PREFERRED_MARGIN (a classical candidate) times the
    preferred fill's take by take: each take's mean paired difference, below 0 by Student's t
    at TRUST_CONFIDENCE over at least TRUST_TAKES takes."""
    out = set()
    for (part, gap), takes in errors.hole_takes.items():
        preferred = np.array(errors.holes.get((part, gap, PREFERRED), []))
        if len(preferred) != len(takes):
            continue
        keys = take_numbers(takes)  # (holes,) the take's number
        n = int(keys.max()) + 1 if len(keys) else 0
        if n < TRUST_TAKES:
            continue
        for (p, g, method), e in errors.holes.items():
            if (p, g) != (part, gap) or method == PREFERRED or len(e) != len(takes):
                continue
            d = _over_margin(e, preferred, method)  # (holes,)
            per_take = np.bincount(keys, weights=d, minlength=n) / np.bincount(keys, minlength=n)  # (takes,)
            if per_take.mean() + stdtrit(n - 1, TRUST_CONFIDENCE) * per_take.std(ddof=1) / np.sqrt(n) < 0:
                out.add((p, g, method))
    return out


def _over_margin(errors: list[float], preferred: np.ndarray, method: str) -> np.ndarray:
    """Per-hole errors of `method` less what choose() asks it to beat: its _margin times the
    preferred fill's error on the same hole."""
    return np.array(errors) - _margin(method) * preferred


def _margin(method: str) -> float:
    """The share of the preferred fill's error choose() asks a candidate to be below: MODEL_MARGIN
    (a model, or a blend with one), PREFERRED_MARGIN (a classical candidate)."""
    return MODEL_MARGIN if is_learned(method) else PREFERRED_MARGIN


def apply_fill_policy(
    policy: FillPolicy,
    positions: torch.Tensor,
    observed: torch.Tensor,
    fills: dict[str, torch.Tensor],
    fps: float,
    skeleton: Skeleton,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each missing token from the fill the policy names for its hole; observed tokens as given.

    positions: (B, T, J, 3); observed: (B, T, J) bool; fills: method -> (B, T, J, 3), holding
    every single method of policy.methods() -> (B, T, J, 3), and (B, T, J) the index into
    policy_names(policy, fills) of the candidate each token took (-1 for observed tokens)."""
    names = policy_names(policy, fills)
    choice = token_choice(observed, fps, skeleton, policy.gaps_s, policy.table(names))
    return pick(fills, names, choice, positions, observed)


def policy_names(policy: FillPolicy, fills: dict[str, torch.Tensor]) -> list[str]:
    """The candidates apply_fill_policy may take: the single fills given, then the blends the
    policy names (the index its `chosen` refers to)."""
    return list(fills) + [m for m in policy.chosen() if m not in fills]


class Calibration(ErrorSums):
    """The policy fitted on the val split: accumulates, over validation batches, each candidate's
    error per (part, gap) on infill tasks (ErrorSums) and the model's disagreement with clean
    observed tokens -> FillPolicy (evaluation/policy_fit.py feeds it)."""

    def __init__(self, gaps_s):
        super().__init__(gaps_s)
        self.clean: list[torch.Tensor] = []
        self.windows = 0

    def add_clean(self, estimate: torch.Tensor, positions: torch.Tensor, observed: torch.Tensor) -> None:
        """The model's estimate of windows it saw whole: how far it strays from clean data."""
        self.clean.append((estimate.float() - torch.nan_to_num(positions.float())).norm(dim=-1)[observed].cpu())
        self.windows += len(positions)

    def compute(self) -> FillPolicy | None:
        if not self.sums:
            return None
        threshold = None
        if self.clean:
            d = torch.cat(self.clean)
            if d.numel():
                # a sample is enough for the quantile (torch.quantile refuses very large inputs)
                d = d[torch.randperm(d.numel(), generator=torch.Generator().manual_seed(0))[:1_000_000]]
                threshold = float(torch.quantile(d.double(), CLEAN_QUANTILE))
        return FillPolicy(self.gaps_s, self.tables(), threshold, self.windows)
