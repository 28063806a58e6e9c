"""fills/: every way to fill a hole behind one interface (fills/fill.py's Fill), and the fill
policy as an estimator (fit, choose, transform) whose fitted state is plain values in checkpoints."""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.core.skeleton import preset
from mocapfix.fills.classical import CLASSICAL, classical_fills
from mocapfix.fills.fill import Fill, Made, made
from mocapfix.fills.model import ModelFill
from mocapfix.fills.motion_matching import FILLS, MotionMatching
from mocapfix.fills.policy import FillPolicy, apply_fill_policy
from mocapfix.io.synthetic import generate_clips
from mocapfix.models.checkpoint import fill_policy_values, load_checkpoint
from mocapfix.pretrained import pretrained_path
from mocapfix.rig.mapping import onto_skeleton

BODY = preset("body21")
GAPS = [0.1, 0.5, 0.9]


def _take(seconds: float = 4.0) -> tuple[torch.Tensor, torch.Tensor]:
    """(1, T, J, 3) float64 with a 0.5-s hole of the right leg and a 0.1-s hole of the body; observed."""
    x = onto_skeleton(generate_clips(1, seconds, 30.0, seed=2)[0], BODY).positions.astype(np.float64)
    x[40:55, list(BODY.groups["right_leg"])] = np.nan
    x[80:83] = np.nan
    x = torch.from_numpy(x)[None]
    return x, ~torch.isnan(x).any(-1)


class Refused(Fill):
    """A fill that must not run."""

    names = ("pchip",)

    def fill(self, positions, observed, fps, skeleton, asked=None, shared=None):
        raise AssertionError("a fill the policy never chooses was run")


def test_every_fill_gives_its_named_candidates_with_observed_tokens_as_given():
    x, obs = _take()
    fills = [*classical_fills(), MotionMatching(None), ModelFill(lambda p, o: torch.nan_to_num(p)), Made("m", x)]
    out = made(fills, x, obs, 30.0, BODY)
    assert list(out) == [*CLASSICAL, *FILLS, "xmae", "m"]
    for name, filled in out.items():
        assert filled.shape == x.shape, name
        assert torch.equal(filled[obs], x[obs]), name
        if name not in ("xmae", "m"):
            assert torch.isfinite(filled).all(), name


def test_fills_made_together_share_one_lerp_fill_and_give_what_each_gives_alone(monkeypatch):
    """made() hands every fill the take's Lerp fill (each classical fill asked for a few holes
    answers the others with it): each candidate is the very one the fill makes alone, asked or
    not, and the whole take's Lerp fill is made once for all of them (and once by "lerp" itself)."""
    import mocapfix.fills.classical as classical

    x, observed = _take()
    asked = ~observed & (torch.arange(x.shape[1]) < 60)[None, :, None]  # the leg's hole, not the body's
    fills = classical_fills() + [MotionMatching(None)]
    whole_takes = []
    lerp = classical.lerp_infill
    monkeypatch.setattr(classical, "lerp_infill", lambda p, o: whole_takes.append(p.shape == x.shape) or lerp(p, o))
    for ask in (None, asked):
        alone = {}
        for f in fills:
            alone.update(f.fill(x, observed, 30.0, BODY, ask))
        whole_takes.clear()
        together = made(fills, x, observed, 30.0, BODY, asked=ask)
        assert together.keys() == alone.keys()
        for name in alone:
            assert torch.equal(together[name], alone[name]), name
        assert ask is None or sum(whole_takes) == 2


def test_transform_runs_only_the_fills_it_chooses_and_counts_what_each_filled():
    """choose: limb for every arm and body hole, the mean of lerp and spline for a 0.5-s leg hole;
    PCHIP is measured but never chosen, so it is never run."""
    x, obs = _take()
    table = {m: [50.0] * 3 for m in ("lerp", "spline", "limb", "pchip")}
    leg = {**table, "lerp+spline": [50.0, 10.0, 50.0], "limb": [40.0] * 3}
    policy = FillPolicy(GAPS, {"full": dict(table, limb=[40.0] * 3), "arm": dict(table, limb=[40.0] * 3), "leg": leg})
    assert policy.choose("leg", 0.5) == "lerp+spline" and policy.choose("full", 0.1) == "limb"
    assert "pchip" in policy.methods() and "pchip" not in policy.chosen()
    fills = [Refused(), *(f for f in classical_fills() if f.names[0] != "pchip")]
    out, counts = policy.transform(x, obs, 30.0, BODY, fills)
    leg_tokens = int((~obs[0, 40:55]).sum())
    assert counts == {"lerp+spline": leg_tokens, "limb": int((~obs).sum()) - leg_tokens}
    candidates = made(classical_fills(), x, obs, 30.0, BODY)  # over the whole take; transform's fill crops
    whole = apply_fill_policy(policy, x, obs, candidates, 30.0, BODY)[0]
    assert (out - whole).norm(dim=-1).max() < 1e-5 and torch.equal(out[obs], x[obs])
    mean = 0.5 * (candidates["lerp"] + candidates["spline"])
    assert torch.allclose(out[0, 40:55][~obs[0, 40:55]], mean[0, 40:55][~obs[0, 40:55]], atol=1e-5, rtol=0)


class Asked(Fill):
    """Records the tokens it was asked for; answers with the Hermite fill."""

    names = ("match", "match_delta")

    def __init__(self):
        self.asked = None

    def fill(self, positions, observed, fps, skeleton, asked=None, shared=None):
        self.asked = asked
        out = made(classical_fills(), positions, observed, fps, skeleton, {"hermite"})["hermite"]
        return {name: out for name in self.names}


def test_transform_asks_each_fill_only_for_the_holes_it_fills():
    """The leg's 0.5-s hole takes the mean of the limb fill and match_delta, the body's 0.1-s hole
    the limb fill: motion matching is asked for the leg hole's tokens only (it searches no other
    hole), and the output is the one every fill asked for everything gives."""
    x, obs = _take()
    table = {m: [50.0] * 3 for m in ("limb", "match", "match_delta")}
    leg = {**table, "limb+match_delta": [50.0, 10.0, 50.0]}
    policy = FillPolicy(GAPS, {"full": dict(table, limb=[40.0] * 3), "arm": dict(table), "leg": leg})
    spy = Asked()
    out, counts = policy.transform(x, obs, 30.0, BODY, [*classical_fills(), spy])
    leg_hole = torch.zeros_like(obs)
    leg_hole[0, 40:55] = ~obs[0, 40:55]
    assert torch.equal(spy.asked, leg_hole)
    assert counts["limb+match_delta"] == int(leg_hole.sum())
    candidates = made([*classical_fills(), spy], x, obs, 30.0, BODY)
    assert torch.equal(out, apply_fill_policy(policy, x, obs, candidates, 30.0, BODY)[0])


def test_a_shipped_checkpoints_policy_reads_as_plain_values_and_chooses_as_it_did():
    values = fill_policy_values(load_checkpoint(pretrained_path("xmae-cpu-bandai")))
    policy = FillPolicy.from_dict(values)
    assert FillPolicy.from_dict(policy.to_dict()) == policy
    assert all(isinstance(g, float) for g in policy.to_dict()["gaps_s"])
    chosen = {policy.choose(p, g) for p in ("full", "arm", "leg") for g in policy.gaps_s}
    assert chosen == set(policy.chosen()) and chosen <= set(m for t in values["error_mm"].values() for m in t) | {
        "xmae"
    }


def test_fit_on_a_recording_takes_the_model_only_where_it_earned_it():
    """FillPolicy.fit: holes of the recording's kinds cut into it, the model (an oracle here, a
    ready Fill) measured with the classical fills; 4 s of take are too few holes to trust it."""
    x, _ = _take()
    truth = onto_skeleton(generate_clips(1, 4.0, 30.0, seed=2)[0], BODY).positions.astype(np.float64)
    val = {p: {m: [50.0] * 3 for m in ("lerp", "limb", "spline", "xmae")} for p in ("full", "arm", "leg")}
    oracle = Made("xmae", torch.from_numpy(truth)[None])
    policy, note = FillPolicy(GAPS, val).fit([(x[0].numpy(), 30.0)], BODY, oracle, holes_of=([x[0].numpy()], 30.0))
    assert note.startswith("fill policy measured on this recording") and "classical fills only" in note
    assert policy.choose("leg", 0.5) != "xmae" and policy.preferred == ("limb", 0.95)
