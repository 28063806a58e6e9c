"""A stack (fills/fill.py STACK): the Hermite fill plus a model's and motion matching's steps from
it, each weighted as the recording's cut holes say, measured with weights fitted on the other
takes' holes and taken by the policy where it wins, as any candidate with a model in it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mocapfix.core.skeleton import preset
from mocapfix.fills import errors
from mocapfix.fills.classical import CLASSICAL, classical_fills
from mocapfix.fills.errors import ErrorSums, _stack_errors
from mocapfix.fills.fill import Fill, components, stacked
from mocapfix.fills.policy import TRUSTED_HOLES, FillPolicy, is_learned
from mocapfix.io.synthetic import generate_clips
from mocapfix.rig.mapping import onto_skeleton

BODY = preset("body21")
GAPS = [0.1, 0.3, 0.5, 0.7, 0.9]
SLIP = torch.tensor([0.03, -0.02, 0.01], dtype=torch.float64)  # metres: an error the two make in opposite ways


def test_a_stack_is_made_of_the_hermite_fill_and_its_steps_and_counts_as_learned():
    assert components("correction*match_delta") == ["hermite", "correction", "match_delta"]
    assert is_learned("correction*match_delta") and not is_learned("limb+spline")
    origin, a, b = torch.zeros(2, 3), torch.ones(2, 3), -torch.ones(2, 3)
    w = torch.tensor([[0.5, 0.25], [1.0, 0.0]])  # (tokens, steps)
    assert torch.allclose(stacked(origin, [a, b], w), torch.tensor([[0.25] * 3, [1.0] * 3]))


def test_stack_weights_are_held_out_by_group_and_fitted_on_all():
    """Each group's tokens are scored with the weights the other groups give: a group whose
    truth follows other weights than the rest is scored worse than in-sample fitting would."""
    rng = np.random.default_rng(0)
    steps = rng.normal(size=(600, 2, 3))  # (M, K, 3)
    target = 0.7 * steps[:, 0] + 0.4 * steps[:, 1]
    group = np.repeat(np.arange(6), 100)
    err, w = _stack_errors(steps, target, group)
    assert np.allclose(w, [0.7, 0.4], atol=1e-4) and err.max() < 1e-4
    odd = target.copy()
    odd[group == 5] = 2.0 * steps[group == 5, 0]  # one group follows other weights
    err, pooled = _stack_errors(steps, odd, group)
    in_sample = np.linalg.norm(odd - np.einsum("mkc,k->mc", steps, pooled), axis=-1)
    five = group == 5  # scored with the others' weights (0.7, 0.4), not the pooled ones
    assert np.allclose(err[five], np.linalg.norm(odd[five] - target[five], axis=-1), atol=1e-4)
    assert err[five].mean() > 1.1 * in_sample[five].mean()
    # one group: nothing to hold out, its tokens scored with the weights fitted on them
    err, w = _stack_errors(steps, target, np.zeros(600, dtype=int))
    assert np.allclose(w, [0.7, 0.4], atol=1e-4)


def _truth_of(takes, x: torch.Tensor, o: torch.Tensor) -> torch.Tensor:
    """The take whose observed tokens these are (the fills below know the truth)."""
    return torch.from_numpy(next(t for t, _ in takes if len(t) == len(x) and np.allclose(t[o.numpy()], x[o].numpy())))


class _Steps(Fill):
    """A model (xmae) and motion matching (match, match_delta) that each step from the Hermite
    fill by a share of the way to the truth, and slip: the model 1.5 x the way plus SLIP, match_delta
    by -1.5 x SLIP. Neither alone nor their mean is exact; the Hermite fill plus 2/3 of the
    model's step and 4/9 of match_delta's is."""

    def __init__(self, takes, names):
        self.takes, self.names = takes, names

    def fill(self, positions, observed, fps, skeleton, asked=None, shared=None):
        hermite = CLASSICAL["hermite"](positions, observed, skeleton.parents)
        truth = torch.stack([_truth_of(self.takes, x, o) for x, o in zip(positions, observed)])
        if "xmae" in self.names:
            return {"xmae": hermite + 1.5 * (truth - hermite) + SLIP}
        return {"match": truth + 0.05, "match_delta": hermite - 1.5 * SLIP}


@pytest.fixture
def stepped(monkeypatch):
    takes = [(onto_skeleton(c, BODY).positions.astype(np.float64), 30.0) for c in generate_clips(4, 30.0, 30.0, seed=3)]
    model, match = _Steps(takes, ("xmae",)), _Steps(takes, ("match", "match_delta"))
    monkeypatch.setattr(errors, "take_fills", lambda library, key, model_fill: [*classical_fills(), match, model_fill])
    return takes, model, match


def test_the_policy_takes_a_stack_that_wins_on_the_cut_holes_and_fills_with_its_weights(stepped):
    takes, model, match = stepped
    x = takes[0][0].copy()
    x[100:127] = np.nan  # a 0.9-s full-body hole of its own
    val = {p: {m: [50.0] * 5 for m in ("lerp", "limb", "spline", "pchip", "xmae")} for p in ("full", "arm", "leg")}
    policy, note = FillPolicy(GAPS, val, None).fit(takes, BODY, model, holes_of=([x], 30.0))
    assert int(note.split("(")[1].split(" holes")[0]) >= TRUSTED_HOLES
    assert policy.choose("full", 0.9) == "xmae*match_delta"
    assert policy.error_mm["full"]["xmae*match_delta"][-1] < 1e-3  # mm: exact, held out by take
    assert min(policy.error_mm["full"][m][-1] for m in ("xmae", "match_delta", "match_delta+xmae")) > 5
    assert policy.stacks["full"]["xmae*match_delta"][-1] == pytest.approx([2 / 3, 4 / 9], abs=1e-4)
    # transform: the hole filled as the weights say, the stack counted as what filled it
    assert FillPolicy.from_dict(policy.to_dict()).stacks == policy.stacks
    xt, ot = torch.from_numpy(x)[None], torch.from_numpy(np.isfinite(x).all(-1))[None]
    out, counts = policy.transform(xt, ot, 30.0, BODY, [*classical_fills(), match, model])
    truth = torch.from_numpy(takes[0][0])
    assert torch.allclose(out[0, 100:127], truth[100:127], atol=1e-6)
    assert counts == {"xmae*match_delta": 27 * BODY.num_joints}


def test_a_stack_whose_fill_was_screened_out_of_a_kind_has_no_numbers_there():
    e = ErrorSums([0.5])
    truth = torch.zeros(1, 20, 3, 3, dtype=torch.float64)
    scored = torch.zeros(1, 20, 3, dtype=torch.bool)
    scored[0, 5:10] = True
    hole_of = torch.ones(1, 20, 3, dtype=torch.long)
    fills = {"hermite": truth + 0.02, "correction": truth + 0.01, "match_delta": truth - 0.01, "limb": truth}
    e.add_fills("full", 0.5, fills, truth, scored, hole_of, "a")
    e.add_fills("full", 0.5, fills, truth, scored, hole_of, "b")
    e.settle_stacks()
    assert len(e.holes[("full", 0.5, "correction*match_delta")]) == 2
    e.drop("full", 0.5, ["match_delta", "correction*match_delta"])
    e.add_fills("full", 0.5, {k: v for k, v in fills.items() if k != "match_delta"}, truth, scored, hole_of, "c")
    e.settle_stacks()
    assert ("full", 0.5, "correction*match_delta") not in e.sums and not e.stack_weights
