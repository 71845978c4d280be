"""Adam with a cosine learning-rate schedule, written out for the NODE learners.

The same floats as ``torch.optim.Adam`` (its single-tensor update, the one it runs on CPU) stepped
with ``torch.optim.lr_scheduler.CosineAnnealingLR`` (its recursive form), without torch.optim:
constructing the first torch optimiser in a process imports ``torch._dynamo``, which costs seconds
of CPU time, a large part of a NODE training of a few seconds. The tests check the two against
each other, bit for bit.

References
----------
Kingma, D. P., Ba, J. (2015). Adam: a method for stochastic optimization. ICLR. arXiv:1412.6980
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import torch


class Adam:
    """Adam on ``params`` with L2 ``weight_decay`` (added to the gradient, as torch's ``Adam``),
    its learning rate annealed from ``lr`` to ``lr_final`` over ``t_max`` steps by the cosine rule

        lr_k = lr_final + (lr_{k-1} - lr_final) (1 + cos(pi k / t_max)) / (1 + cos(pi (k - 1) / t_max)),

    (``CosineAnnealingLR``'s recursive form; ``t_max`` 0: a constant ``lr``). ``step`` applies one
    update with the current rate and then advances the schedule, as ``opt.step(); sched.step()``.
    """

    def __init__(self, params: Iterable[torch.Tensor], lr: float, lr_final: float | None = None,
                 t_max: int = 0, weight_decay: float = 0.0, betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8) -> None:
        self.params = list(params)
        self.lr = self.lr_initial = float(lr)
        self.lr_final = self.lr if lr_final is None else float(lr_final)
        self.t_max = int(t_max)
        self.weight_decay = float(weight_decay)
        self.beta1, self.beta2 = betas
        self.eps = eps
        self.steps = 0           # updates done
        self.epoch = 0           # schedule steps done
        self.exp_avg = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self.exp_avg_sq = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]

    def zero_grad(self) -> None:
        """Drop every parameter's gradient (``set_to_none``)."""
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One Adam update of every parameter that has a gradient, then one schedule step."""
        self.steps += 1
        step = float(self.steps)
        bias1, bias2 = 1 - self.beta1 ** step, 1 - self.beta2 ** step
        step_size, bias2_sqrt = self.lr / bias1, bias2 ** 0.5
        for p, m, v in zip(self.params, self.exp_avg, self.exp_avg_sq):
            if p.grad is None:
                continue
            grad = p.grad if self.weight_decay == 0 else p.grad.add(p, alpha=self.weight_decay)
            m.lerp_(grad, 1 - self.beta1)
            v.mul_(self.beta2).addcmul_(grad, grad, value=1 - self.beta2)
            p.addcdiv_(m, (v.sqrt() / bias2_sqrt).add_(self.eps), value=-step_size)
        if self.t_max > 0:
            self.epoch += 1
            k, t = self.epoch, self.t_max
            if (k - 1 - t) % (2 * t) == 0:
                self.lr += (self.lr_initial - self.lr_final) * (1 - math.cos(math.pi / t)) / 2
            else:
                self.lr = ((1 + math.cos(math.pi * k / t)) / (1 + math.cos(math.pi * (k - 1) / t))
                           * (self.lr - self.lr_final) + self.lr_final)
