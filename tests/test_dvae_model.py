"""Motion-DVAE networks and losses on a tiny model: the ELBO terms against a direct computation
(step-by-step recurrences, torch.distributions, explicit FK), causality of the generative model,
the inverse-gamma KL and expectations of the denoising ELBO."""

from __future__ import annotations

import shutil

import pytest
import torch
from torch.distributions import Gamma, InverseGamma, Normal, kl_divergence

from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.io.synthetic import generate_clips
from mocapfix.models.dvae import inverse_gamma_kl
from mocapfix.models.dvae_state import velocity_mask
from mocapfix.training.denoise_module import DVAEDenoiseModule
from mocapfix.training.dvae_module import MotionDVAEModule

T = 6  # frames per window: x_0 and x_1..x_5


def _batch(B=3, seed=2):
    clips = generate_clips(B, 1.0, 30.0, seed=seed)
    s = slice(4, 4 + T)
    return {
        "positions": torch.stack([torch.from_numpy(c.positions[s]) for c in clips]),
        "rotations": torch.stack([torch.from_numpy(c.rotations[s]) for c in clips]),
        "root_translation": torch.stack([torch.from_numpy(c.root_translation[s]) for c in clips]),
        "offsets": torch.stack([torch.from_numpy(c.offsets) for c in clips]),
    }, clips[0].skeleton


def _tiny(skeleton, **kw) -> MotionDVAEModule:
    torch.manual_seed(0)
    m = MotionDVAEModule(
        latent_dim=4,
        lstm_hidden=16,
        mlp_hidden=16,
        norm_groups=4,
        skeleton=skeleton.to_dict(),
        window_fps=30.0,
        window_frames=T,
        **kw,
    )
    D = m.codec.dim
    m.net.x_mean.copy_(torch.randn(D) * 0.1)  # non-trivial standardisation, so the test sees it
    m.net.x_std.copy_(torch.rand(D) + 0.5)
    return m


def _lstm_step(lstm: torch.nn.LSTM, x, h, c):
    out, (h, c) = lstm(x[:, None], (h[None], c[None]))
    return h[0], c[0]


def test_prior_elbo_terms_match_a_direct_computation():
    batch, skel = _batch()
    m = _tiny(skel)
    g, e = m.net.gen, m.net.enc
    with torch.no_grad():
        x, shape = m.encode_batch(batch)
        terms, x_hat, out = m.elbo_terms(x, shape, sample=False)
        xn = (x - m.net.x_mean) / m.net.x_std
        xe = xn * (~velocity_mask("rotations", skel.num_joints)).float()  # the encoder reads the poses only
        B = x.shape[0]
        # inference model, one step at a time: backward data LSTM, then the latent recursion
        h, c = torch.zeros(B, 16), torch.zeros(B, 16)
        h_data = [None] * (T - 1)
        for t in reversed(range(T - 1)):
            h, c = _lstm_step(e.e_data, xe[:, 1 + t], h, c)
            h_data[t] = h
        h, c = e.e_ini(xe[:, 0])
        q_mu, q_logvar = [], []
        for t in range(T - 1):
            mu, logvar = e.e_glob(torch.cat([h, h_data[t]], -1)).chunk(2, -1)
            q_mu.append(mu), q_logvar.append(logvar)
            h, c = e.e_lat(mu, (h, c))
        q_mu, q_logvar = torch.stack(q_mu, 1), torch.stack(q_logvar, 1)
        # generative model: p(z_t | z_<t, x_0) from h_{t-1}, x_t from h_t
        h, c = g.d_ini(xn[:, 0])
        p_mu, p_logvar, xs = [], [], []
        for t in range(T - 1):
            mu, logvar = g.d_z(h).chunk(2, -1)
            p_mu.append(mu), p_logvar.append(logvar)
            h, c = _lstm_step(g.lstm, q_mu[:, t], h, c)
            xs.append(g.d_x(h))
        p_mu, p_logvar, xs = torch.stack(p_mu, 1), torch.stack(p_logvar, 1), torch.stack(xs, 1)
        torch.testing.assert_close(out.q_mu, q_mu, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(out.p_mu, p_mu, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(out.x_hat, xs, atol=1e-5, rtol=1e-5)

        rec = ((xs - xn[:, 1:]) ** 2).sum() / B
        kl = kl_divergence(Normal(q_mu, (0.5 * q_logvar).exp()), Normal(p_mu, (0.5 * p_logvar).exp())).sum() / B
        raw = xs * m.net.x_std + m.net.x_mean
        J = skel.num_joints

        def fk(s):  # [r, r_dot, phi, phi_dot, Theta, Theta_dot] -> joints
            theta = s[..., 12 : 12 + 3 * (J - 1)].reshape(B, T - 1, J - 1, 3)
            rot = torch.cat([s[..., None, 6:9], theta], -2)
            return fk_axis_angle(rot, s[..., 0:3], batch["offsets"][:, None], skel.parents)

        reg = ((fk(raw) - fk(x[:, 1:])) ** 2).sum() / B
    torch.testing.assert_close(terms.rec, rec, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(terms.kl, kl, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(terms.reg, reg, rtol=1e-4, atol=1e-6)
    assert terms.kl > 0 and terms.reg > 0
    # the clean joints the regulariser compares with are the data's own positions (canonical frame)
    truth = m.codec.points(x, shape).joints
    dist = (truth[:, 1:] - truth[:, :1]).norm(dim=-1)
    want = (batch["positions"][:, 1:] - batch["positions"][:, :1]).norm(dim=-1)
    torch.testing.assert_close(dist, want, atol=1e-5, rtol=1e-5)


def test_generative_model_is_causal():
    batch, skel = _batch(B=2)
    m = _tiny(skel)
    with torch.no_grad():
        x, _ = m.encode_batch(batch)
        x0 = m.net.normalize(x)[:, 0]
        z = torch.randn(2, T - 1, 4)
        x_hat, p_mu, _, _ = m.net.gen(x0, z)
        z2 = z.clone()
        z2[:, 2] += 1.0  # z_3
        x_hat2, p_mu2, _, _ = m.net.gen(x0, z2)
    assert torch.equal(x_hat[:, :2], x_hat2[:, :2]) and not torch.allclose(x_hat[:, 2:], x_hat2[:, 2:])
    assert torch.equal(p_mu[:, :3], p_mu2[:, :3]) and not torch.allclose(p_mu[:, 3:], p_mu2[:, 3:])


def test_inverse_gamma_kl_matches_torch_distributions():
    a = torch.tensor([0.7, 2.0, 5.0, 40.0])
    b = torch.tensor([1.3, 0.4, 6.0, 35.0])
    for lam in (2.0, 10.0, 200.0):
        prior = torch.tensor(lam / 2, dtype=torch.float64)
        want = kl_divergence(Gamma(a.double(), b.double()), Gamma(prior, prior))
        torch.testing.assert_close(inverse_gamma_kl(a, b, lam / 2, lam / 2), want)  # 1/v ~ Gamma: same KL
    # the Gaussian setting: a huge lambda, float64 keeps the small difference
    c = 5e5
    kl = inverse_gamma_kl(torch.tensor([c, c * 1.01]), torch.tensor([c, c]), c, c)
    assert kl[0].abs() < 1e-6 and 0 < kl[1] < 1e3


def test_denoising_data_term_is_the_expectation_over_the_noise_posterior():
    batch, skel = _batch(B=2)
    prior = _tiny(skel)
    torch.manual_seed(1)
    dm = DVAEDenoiseModule(prior_hparams=dict(prior.hparams), noise_lambda=4.0, obs_scale_m=0.1)
    # the predictors start where they should: x_0 at the observation, v at the prior (KL 0)
    noisy = dm.add_noise(batch, 0.1, torch.Generator().manual_seed(0))
    obs = dm.observation(noisy)
    with torch.no_grad():
        inf = dm.infer(obs, sample=False)
        y, _ = dm.codec.encode(obs.positions, obs.rotations, obs.root_translation)
        # x_0 starts at the observed pose with mean (standardised 0) velocities
        yn0 = dm.net.normalize(y)[:, 0]
        vel = velocity_mask("rotations", skel.num_joints)
        torch.testing.assert_close(inf.x0_mu[:, ~vel], yn0[:, ~vel])
        assert torch.equal(inf.x0_mu[:, vel], torch.zeros_like(yn0[:, vel]))
        assert dm.elbo_terms(inf)["kl_v"].abs() < 1e-6
        torch.nn.init.normal_(dm.noise_pred.e_b.net[-1].bias, std=0.5)  # move q(v) off the prior
        inf = dm.infer(obs, sample=False)
        terms = dm.elbo_terms(inf)
        alpha, beta = 2.0 * inf.a.exp(), 2.0 * inf.b.exp()
        sq = (((inf.y3d - inf.m) / 0.1) ** 2).flatten(-2)
        v = InverseGamma(alpha.double(), beta.double()).sample((4000,)).float()  # (S, B, T, 3K)
        mc = 0.5 * (sq / v + v.log()).mean(0).sum() / 2
    assert abs(float(terms["data"]) - float(mc)) < 0.02 * abs(float(mc))
    assert terms["kl_v"] > 0 and terms["kl_z"] > 0


def test_gaussian_setting_is_the_exact_large_lambda_limit():
    """From lambda = 1e4 on, v = 1 exactly: the data term is half the squared error, kl_v is 0,
    and the noise predictor gets no gradient (at lambda = 1e6 the IG terms gave it gradients of
    order lambda, which reached the encoder through the shared LSTM states)."""
    batch, skel = _batch(B=2)
    prior = _tiny(skel)
    torch.manual_seed(1)
    big = DVAEDenoiseModule(prior_hparams=dict(prior.hparams), noise_lambda=1e6, obs_scale_m=0.1)
    obs = big.observation(big.add_noise(batch, 0.1, torch.Generator().manual_seed(0)))
    torch.nn.init.normal_(big.noise_pred.e_b.net[-1].bias, std=0.5)  # a noise predictor off the prior
    loss, terms = big.denoise_loss(obs, 1.0, sample=False)
    inf = big.infer(obs, sample=False)
    sq = (((inf.y3d - inf.m) / 0.1) ** 2).flatten(-2)
    torch.testing.assert_close(terms["data"], 0.5 * sq.sum((1, 2)).mean(), rtol=1e-5, atol=0)
    assert terms["kl_v"] == 0
    loss.backward()
    assert all(p.grad is None for p in big.noise_pred.parameters())
    assert not any(p.requires_grad for p in big.noise_pred.parameters())  # out of the optimiser (and DDP)
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in big.net.parameters())
    # the noise-model formula tends to it: with q(v) at the prior, lambda = 5e3 is within 0.1 %
    near = DVAEDenoiseModule(prior_hparams=dict(prior.hparams), noise_lambda=5e3, obs_scale_m=0.1)
    near.load_state_dict(big.state_dict())
    torch.nn.init.zeros_(near.noise_pred.e_b.net[-1].bias)
    with torch.no_grad():
        near_terms = near.elbo_terms(near.infer(obs, sample=False))
    torch.testing.assert_close(near_terms["data"], terms["data"].detach(), rtol=1e-3, atol=0)


def _velocity_noise(xn: torch.Tensor, vel: torch.Tensor, scale: float = 30.0) -> torch.Tensor:
    """xn with its velocity entries moved by `scale` standard deviations (noisy finite differences)."""
    g = torch.Generator().manual_seed(3)
    return xn + scale * torch.randn(xn.shape, generator=g) * vel.float()


def test_encoder_and_initial_state_predictor_read_poses_only():
    """Issue 4: Gaussian noise of 0.1 rad on the joint rotations puts the finite-difference
    velocities of the observed state 10-40 data standard deviations off. An encoder that reads
    them starts the denoising stage far outside its training distribution (its estimate was
    worse than the noisy input). The encoder and q_omega read the poses; the decoder still
    outputs the whole state."""
    batch, skel = _batch()
    m = _tiny(skel)
    vel = velocity_mask("rotations", skel.num_joints)
    torch.testing.assert_close(m.net.enc_keep, (~vel).float())
    with torch.no_grad():
        x, _ = m.encode_batch(batch)
        xn = m.net.normalize(x)
        noisy = _velocity_noise(xn, vel)
        out = m.net(xn[:, 0], xn[:, 1:], sample=False)
        out2 = m.net(noisy[:, 0], noisy[:, 1:], sample=False)
        torch.testing.assert_close(out2.q_mu, out.q_mu)
        # the decoder starts from the whole x_0 (d_ini), so with the same x_0 the same motion
        torch.testing.assert_close(m.net(xn[:, 0], noisy[:, 1:], sample=False).x_hat, out.x_hat)
        assert out.x_hat.shape[-1] == m.codec.dim  # the decoder still gives poses and velocities
        # ... and so does the initial-state predictor of the denoising stage
        dn = DVAEDenoiseModule(prior_hparams=dict(m.hparams), noise_lambda=4.0)
        torch.nn.init.normal_(dn.x0_pred.e_ini.net[-1].weight, std=0.1)  # a predictor that reads its input
        mu, logvar = dn.x0_pred(xn)
        mu2, logvar2 = dn.x0_pred(noisy)
        torch.testing.assert_close(mu2, mu)
        torch.testing.assert_close(logvar2, logvar)
        # a pose change does reach both
        moved = xn + 0.5 * (~vel).float()
        assert not torch.allclose(m.net(moved[:, 0], moved[:, 1:], sample=False).q_mu, out.q_mu)
        assert not torch.allclose(dn.x0_pred(moved)[0], mu)


def test_encoder_velocities_option_and_old_checkpoints_read_the_whole_state():
    batch, skel = _batch()
    m = _tiny(skel, encoder_velocities=True)
    assert torch.equal(m.net.enc_keep, torch.ones(m.codec.dim))
    with torch.no_grad():
        xn = m.net.normalize(m.encode_batch(batch)[0])
        noisy = _velocity_noise(xn, velocity_mask("rotations", skel.num_joints))
        assert not torch.allclose(
            m.net(noisy[:, 0], noisy[:, 1:], sample=False).q_mu, m.net(xn[:, 0], xn[:, 1:], sample=False).q_mu
        )
    # a state dict saved before enc_keep existed loads as an encoder reading everything
    old = {k: v for k, v in _tiny(skel).net.state_dict().items() if k != "enc_keep"}
    fresh = _tiny(skel).net
    fresh.load_state_dict(old)
    assert torch.equal(fresh.enc_keep, torch.ones(m.codec.dim))


def test_estimate_is_in_the_world_frame_and_starts_at_the_observed_pose():
    """The denoised estimate goes back from the window's canonical frame to the world: on a
    clean observation its first frame (x_0 = the observed pose) is the data's, and its error is
    the same as the canonical-frame error of the decoded points."""
    from mocapfix.models.dvae_state import to_canonical

    batch, skel = _batch()
    turn = torch.tensor([0.0, 0.0, 1.2])  # a heading and an xy offset the canonical frame takes away
    import roma

    R = roma.rotvec_to_rotmat(turn)
    batch["positions"] = batch["positions"] @ R.T + torch.tensor([3.0, -2.0, 0.0])
    batch["root_translation"] = batch["root_translation"] @ R.T + torch.tensor([3.0, -2.0, 0.0])
    root = roma.rotvec_to_rotmat(batch["rotations"][:, :, 0])
    batch["rotations"][:, :, 0] = roma.rotmat_to_rotvec(R @ root)
    prior = _tiny(skel)
    dn = DVAEDenoiseModule(prior_hparams=dict(prior.hparams), first_frame="predicted")  # the paper's x_0
    dn.load_state_dict(prior.state_dict(), strict=False)
    clean = dict(batch, noisy_positions=batch["positions"], noisy_rotations=batch["rotations"])
    with torch.no_grad():
        obs = dn.observation(clean)
        est = dn.estimate(obs)
        inf = dn.infer(obs, sample=False)
    truth = batch["positions"].float()
    torch.testing.assert_close(est[:, 0], truth[:, 0], atol=1e-4, rtol=0)
    torch.testing.assert_close(inf.y3d, to_canonical(truth, inf.canon), atol=1e-4, rtol=0)
    world = (est - truth).norm(dim=-1).mean()
    canonical = (inf.m - to_canonical(truth, inf.canon)).norm(dim=-1).mean()
    torch.testing.assert_close(world, canonical, atol=1e-5, rtol=1e-4)
    assert world > 1e-3  # an untrained decoder: the comparison is not between zeros


@pytest.mark.slow
@pytest.mark.skipif(not (shutil.which("cc") or shutil.which("gcc")), reason="torch.compile on CPU needs a C compiler")
def test_compiled_prior_gives_the_eager_elbo_and_gradients_and_the_same_checkpoint_names():
    batch, skel = _batch()
    eager, compiled = _tiny(skel), _tiny(skel, compile_model=True)
    assert compiled.net._compiled_call_impl is not None and eager.net._compiled_call_impl is None
    assert list(eager.state_dict()) == list(compiled.state_dict())
    compiled.load_state_dict(eager.state_dict())  # a checkpoint of either loads into the other
    results = []
    for m in (eager, compiled):
        x, shape = m.encode_batch(batch)
        terms, _, _ = m.elbo_terms(x, shape, sample=False)  # the posterior-mean path: no random draws to match
        loss = terms.rec + terms.kl + terms.reg
        loss.backward()
        results.append((loss.detach(), m.net.enc.e_glob.net[0].weight.grad.clone()))
    torch.testing.assert_close(results[0][0], results[1][0], atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(results[0][1], results[1][1], atol=1e-4, rtol=1e-3)
