"""The SAC update's element-wise steps and copies as numba kernels (agents/sac.py).

Each kernel does, in one pass over numpy views of the update's buffers, what
a chain of small torch operations did: the same float32 operations on the
same operands in the same order (products, sums and differences of two
float32 numbers are exactly rounded, whoever computes them; numba without
fastmath contracts nothing into fused multiply-adds), so the numbers are
torch's, bit for bit. Reductions (sums over actions), exp and log stay in
torch: their order and their approximations are torch's own. What this saves
is dispatch, temporaries and passes over memory: at these sizes (10 seeds x
64 x 5 x 16) a torch operation costs more in overhead than in arithmetic.

One kernel fuses: Polyak averaging, where torch's add with alpha is a fused
multiply-add (its vectorized fmadd) on CPUs with FMA; `polyak_is_torchs`
checks that on the running machine before BatchedSAC uses it.

Scalars are passed as np.float32 and literals written as float32, so nothing
is promoted to float64.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
from numba import njit, types
from numba.extending import intrinsic


@njit(cache=True)
def _min(a, b):
    """torch.minimum's choice: the second operand unless a < b, NaN if either is."""
    if a != a or b != b:
        return a + b
    return a if a < b else b


@njit(cache=True)
def store_rows(replay, rows, s, s_next, r, a):
    """replay[rows[b]] = s[b] | s_next[b] | r[b] | a[b], each cast to float32."""
    D, U = s.shape[1], r.shape[1]
    for b in range(rows.shape[0]):
        row = replay[rows[b]]
        for i in range(D):
            row[i] = np.float32(s[b, i])
            row[D + i] = np.float32(s_next[b, i])
        for u in range(U):
            row[2 * D + u] = np.float32(r[b, u])
            row[2 * D + U + u] = np.float32(a[b, u])


@njit(cache=True)
def gather_batch(replay, first_row, idx, s, s2, x, x2, r, a):
    """A sampled batch from the replay's rows first_row[b] + idx[b, m]:
    s, s2 (B, M, D); x, x2 (2B, M, D): s, s2 once per twin critic (rows 2b, 2b+1);
    r (B, M, U) float32 and a (B, M, U) int64."""
    B, M = idx.shape
    D, U = s.shape[2], r.shape[2]
    W = replay.shape[1]
    # The rows are scattered over the replay (cache misses): touch each cache line of each row first, independent
    # loads the CPU overlaps, then copy from cache.
    touched = np.float32(0.0)
    for b in range(B):
        for m in range(M):
            row = replay[first_row[b] + idx[b, m]]
            for i in range(0, W, 16):
                touched += row[i]
            touched += row[W - 1]
    for b in range(B):
        for m in range(M):
            row = replay[first_row[b] + idx[b, m]]
            for i in range(D):
                v, v2 = row[i], row[D + i]
                s[b, m, i] = v
                x[2 * b, m, i] = v
                x[2 * b + 1, m, i] = v
                s2[b, m, i] = v2
                x2[2 * b, m, i] = v2
                x2[2 * b + 1, m, i] = v2
            for u in range(U):
                r[b, m, u] = row[2 * D + u]
                a[b, m, u] = np.int64(row[2 * D + U + u])
    return touched


@njit(cache=True)
def soft_value_terms(p2, logp2, q2, alpha, out):
    """out = p2 * (min(q2[:, 0], q2[:, 1]) - alpha * logp2), alpha (B,) per seed;
    p2, logp2, out (B, M, U, A), q2 (B, 2, M, U, A)."""
    B, M, U, A = p2.shape
    for b in range(B):
        al = alpha[b]
        for m in range(M):
            for u in range(U):
                for k in range(A):
                    out[b, m, u, k] = p2[b, m, u, k] * (_min(q2[b, 0, m, u, k], q2[b, 1, m, u, k])
                                                        - al * logp2[b, m, u, k])


@njit(cache=True)
def critic_output_grad(q_all, a, r, v2, discount, mean_grad, y, grad):
    """y = r + discount * v2 (B, M, U); grad (B, 2, M, U, A), zero beforehand,
    gets 0 + (2 (q - y)) * mean_grad at each critic's taken action
    (q = q_all[b, c, m, u, a[b, m, u]]), as scatter_add_ into zeros would."""
    B, _, M, U, _ = q_all.shape
    two, zero = np.float32(2.0), np.float32(0.0)
    for b in range(B):
        for m in range(M):
            for u in range(U):
                yv = r[b, m, u] + discount * v2[b, m, u]
                y[b, m, u] = yv
                k = a[b, m, u]
                for c in range(2):
                    grad[b, c, m, u, k] = zero + (two * (q_all[b, c, m, u, k] - yv)) * mean_grad


@njit(cache=True)
def clear_taken(grad, a):
    """Reset grad[b, c, m, u, a[b, m, u]] to zero (what critic_output_grad wrote)."""
    B, _, M, U, _ = grad.shape
    for b in range(B):
        for m in range(M):
            for u in range(U):
                k = a[b, m, u]
                grad[b, 0, m, u, k] = 0.0
                grad[b, 1, m, u, k] = 0.0


@njit(cache=True)
def actor_logp_grad(logp, p, qn, alpha, mean_grad, grad_logp, p_logp):
    """With z = alpha * logp - min(qn[:, 0], qn[:, 1]):
    grad_logp = (z * mean_grad) * p + (p * mean_grad) * alpha, and p_logp = p * logp
    (the entropy's terms); all (B, M, U, A) but qn (B, 2, M, U, A)."""
    B, M, U, A = p.shape
    for b in range(B):
        al = alpha[b]
        for m in range(M):
            for u in range(U):
                for k in range(A):
                    lp, pv = logp[b, m, u, k], p[b, m, u, k]
                    z = al * lp - _min(qn[b, 0, m, u, k], qn[b, 1, m, u, k])
                    grad_logp[b, m, u, k] = (z * mean_grad) * pv + (pv * mean_grad) * al
                    p_logp[b, m, u, k] = pv * lp


@njit(cache=True)
def sample_actions(p, u, out):
    """Inverse-CDF draws: out[b, i] = #{a: cdf[a] < u[b, i] * cdf[-1]} (at most A - 1),
    cdf the running sum of p[b, i] (float64, summed in order as np.cumsum)."""
    B, U, A = p.shape
    for b in range(B):
        for i in range(U):
            total = 0.0
            for k in range(A):
                total += p[b, i, k]
            cut = u[b, i] * total
            acc, n = 0.0, 0
            for k in range(A):
                acc += p[b, i, k]
                if acc < cut:
                    n += 1
            out[b, i] = min(n, A - 1)


@intrinsic
def _fma32(typingctx, a, b, c):
    """a * b + c rounded once (LLVM's fma, float32)."""
    sig = types.float32(types.float32, types.float32, types.float32)

    def codegen(context, builder, signature, args):
        f = ir.FloatType()
        return builder.call(builder.module.declare_intrinsic("llvm.fma", [f], ir.FunctionType(f, [f, f, f])), args)
    return sig, codegen


@njit(cache=True)
def polyak(target, online, keep, tau):
    """target = fma(online, tau, target * keep) over flat float32 arrays: torch's
    target.mul_(keep) then target.add_(online, alpha=tau), in one pass."""
    for i in range(target.size):
        target[i] = _fma32(online[i], tau, target[i] * keep)


def polyak_is_torchs(torch, keep: float, tau: float) -> bool:
    """Whether `polyak` gives torch's foreach numbers on this machine (torch's add
    is fused only where the CPU has FMA), on seeded samples with a ragged tail."""
    rng = np.random.default_rng(0)
    target, online = (torch.from_numpy(rng.normal(size=4133).astype(np.float32)) for _ in range(2))
    mine = target.numpy().copy()
    polyak(mine, online.numpy(), np.float32(keep), np.float32(tau))
    torch._foreach_mul_([target], keep)
    torch._foreach_add_([target], [online], alpha=tau)
    return bool(np.array_equal(mine, target.numpy()))
