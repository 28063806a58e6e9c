import math

import numpy as np
import pytest
import torch

from mocapfix.core.skeleton import preset
from mocapfix.evaluation.metrics import MPJPE, AccelError, JointAcceleration, LimbSigma

B, T, J = 4, 20, 17


def data(seed=0, nan_frac=0.1):
    rng = np.random.default_rng(seed)
    target = rng.normal(size=(B, T, J, 3))
    pred = target + 0.05 * rng.normal(size=(B, T, J, 3))
    target[rng.random((B, T, J)) < nan_frac] = np.nan
    target[0, 3, 0] = np.nan  # a frame whose root is missing
    mask = rng.random((B, T, J)) < 0.6
    return pred, target, mask


def t(x):
    return torch.from_numpy(np.asarray(x))


# --- direct numpy references ---


def np_mpjpe(pred, target, mask, root_relative=False, root=0):
    if root_relative:
        pred = pred - pred[:, :, root : root + 1]
        target = target - target[:, :, root : root + 1]
    d = np.linalg.norm(pred - target, axis=-1)
    keep = mask & ~np.isnan(d)
    return 1000 * d[keep].mean()


def np_second_diff(x):
    return x[:, :-2] - 2 * x[:, 1:-1] + x[:, 2:]


def np_accel_error(pred, target, mask):
    e = np.linalg.norm(np_second_diff(pred) - np_second_diff(target), axis=-1)
    keep = ~np.isnan(e) & mask[:, 1:-1]
    return 1000 * e[keep].mean()


def np_joint_accel(x, fps):
    a = np.linalg.norm(np_second_diff(x), axis=-1) * fps**2
    return a[~np.isnan(a)].mean()


def np_limb_sigma(x, limbs):
    stds = []
    for b in range(x.shape[0]):
        for a, c in limbs:
            length = np.linalg.norm(x[b, :, a] - x[b, :, c], axis=-1)
            length = length[~np.isnan(length)]
            if len(length) >= 2:
                stds.append(np.std(length))  # population std, ddof=0
    return 1000 * np.mean(stds)


@pytest.mark.parametrize("root_relative", [False, True])
def test_mpjpe_matches_numpy(root_relative):
    pred, target, mask = data()
    m = MPJPE(root_relative=root_relative)
    m.update(t(pred), t(target), t(mask))
    assert math.isclose(m.compute().item(), np_mpjpe(pred, target, mask, root_relative), rel_tol=1e-6)
    m_all = MPJPE(root_relative=root_relative)
    m_all.update(t(pred), t(target))
    assert math.isclose(m_all.compute().item(), np_mpjpe(pred, target, np.ones_like(mask), root_relative), rel_tol=1e-6)


def test_mpjpe_root_relative_root_index_and_excluded_frame():
    pred, target, _ = data(nan_frac=0.0)
    target[1, 5, 2] = np.nan
    m = MPJPE(root_relative=True, root_index=2)
    m.update(t(pred), t(target))
    # the whole frame whose root (joint 2) is missing is dropped; elsewhere only NaN tokens
    # (data() leaves target[0, 3, 0] NaN, a non-root joint for root_index=2)
    assert m.count == B * T * J - J - 1
    assert math.isclose(m.compute().item(), np_mpjpe(pred, target, np.ones((B, T, J), bool), True, 2), rel_tol=1e-6)
    # a rigid translation of the prediction costs nothing root-relative, everything globally
    shift = target + np.array([0.1, 0.0, 0.0])
    rel, glob = MPJPE(root_relative=True), MPJPE()
    rel.update(t(shift), t(target))
    glob.update(t(shift), t(target))
    assert rel.compute().item() < 1e-9 and math.isclose(glob.compute().item(), 100.0, rel_tol=1e-6)


def test_mpjpe_nothing_evaluated_is_nan_and_pred_nan_is_not_hidden():
    pred, target, mask = data()
    m = MPJPE()
    m.update(t(pred), t(target), torch.zeros(B, T, J, dtype=torch.bool))
    assert math.isnan(m.compute().item())
    pred[1, 1, 1] = np.nan
    target[1, 1, 1] = 0.0
    m = MPJPE()
    m.update(t(pred), t(target))
    assert math.isnan(m.compute().item())


def test_accel_error_matches_numpy():
    pred, target, mask = data(1)
    m = AccelError()
    m.update(t(pred), t(target), t(mask))
    assert math.isclose(m.compute().item(), np_accel_error(pred, target, mask), rel_tol=1e-6)
    m = AccelError()
    m.update(t(target), t(target))
    assert m.compute().item() == 0.0


def test_joint_acceleration_matches_numpy():
    _, target, _ = data(2)
    m = JointAcceleration(fps=30)
    m.update(t(target))
    assert math.isclose(m.compute().item(), np_joint_accel(target, 30), rel_tol=1e-6)
    # free fall sampled at 100 Hz: exactly g
    ts = np.arange(10) / 100.0
    fall = np.zeros((1, 10, 1, 3))
    fall[0, :, 0, 2] = -0.5 * 9.81 * ts**2
    m = JointAcceleration(fps=100)
    m.update(t(fall))
    assert math.isclose(m.compute().item(), 9.81, rel_tol=1e-6)


def test_limb_sigma_matches_numpy():
    _, target, _ = data(3, nan_frac=0.2)
    target[2, :, 5] = np.nan  # a joint never present: its limbs skipped in sample 2
    target[3, 1:, 7] = np.nan  # one frame only: limbs with joint 7 skipped in sample 3
    limbs = list(preset("h36m17").limbs)
    m = LimbSigma(limbs)
    m.update(t(target))
    assert math.isclose(m.compute().item(), np_limb_sigma(target, limbs), rel_tol=1e-6)
    # a rigid motion has constant limb lengths
    rigid = np.repeat(np.nan_to_num(target[:1, :1]), T, axis=1) + np.linspace(0, 1, T)[None, :, None, None]
    m = LimbSigma(limbs)
    m.update(t(rigid))
    assert m.compute().item() < 1e-6


def make_metrics():
    limbs = list(preset("h36m17").limbs)
    return [
        (lambda: MPJPE(), "pt"),
        (lambda: MPJPE(root_relative=True), "ptm"),
        (lambda: AccelError(), "ptm"),
        (lambda: JointAcceleration(50), "t"),
        (lambda: LimbSigma(limbs), "t"),
    ]


# the hand-summed instance never saw update(): torchmetrics warns, harmlessly here
@pytest.mark.filterwarnings("ignore:The ``compute`` method of metric")
@pytest.mark.parametrize("factory,args", make_metrics())
def test_two_instances_merged_equal_one_over_all_data(factory, args):
    batches = [data(s) for s in range(4)]

    def feed(m, chunk):
        for pred, target, mask in chunk:
            a = {"p": t(pred), "t": t(target), "m": t(mask)}
            m.update(*[a[k] for k in args])

    whole = factory()
    feed(whole, batches)
    # two "processes" with unequal amounts of data: a mean of means would differ
    r0, r1 = factory(), factory()
    feed(r0, batches[:1])
    feed(r1, batches[1:])
    # (compared from the states: compute() would cache r0's value across merge_state)
    assert not math.isclose(r0.total / r0.count, r1.total / r1.count, rel_tol=1e-3)
    summed = factory()
    summed.total = r0.total + r1.total  # states set by hand, as a "sum" all-reduce would
    summed.count = r0.count + r1.count
    r0.merge_state(r1)
    for m in (r0, summed):
        assert math.isclose(m.compute().item(), whole.compute().item(), rel_tol=1e-6)


def test_states_reduce_with_sum():
    m = MPJPE()
    assert m._reductions["total"].__name__ in ("dim_zero_sum", "sum")
    assert m._reductions["count"].__name__ in ("dim_zero_sum", "sum")


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_metrics_on_cuda():
    pred, target, mask = data()
    m = MPJPE().cuda()
    m.update(t(pred).cuda(), t(target).cuda(), t(mask).cuda())
    assert math.isclose(m.compute().item(), np_mpjpe(pred, target, mask), rel_tol=1e-6)
