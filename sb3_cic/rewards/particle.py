"""Particle-based (k-nearest-neighbour) entropy estimator of APT, shared by CIC, APT and APS."""

from __future__ import annotations

import numpy as np
import torch as th
from torch import nn

from sb3_cic.speed import speed_options


class RunningMeanStd(nn.Module):
    """Running mean and variance of a stream of batches (URLB's ``RMS``), saved in ``state_dict``.

    :param epsilon: initial pseudo-count
    :param shape: shape of one sample
    """

    def __init__(self, epsilon: float = 1e-4, shape: tuple[int, ...] = (1,)) -> None:
        super().__init__()
        self.register_buffer("mean", th.zeros(shape))
        self.register_buffer("var", th.ones(shape))
        self.register_buffer("count", th.tensor(epsilon, dtype=th.float64))

    @th.no_grad()
    def update(self, x: th.Tensor) -> None:
        """Fold the batch ``x`` (first dimension = samples) into the statistics."""
        n = x.shape[0]
        count = self.count.to(x.dtype)
        delta = x.mean(dim=0) - self.mean
        total = count + n
        self.var.copy_((self.var * count + x.var(dim=0) * n + delta.pow(2) * count * n / total) / total)
        self.mean.add_(delta * n / total)
        self.count.view(1).add_(n)  # through a view: torch.compile drops an in-place update of a 0-d float64 tensor


def knn_distances(source: th.Tensor, target: th.Tensor, k: int) -> th.Tensor:
    """Euclidean distances from each ``source`` row to its ``k`` nearest ``target`` rows, ascending.

    The neighbours are selected on squared distances from matrix products (``|a|^2 + |b|^2 - 2 a.b``) and
    ``topk`` (no ``B1 x B2 x D`` tensor); on the CPU, with ``speed_options.knn_partition``, numpy's
    ``argpartition`` selects the same neighbours faster (not while ``torch.compile`` traces it). The ``k``
    distances returned are then computed exactly from the differences to the selected rows (``B1 x k x D``):
    the expanded form's float32 rounding (up to ~1e-3 for unit vectors) would otherwise give a point a non-zero
    distance to an exact copy of itself, as URLB's broadcast ``torch.norm`` does not. When ``source`` is ``target``
    a point is its own first neighbour (distance 0), as in URLB.

    :param source: ``(B1, D)``
    :param target: ``(B2, D)``
    :param k: number of neighbours (``<= B2``)
    :return: ``(B1, k)``
    """
    sq = (source.pow(2).sum(1, keepdim=True) + target.pow(2).sum(1).unsqueeze(0)).addmm_(source, target.T, alpha=-2.0)
    if source is target:  # a point selects itself first, whatever the rounding residue of |a|^2 + |a|^2 - 2 a.a
        sq.diagonal().fill_(-1.0)
    numpy_ok = (
        sq.device.type == "cpu" and sq.dtype in (th.float32, th.float64) and not sq.requires_grad
        and not th.compiler.is_compiling()
    )
    if speed_options.knn_partition and numpy_ok and k < sq.shape[1]:
        # the same k neighbours as topk: numpy's introselect, without a sort of the whole row
        index = th.from_numpy(np.argpartition(sq.numpy(), k - 1, axis=1)[:, :k])
    else:
        index = th.topk(sq, k, dim=1, largest=False, sorted=False).indices
    distances = th.linalg.vector_norm(source.unsqueeze(1) - target[index], dim=2)
    return distances.sort(dim=1).values


#: floor of the running statistic the distances are divided by: a first batch of identical points (training
#: that starts with fewer stored transitions than neighbours) has a running mean of 0, and 0 / 0 would make the
#: reward, then the critic, NaN; with the floor its reward is 0
MIN_DIVISOR = 1e-8


class ParticleEntropy(nn.Module):
    """APT's particle entropy reward: ``log(c + x)`` of the (normalised, clipped) kNN distances.

    With ``avg=True``: ``x = mean_k(max(d_k / m - clip, 0))``, each of the k distances normalised and clipped
    before the average, as URLB's ``PBE`` and the CIC code do (a point's zero distance to itself counts 0);
    ``m`` is the running mean of the distances when ``rms=True`` (1 otherwise), which all k distances of the
    batch update. With ``avg=False`` the k-th distance alone is kept, and it alone updates the running statistics.
    The statistic is floored at :data:`MIN_DIVISOR` (URLB's would give 0 / 0 on a batch of identical points).

    :param k: number of neighbours (URLB and the CIC paper: 12)
    :param avg: average over the k neighbours (else keep the k-th)
    :param rms: divide by the running statistic of the kNN distances
    :param clip: subtracted from each normalised distance before flooring at 0 (negative: no clip, no floor)
    :param c: constant inside the log
    :param divide_by: the running statistic: "mean" (URLB, the CIC paper) or "var", the running variance that
        the CIC code divides by (its ``moving_std`` is the variance)
    :param center: subtract the running mean from each distance before dividing (MOSS's ``minus_mean``:
        ``(d_k - mean) / var``)
    """

    def __init__(
        self,
        k: int = 12,
        avg: bool = True,
        rms: bool = True,
        clip: float = 0.0005,
        c: float = 1.0,
        divide_by: str = "mean",
        center: bool = False,
    ) -> None:
        super().__init__()
        if divide_by not in ("mean", "var"):
            raise ValueError(f"divide_by must be 'mean' or 'var', got {divide_by!r}")
        self.k, self.avg, self.use_rms, self.clip, self.c, self.divide_by = k, avg, rms, clip, c, divide_by
        self.center = center
        self.rms = RunningMeanStd()

    def forward(self, source: th.Tensor, target: th.Tensor | None = None) -> th.Tensor:
        """Reward of each ``source`` row against the ``target`` particles (default: ``source``), ``(B, 1)``."""
        target = source if target is None else target
        x = knn_distances(source, target, min(self.k, target.shape[0]))
        if not self.avg:
            x = x[:, -1:]
        if self.use_rms:
            self.rms.update(x.reshape(-1, 1))
            divisor = (self.rms.mean if self.divide_by == "mean" else self.rms.var).clamp_min(MIN_DIVISOR)
            x = (x - self.rms.mean if self.center else x) / divisor
        if self.clip >= 0:
            x = th.clamp_min(x - self.clip, 0.0)
        return th.log(self.c + x.mean(dim=1, keepdim=True))
