"""Classical fills, the baselines of the test tables: Lerp (the XMAE paper's), splines through
each joint's observed frames (what capture software does: a cubic spline, or PCHIP, which does not
overshoot), a cubic Hermite that continues the motion at each end's velocity, and the limb fill
(bone lengths kept). A learned model is worth using only where it beats the best of these."""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.interpolate import CubicSpline, PchipInterpolator

from mocapfix.fills.fill import Fill
from mocapfix.fills.holes import runs


def _observed_neighbours(obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """obs: (B, T, J) bool -> t, prev, nxt (B, T, J): each token's frame, the last observed frame
    at or before it (-1 if none) and the first at or after it (T if none): running max forward,
    running min backward (numpy's on the CPU: 3x torch's cummax along a middle dimension)."""
    B, T, J = obs.shape
    t = torch.arange(T, device=obs.device).view(1, T, 1).expand(B, T, J)
    if obs.device.type == "cpu":
        o, frames = obs.numpy(), np.arange(T).reshape(1, T, 1)
        prev = np.maximum.accumulate(np.where(o, frames, -1), axis=1)
        nxt = np.minimum.accumulate(np.where(o, frames, T)[:, ::-1], axis=1)[:, ::-1]
        return t, torch.from_numpy(prev), torch.from_numpy(nxt.copy())  # copy: no negative strides
    prev = torch.where(obs, t, -1).cummax(dim=1).values
    nxt = torch.where(obs, t, T).flip(1).cummin(dim=1).values.flip(1)
    return t, prev, nxt


def lerp_infill(positions: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """Fill every unobserved token by linear interpolation in time between the nearest observed
    frames of the same joint.

    positions: (B, T, J, 3) (values at unobserved tokens are ignored, NaN allowed there)
    observed: (B, T, J) bool
    -> (B, T, J, 3), never NaN where something could be filled:
    - observed tokens are returned bit-identical (a token marked observed but holding NaN is
      treated as unobserved);
    - a gap touching the window border holds the nearest observed value;
    - a joint never observed in the window takes, at each frame, the mean of the (interpolated)
      joints that are observed somewhere in the window: a crude guess that at least stays on the
      body; 0 if no joint of the window is observed at all.
    """
    obs = observed.to(torch.bool) & ~torch.isnan(positions).any(dim=-1)
    return _lerp(positions, obs, *_observed_neighbours(obs))


def _lerp(
    positions: torch.Tensor, obs: torch.Tensor, t: torch.Tensor, prev: torch.Tensor, nxt: torch.Tensor
) -> torch.Tensor:
    """lerp_infill given its tokens' observed-ness (obs: (B, T, J) bool, NaN tokens already out)
    and _observed_neighbours(obs) (t, prev, nxt), which the Hermite shares."""
    B, T, J, _ = positions.shape
    if positions.device.type == "cpu" and bool(obs.any(dim=1).all()):
        return _lerp_missing(positions, obs, prev, nxt)
    p_val = positions.gather(1, prev.clamp(0, T - 1)[..., None].expand(B, T, J, 3))
    n_val = positions.gather(1, nxt.clamp(0, T - 1)[..., None].expand(B, T, J, 3))
    filled = _between(p_val, n_val, t, prev, nxt, T)

    # Joints with no observation in the window: per-frame mean of the joints that have one.
    seen = obs.any(dim=1, keepdim=True)  # (B, 1, J)
    zero = torch.zeros((), dtype=positions.dtype, device=positions.device)
    n_seen = seen.sum(dim=2, keepdim=True)[..., None]  # (B, 1, 1, 1)
    body_mean = torch.where(seen[..., None], filled, zero).sum(dim=2, keepdim=True) / n_seen.clamp_min(1)
    filled = torch.where(seen[..., None], filled, body_mean)

    return torch.where(obs[..., None], positions, filled)


def _between(
    p_val: torch.Tensor, n_val: torch.Tensor, t: torch.Tensor, prev: torch.Tensor, nxt: torch.Tensor, T: int
) -> torch.Tensor:
    """Tokens at frames t (...,) between the observed values p_val at frame prev and n_val at
    frame nxt (..., 3) -> (..., 3) linearly; a gap with no observed frame before (prev < 0) or
    after (nxt == T) holds the edge value."""
    span = (nxt - prev).clamp_min(1).to(p_val.dtype)
    w = (t - prev).to(p_val.dtype) / span
    w = torch.where(prev >= 0, torch.where(nxt < T, w, 0.0), 1.0)[..., None]
    # the branch not taken may hold NaN (clamped gathers of missing tokens): where() keeps it out
    return torch.where(w == 0, p_val, torch.where(w == 1, n_val, p_val + w * (n_val - p_val)))


def _lerp_missing(positions: torch.Tensor, obs: torch.Tensor, prev: torch.Tensor, nxt: torch.Tensor) -> torch.Tensor:
    """lerp_infill where every joint is observed somewhere in each window, computed at the missing
    tokens only (bit-identical: the same arithmetic on fewer tokens). On the CPU a take of `fix`
    is mostly observed, and the whole-take gathers and selections cost several milliseconds a
    call at 120 fps; on a GPU the indexing would wait for the device, so it keeps the full path.
    positions: (B, T, J, 3); obs: (B, T, J) bool; prev, nxt: _observed_neighbours(obs)'s."""
    T = positions.shape[1]
    at, f, row = _tokens(~obs)  # (M,) each
    p, n = prev.reshape(-1)[at], nxt.reshape(-1)[at]
    J, flat = obs.shape[2], positions.reshape(-1, 3)
    p_val, n_val = flat[row + p.clamp(0, T - 1) * J], flat[row + n.clamp(0, T - 1) * J]  # (M, 3)
    out = positions.clone(memory_format=torch.contiguous_format)
    out.view(-1, 3)[at] = _between(p_val, n_val, f, p, n, T)
    return out


def _tokens(mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """mask: (B, T, J) bool -> at, f, row (M,): the tokens where it is True, as indices into the
    flattened (B T J), their frames, and their joints' indices at frame 0 of their take (+ k J:
    the same joint at frame k). One flat index reads a token twice as fast as (b, t, j)."""
    _, T, J = mask.shape
    at = torch.nonzero(mask.reshape(-1)).squeeze(1)
    f = at // J % T
    return at, f, at - f * J


def hermite_infill(positions: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """Fill every unobserved token with a cubic in time that leaves the last observed frame
    before the gap at the joint's velocity there and arrives at the first observed frame after
    it at the velocity there (cubic Hermite; velocities from each end's observed neighbour, the
    gap's secant where an end has none). Near dense data this is what a cubic spline does, but it
    needs no linear solve: it runs batched on the device, inside a training step.
    Same contract as lerp_infill (observed tokens bit-identical, border gaps hold the edge value,
    joints never observed take the body's mean).

    positions: (B, T, J, 3), observed: (B, T, J) bool -> (B, T, J, 3)
    """
    obs = observed.to(torch.bool) & ~torch.isnan(positions).any(dim=-1)
    t, prev, nxt = _observed_neighbours(obs)
    lerp = _lerp(positions, obs, t, prev, nxt)  # the value at every observed and border token
    if positions.device.type == "cpu":
        return _hermite_missing(positions, obs, lerp, prev, nxt)
    return _hermite_everywhere(lerp, obs, t, prev, nxt)


def _hermite_everywhere(
    lerp: torch.Tensor, obs: torch.Tensor, t: torch.Tensor, prev: torch.Tensor, nxt: torch.Tensor
) -> torch.Tensor:
    """hermite_infill's cubic at every token, kept where a token is inside a gap (on a device:
    no indexing to wait for). lerp: (B, T, J, 3) the Lerp fill; obs: (B, T, J) bool; t, prev,
    nxt: _observed_neighbours(obs)'s -> (B, T, J, 3)."""
    B, T, J, _ = lerp.shape
    inside = (prev >= 0) & (nxt < T) & ~obs
    # the observed neighbour beyond each end of the gap: before prev, after nxt
    before = torch.cat([torch.full_like(prev[:, :1], -1), prev[:, :-1]], dim=1)  # last observed < t
    after = torch.cat([nxt[:, 1:], torch.full_like(nxt[:, :1], T)], dim=1)  # first observed > t
    pp = before.gather(1, prev.clamp(0, T - 1))  # (B, T, J)
    nn = after.gather(1, nxt.clamp(0, T - 1))

    def at(index):  # (B, T, J) frame index -> (B, T, J, 3) the lerp-filled value there
        return lerp.gather(1, index.clamp(0, T - 1)[..., None].expand(B, T, J, 3))

    cubic = _cubic(t, prev, nxt, pp, nn, at(prev), at(nxt), at(pp), at(nn), T)
    return torch.where(inside[..., None], cubic, lerp)


def _hermite_missing(
    positions: torch.Tensor, obs: torch.Tensor, lerp: torch.Tensor, prev: torch.Tensor, nxt: torch.Tensor
) -> torch.Tensor:
    """_hermite_everywhere's answer computed at the tokens inside a gap only (the same
    arithmetic, _cubic, on fewer tokens: bit-identical; on the CPU a take is mostly observed, and
    the whole-take cubic cost ~8 ms a call on a 1,100-frame take against ~1 ms for the Lerp under
    it). Every value it reads is at an observed frame, where `lerp` is the recording.
    positions, lerp: (B, T, J, 3); obs: (B, T, J) bool; prev, nxt: _observed_neighbours(obs)'s."""
    _, T, J, _ = positions.shape
    at, f, row = _tokens((prev >= 0) & (nxt < T) & ~obs)  # (M,) each: the tokens inside a gap
    if not len(at):
        return lerp
    prev, nxt = prev.reshape(-1), nxt.reshape(-1)
    p, n = prev[at], nxt[at]
    # the observed neighbour beyond each end of the gap: before p, after n
    pp = torch.where(p > 0, prev[row + (p - 1).clamp_min(0) * J], -1)
    nn = torch.where(n < T - 1, nxt[row + (n + 1).clamp_max(T - 1) * J], T)
    flat = positions.reshape(-1, 3)
    values = [flat[row + k * J] for k in (p, n, pp.clamp_min(0), nn.clamp_max(T - 1))]  # (M, 3) each
    out = lerp.clone(memory_format=torch.contiguous_format)
    out.view(-1, 3)[at] = _cubic(f, p, n, pp, nn, *values, T)
    return out


def _cubic(t, prev, nxt, pp, nn, p_val, n_val, pp_val, nn_val, T: int) -> torch.Tensor:
    """The Hermite cubic at tokens at frames t (...,) in a gap between observed frames prev and
    nxt (values p_val, n_val: (..., 3)), with each end's velocity from its observed neighbour
    beyond (frames pp, nn; values pp_val, nn_val), the gap's secant where there is none (pp < 0,
    nn == T) -> (..., 3)."""
    span = (nxt - prev).clamp_min(1).to(p_val.dtype)[..., None]  # (..., 1)
    secant = (n_val - p_val) / span
    v_p = torch.where((pp >= 0)[..., None], (p_val - pp_val) / (prev - pp).clamp_min(1)[..., None], secant)
    v_n = torch.where((nn < T)[..., None], (nn_val - n_val) / (nn - nxt).clamp_min(1)[..., None], secant)
    s = ((t - prev).to(p_val.dtype)[..., None] / span).clamp(0, 1)
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * p_val + h10 * span * v_p + h01 * n_val + h11 * span * v_n


_SPLINES = {"spline": CubicSpline, "pchip": PchipInterpolator}


def spline_infill(
    positions: torch.Tensor, observed: torch.Tensor, kind: str = "spline", only: torch.Tensor | None = None
) -> torch.Tensor:
    """Fill every unobserved token from a spline in time through the observed frames of the same
    joint: "spline" a cubic spline (scipy's CubicSpline, not-a-knot ends), "pchip" a monotone
    piecewise-cubic Hermite one. Same contract as lerp_infill, whose answer stands where a spline
    has nothing to add: gaps at the window's border hold the edge value (no extrapolation), and a
    joint seen in fewer than 3 frames of the window is interpolated linearly.

    positions: (B, T, J, 3), observed: (B, T, J) bool; only: (J,) bool, the joints whose spline
    is wanted (None: all; the others keep Lerp's answer: each spline is a scipy call) -> (B, T, J, 3)
    """
    spline = _SPLINES[kind]
    out = lerp_infill(positions, observed)
    B, T, J, _ = positions.shape
    obs = (observed.to(torch.bool) & ~torch.isnan(positions).any(dim=-1)).permute(0, 2, 1).reshape(B * J, T)
    x = out.detach().permute(0, 2, 1, 3).reshape(B * J, T, 3).cpu().double().numpy()
    obs = obs.cpu().numpy()
    t = np.arange(T)
    first, last = obs.argmax(axis=1), T - 1 - obs[:, ::-1].argmax(axis=1)  # (B*J,)
    inside = (t >= first[:, None]) & (t <= last[:, None])  # (B*J, T)
    wanted = np.ones(B * J, dtype=bool) if only is None else np.tile(only.cpu().numpy(), B)  # (B*J,)
    todo = np.flatnonzero(wanted & (obs.sum(axis=1) >= 3) & (inside & ~obs).any(axis=1))
    if todo.size == 0:
        return out
    # Sequences with the same observed frames share one spline call (vector-valued along axis 1):
    # the evaluation tasks cut the same gap into every window, so there are few patterns.
    keys = np.packbits(obs[todo], axis=1)
    keys = keys.view(np.dtype((np.void, keys.shape[1]))).reshape(-1)  # one bytes key per row
    _, first_of, which = np.unique(keys, return_index=True, return_inverse=True)
    for k, row in enumerate(first_of):
        rows = todo[which.reshape(-1) == k]
        pattern = obs[todo[row]]
        known = np.flatnonzero(pattern)
        fill = np.flatnonzero(~pattern & (t >= known[0]) & (t <= known[-1]))
        x[rows[:, None], fill] = spline(known, x[rows][:, known], axis=1)(fill)
    filled = torch.from_numpy(x).to(out).reshape(B, J, T, 3).permute(0, 2, 1, 3)
    return torch.where(observed[..., None] & ~torch.isnan(positions).any(-1, keepdim=True), positions, filled)


def bone_lengths(positions: torch.Tensor, observed: torch.Tensor, parents) -> torch.Tensor:
    """positions: (B, T, J, 3), observed: (B, T, J) -> (B, 1, C) each bone's median length over the
    frames where both its ends are observed (NaN where never), C the joints with a parent in order."""
    obs = observed.to(torch.bool) & ~torch.isnan(positions).any(dim=-1)
    p = torch.as_tensor(list(parents), device=positions.device)
    child = torch.nonzero(p >= 0).flatten()
    both = obs[:, :, child] & obs[:, :, p[child]]  # (B, T, C)
    length = torch.where(both, (positions[:, :, child] - positions[:, :, p[child]]).norm(dim=-1), torch.nan)
    return length.nanmedian(dim=1, keepdim=True).values


def limb_infill(
    positions: torch.Tensor, observed: torch.Tensor, parents, lengths: torch.Tensor | None = None
) -> torch.Tensor:
    """Fill along the skeleton, keeping bone lengths: each missing joint is its parent's (filled)
    position plus the bone vector from parent to joint, interpolated in time (cubic spline) over
    the frames where both ends are seen and scaled to the bone's median length in the window.
    The way capture software fills a marker from its rigid-body partners: a hand hole under an
    observed elbow follows the elbow. A joint whose bone is never seen whole in the window, and
    the root, are filled by the spline of their own positions.

    positions: (B, T, J, 3), observed: (B, T, J) bool, parents: (J,) with parents[j] < j;
    lengths: (B, 1, C) the bones' lengths (bone_lengths; None: measured in the window)
    -> (B, T, J, 3), observed tokens as given."""
    obs = observed.to(torch.bool) & ~torch.isnan(positions).any(dim=-1)
    p = torch.as_tensor(list(parents), device=positions.device)
    child = torch.nonzero(p >= 0).flatten()
    both = obs[:, :, child] & obs[:, :, p[child]]  # (B, T, C)
    seen = both.any(dim=1)  # (B, C) the bone has a length
    # the spline of a joint's own positions: the root's fill, and a joint's whose bone is never seen
    own_wanted = p < 0
    own_wanted[child] = ~seen.all(dim=0)
    own = spline_infill(positions, obs, only=own_wanted)
    bone = positions[:, :, child] - positions[:, :, p[child]]  # (B, T, C, 3)
    bone = spline_infill(torch.where(both[..., None], bone, torch.nan), both)
    length = bone_lengths(positions, obs, parents) if lengths is None else lengths  # (B, 1, C)
    bone = bone * (length / bone.norm(dim=-1).clamp_min(1e-9))[..., None]
    out = own.clone()
    for k, j in enumerate(child.tolist()):  # parents before children: a parent is final before its child
        along = out[:, :, parents[j]] + bone[:, :, k]
        fill = torch.where(seen[:, None, k, None], along, own[:, :, j])
        out[:, :, j] = torch.where(obs[:, :, j, None], positions[:, :, j], fill)
    return out


CLASSICAL = {
    "lerp": lambda p, o, parents: lerp_infill(p, o),
    "spline": lambda p, o, parents: spline_infill(p, o, "spline"),
    "pchip": lambda p, o, parents: spline_infill(p, o, "pchip"),
    "hermite": lambda p, o, parents: hermite_infill(p, o),
    "limb": limb_infill,
}


# A fill asked for a few holes of a take fills crops around them (CROP_FRAMES of the take each
# side), not the whole take: Lerp, the Hermite and PCHIP read two observed frames each side of a
# hole, a cubic spline's reach dies off by ~0.27 a knot (16 knots: 1e-9 of it), and the limb fill
# gets the whole take's bone lengths. Holes not asked for keep the Lerp fill (Fill's contract).
CROP_FRAMES = 16


class Classical(Fill):
    """A classical fill of CLASSICAL as a Fill (found by name when it runs: a worker of fix --jobs
    gets it pickled). Asked for some holes, it fills crops around them (CROP_FRAMES)."""

    def __init__(self, name: str):
        self.names = (name,)

    def fill(self, positions, observed, fps, skeleton, asked=None, shared=None) -> dict[str, torch.Tensor]:
        name, parents = self.names[0], skeleton.parents
        spans = None
        if asked is not None and name != "lerp":
            seen = observed.to(torch.bool) & ~torch.isnan(positions).any(dim=-1)
            spans = crop_spans(hole_frames_of(asked, seen, parents if name == "limb" else None), CROP_FRAMES)
        if spans is None or sum(e - s for _, s, e in spans) > 0.5 * asked.shape[0] * asked.shape[1]:
            return {name: CLASSICAL[name](positions, observed, parents)}  # the whole take: as cheap
        if shared is None:
            out = lerp_infill(positions, observed)
        else:
            if shared.lerp is None:
                shared.lerp = lerp_infill(positions, observed)
            out = shared.lerp.clone()
        if not spans:
            return {name: out}
        # the crops side by side, (S, W, J, 3), a shorter one padded with unobserved frames after
        # its end (a border gap for every fill: nothing inside the crop changes)
        W = max(e - s for _, s, e in spans)
        crops = positions.new_full((len(spans), W, *positions.shape[2:]), float("nan"))
        seen = torch.zeros(crops.shape[:3], dtype=torch.bool, device=observed.device)
        for k, (b, s, e) in enumerate(spans):
            crops[k, : e - s], seen[k, : e - s] = positions[b, s:e], observed[b, s:e]
        if name == "limb":
            lengths = bone_lengths(positions, observed, parents)[[b for b, _, _ in spans]]  # (S, 1, C)
            filled = limb_infill(crops, seen, parents, lengths)
        else:
            filled = CLASSICAL[name](crops, seen, parents)
        for k, (b, s, e) in enumerate(spans):
            out[b, s:e] = torch.where(asked[b, s:e, :, None], filled[k, : e - s], out[b, s:e])
        return {name: out}


def hole_frames_of(asked: torch.Tensor, seen: torch.Tensor, parents=None) -> torch.Tensor:
    """asked: (B, T, J) bool, missing tokens asked for; seen: (B, T, J) bool, the observed ones ->
    (B, T) bool: the frames of every hole an asked token is in, from the observed frame before it
    to the one after (a hole goes on past the asked frames: it is filled from its own ends).
    parents: where given, a joint's hole runs on while a joint above it misses (the limb fill
    follows the parent)."""
    missing = ~seen
    if parents is not None:
        missing = missing.clone()
        for j, parent in enumerate(parents):  # parents before children
            if parent >= 0:
                missing[..., j] |= missing[..., parent]
    _, prev, nxt = _observed_neighbours(~missing)  # (B, T, J)
    B, T, _ = asked.shape
    b = torch.arange(B, device=asked.device).view(B, 1, 1).expand_as(asked)[asked]
    # +1 where an asked token's hole starts (its observed frame before), -1 after it ends
    edges = torch.zeros(B, T + 1, dtype=torch.long, device=asked.device)
    edges.index_put_((b, prev[asked].clamp_min(0)), torch.ones_like(b), accumulate=True)
    edges.index_put_((b, nxt[asked].clamp_max(T - 1) + 1), -torch.ones_like(b), accumulate=True)
    return edges.cumsum(dim=1)[:, :T] > 0


def crop_spans(frames: torch.Tensor, context: int) -> list[tuple[int, int, int]]:
    """frames: (B, T) bool (hole_frames_of) -> (b, start, end) of each crop: a run of frames with
    `context` frames more each side, crops that overlap merged."""
    B, T = frames.shape
    spans: list[tuple[int, int, int]] = []
    for b in range(B):
        for s, e in runs(frames[b].cpu().numpy()):
            s, e = max(0, s - context), min(T, e + context)
            if spans and spans[-1][0] == b and s <= spans[-1][2]:
                spans[-1] = (b, spans[-1][1], max(e, spans[-1][2]))
            else:
                spans.append((b, s, e))
    return spans


def classical_fills() -> list[Fill]:
    """Every classical fill, in CLASSICAL's order."""
    return [Classical(name) for name in CLASSICAL]


def gaussian_smooth(positions: torch.Tensor, sigma_frames: float) -> torch.Tensor:
    """The classical answer to jitter: each joint's trajectory convolved in time with a Gaussian
    of sigma_frames frames; at the window's ends the kernel is renormalised over the frames
    inside (no padding values invented). positions: (B, T, J, 3), complete -> (B, T, J, 3)."""
    B, T, J, _ = positions.shape
    radius = max(1, int(math.ceil(3 * sigma_frames)))
    t = torch.arange(-radius, radius + 1, dtype=positions.dtype, device=positions.device)
    kernel = torch.exp(-0.5 * (t / sigma_frames) ** 2)[None, None]  # (1, 1, 2r+1)
    x = positions.permute(0, 2, 3, 1).reshape(B * J * 3, 1, T)
    num = torch.nn.functional.conv1d(x, kernel, padding=radius)
    den = torch.nn.functional.conv1d(torch.ones_like(x[:1]), kernel, padding=radius)
    return (num / den).reshape(B, J, 3, T).permute(0, 3, 1, 2)
