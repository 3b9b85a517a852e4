"""Checkpointing for AD through long scans: each step of a scan is one custom Dr.Jit operation
(:class:`Checkpoint`, used as ``dr.custom(Checkpoint, fn, state, params)``) whose inputs are
stored and whose derivatives replay it (the differentiable volume caustic's photon and view
steps, :mod:`photonmap.volume.gradients`)."""

from __future__ import annotations

import drjit as dr


def _leaves(tree):
    """The arrays of a nest of tuples, depth first."""
    if isinstance(tree, tuple | list):
        return [leaf for item in tree for leaf in _leaves(item)]
    return [tree]


class Checkpoint(dr.CustomOp):
    """One step of a scan as a custom AD operation: the primal is evaluated at once; the
    derivatives replay the step from its stored (evaluated) inputs with a nested AD graph and
    evaluate them — checkpointing, so that reverse mode through hundreds of steps compiles one
    small kernel per step (which Dr.Jit's kernel cache then reuses) rather than one huge one."""

    def eval(self, fn, state, params):
        self.fn, self.state, self.params = fn, state, params
        out = fn(state, params)
        dr.eval(out)
        return out

    def _replay(self):
        state, params = dr.detach(self.state), dr.detach(self.params)
        dr.enable_grad(state, params)
        return state, params, self.fn(state, params)

    def forward(self):
        state, params, out = self._replay()
        dr.set_grad(state, self.grad_in("state"))
        dr.set_grad(params, self.grad_in("params"))
        dr.forward_to(out, flags=dr.ADFlag.ClearNone)  # outputs may be interior nodes
        grad = dr.grad(out)
        dr.eval(grad)
        self.set_grad_out(grad)

    def backward(self):
        state, params, out = self._replay()
        objective = None
        for o, g in zip(_leaves(out), _leaves(self.grad_out()), strict=True):
            term = dr.sum(o * g)
            objective = term if objective is None else objective + term
        dr.backward(objective)
        grads = dr.grad(state), dr.grad(params)
        dr.eval(grads)
        self.set_grad_in("state", grads[0])
        self.set_grad_in("params", grads[1])

    def name(self):
        return "checkpointed step"
