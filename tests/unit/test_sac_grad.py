"""The SAC's hand-written gradients (agents/batched_mlp.py, BatchedSAC.update)
are autograd's: the same update with torch.autograd on the same sampled
batches leaves every weight, Adam moment and temperature bit for bit equal."""

import dataclasses

import numpy as np
import pytest

from truav.config import Config

torch = pytest.importorskip("torch")


def autograd_update(sac) -> None:
    """BatchedSAC.update as losses and torch.autograd (its form before the gradients were written out)."""
    s, s2, _, _, r, a = sac._sample()
    params = sac.actor + sac.critic + [sac.log_alpha]
    for p in params:
        p.requires_grad_(True)
    try:
        alpha = sac.log_alpha.detach().exp()[:, None, None, None]
        with torch.no_grad():
            logp2, p2 = sac._policy(s2)
            q2 = torch.min(*sac._q(sac.target, s2))
            y = r + sac.discount * (p2 * (q2 - alpha * logp2)).sum(-1)
        q = sac._q(sac.critic, s).gather(-1, a[None, ..., None].expand(2, -1, -1, -1, 1))[..., 0]
        critic_loss = ((q - y[None]) ** 2).mean(dim=(2, 3)).sum()
        grads = torch.autograd.grad(critic_loss, sac.critic)
        with torch.no_grad():
            sac.critic_opt.step(list(grads))
        logp, p = sac._policy(s)
        with torch.no_grad():
            qmin = torch.min(*sac._q(sac.critic, s))
        actor_loss = (p * (alpha * logp - qmin)).sum(-1).mean(dim=(1, 2)).sum()
        grads = torch.autograd.grad(actor_loss, sac.actor)
        with torch.no_grad():
            sac.actor_opt.step(list(grads))
        entropy = -(p.detach() * logp.detach()).sum(-1).mean(dim=(1, 2))
        (grad,) = torch.autograd.grad((sac.log_alpha * (entropy - sac.target_entropy)).sum(), [sac.log_alpha])
        with torch.no_grad():
            sac.alpha_opt.step([grad])
            torch._foreach_mul_(sac.target, 1.0 - sac.cfg.tau)
            torch._foreach_add_(sac.target, sac.critic, alpha=sac.cfg.tau)
    finally:
        for p in params:
            p.requires_grad_(False)


@pytest.mark.parametrize("hidden,batch,seeds,obs_dim,n_uavs", [(8, 8, 3, 6, 3), (64, 64, 2, 40, 5)])
def test_written_out_gradients_are_autograds_bit_for_bit(hidden, batch, seeds, obs_dim, n_uavs):
    from agents.sac import BatchedSAC
    cfg = dataclasses.replace(Config().central, hidden=hidden, batch_size=batch, buffer_size=500)
    pair = [BatchedSAC(cfg, 0.9, obs_dim, n_uavs, 16, [np.random.default_rng(s) for s in range(seeds)])
            for _ in range(2)]
    data = np.random.default_rng(7)

    def store(n):
        for _ in range(n):
            args = (data.normal(size=(seeds, obs_dim)), data.integers(0, 16, (seeds, n_uavs)),
                    data.normal(size=(seeds, n_uavs)), data.normal(size=(seeds, obs_dim)))
            for sac in pair:
                sac.store(*args)

    store(50)
    for step in range(30):
        pair[0].update()
        autograd_update(pair[1])
        store(1)
    fast, ref = (sac.state_dict() for sac in pair)
    assert fast.keys() == ref.keys()
    for key in fast:
        np.testing.assert_array_equal(fast[key], ref[key], err_msg=key)
    moments = [(o.actor_opt, o.critic_opt, o.alpha_opt) for o in pair]
    for mine, theirs in zip(*moments):
        for x, y in zip(mine.exp_avg + mine.exp_avg_sq, theirs.exp_avg + theirs.exp_avg_sq):
            assert torch.equal(x, y)
    for x, y in zip(pair[0].target, pair[1].target):
        assert torch.equal(x, y)
    assert not np.array_equal(fast["actor0"], BatchedSAC(cfg, 0.9, obs_dim, n_uavs, 16,
                              [np.random.default_rng(s) for s in range(seeds)]).state_dict()["actor0"])  # it learned
