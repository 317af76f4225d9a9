"""The SAC's batched MLP, forward and backward written out (agents/sac.py).

A network here is N independent MLPs (one per seed, or per seed and twin
critic) held as six tensors w1, b1, w2, b2, w3, b3 of shapes (N, fan_in,
fan_out) and (N, 1, fan_out): relu(x w1 + b1) -> relu(. w2 + b2) -> . w3 + b3,
each layer one batched matrix product (torch.baddbmm).

The backward pass is the one autograd runs for these operations, op for op
and in its order (baddbmm's gradients are bmm's with the transposed operand
and a sum over rows for the broadcast bias; relu's is threshold_backward on
its output), so its numbers are autograd's, bit for bit
(tests/unit/test_sac_grad.py checks it against torch.autograd). Written out, it
runs without a graph, into buffers allocated once: at these sizes (64 rows,
64 units) the autograd engine, the allocations and the copies it makes cost
as much as the arithmetic.
"""

from __future__ import annotations


class BatchedMlp:
    """Activations and gradient buffers of one network shape for `rows` inputs
    per MLP. forward keeps what backward needs, so a backward belongs to the
    last forward with the same parameters."""

    def __init__(self, torch, params, rows: int, backward: bool = True):
        self.torch = torch
        n, hidden, out = params[0].shape[0], params[0].shape[2], params[4].shape[2]
        self.h1 = torch.empty((n, rows, hidden))
        self.h2 = torch.empty((n, rows, hidden))
        self.out = torch.empty((n, rows, out))
        if not backward:  # forward only (acting)
            return
        self.grad_h1 = torch.empty((n, rows, hidden))
        self.grad_h2 = torch.empty((n, rows, hidden))
        self.grads = [torch.empty_like(p) for p in params]
        """Gradients of the parameters, in their order, written by backward."""

    def forward(self, params, x):
        """Outputs (N, rows, out) of x (N, rows, in); a view of a buffer the next forward overwrites."""
        torch = self.torch
        w1, b1, w2, b2, w3, b3 = params
        torch.baddbmm(b1, x, w1, out=self.h1).relu_()
        torch.baddbmm(b2, self.h1, w2, out=self.h2).relu_()
        return torch.baddbmm(b3, self.h2, w3, out=self.out)

    def backward(self, params, x, grad_out):
        """Parameter gradients (self.grads) of a loss whose gradient at the last
        forward's outputs (from x, with params) is grad_out (N, rows, out)."""
        torch, relu_grad = self.torch, self.torch.ops.aten.threshold_backward.grad_input
        w1, _, w2, _, w3, _ = params
        gw1, gb1, gw2, gb2, gw3, gb3 = self.grads
        torch.bmm(self.h2.transpose(1, 2), grad_out, out=gw3)
        torch.sum(grad_out, 1, keepdim=True, out=gb3)
        torch.bmm(grad_out, w3.transpose(1, 2), out=self.grad_h2)
        grad_z2 = relu_grad(self.grad_h2, self.h2, 0, grad_input=self.grad_h2)
        torch.bmm(self.h1.transpose(1, 2), grad_z2, out=gw2)
        torch.sum(grad_z2, 1, keepdim=True, out=gb2)
        torch.bmm(grad_z2, w2.transpose(1, 2), out=self.grad_h1)
        grad_z1 = relu_grad(self.grad_h1, self.h1, 0, grad_input=self.grad_h1)
        torch.bmm(x.transpose(1, 2), grad_z1, out=gw1)
        torch.sum(grad_z1, 1, keepdim=True, out=gb1)
        return self.grads
