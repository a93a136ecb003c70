"""The most likely path through a walk's hypotheses (min-sum Viterbi), and how sure it is.

Frame ``f`` has emission costs ``e_f`` (H_f,) and between frames ``f-1`` and ``f`` transition
costs ``C_f`` (H_{f-1}, H_f). The forward pass gives ``A_f(j)``, the cost of the best path of
frames 0..f ending in pose j; the backward pass ``B_f(j)``, the best continuation from j to the
end. ``A_f(j) + B_f(j)`` is the cost of the best whole path through pose j (its min-marginal):
the chosen pose's is the path's cost, and another pose's minus it says how much the walk
prefers its choice (the frame's ``margin``, in nats).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass
class Path:
    """The best path: ``choice[f]`` the pose index of frame f, ``marginals[f]`` (H_f,) the costs of
    the best paths through each of its poses, ``cost`` the best path's."""

    choice: list[int]
    marginals: list[np.ndarray]
    cost: float


def best_path(emissions: list[np.ndarray], transition: Callable[[int], np.ndarray]) -> Path:
    """The min-cost path; ``transition(f)`` gives ``C_f`` (H_{f-1}, H_f) for f >= 1. Ties go to the
    lower pose index (poses are best-first), so the result does not depend on anything else."""
    n = len(emissions)
    if n == 0:
        return Path([], [], 0.0)
    A = [np.asarray(emissions[0], float)]
    back: list[np.ndarray] = []
    trans: list[np.ndarray] = []
    for f in range(1, n):
        C = np.asarray(transition(f), float)
        trans.append(C)
        tot = A[-1][:, None] + C
        arg = np.argmin(tot, axis=0)
        back.append(arg)
        A.append(tot[arg, np.arange(tot.shape[1])] + np.asarray(emissions[f], float))
    B = [np.zeros(len(emissions[-1]))]
    for f in range(n - 1, 0, -1):
        nxt = np.asarray(emissions[f], float) + B[0]
        B.insert(0, np.min(trans[f - 1] + nxt[None, :], axis=1))
    choice = [int(np.argmin(A[-1]))]
    for f in range(n - 2, -1, -1):
        choice.insert(0, int(back[f][choice[0]]))
    return Path(choice, [a + b for a, b in zip(A, B)], float(np.min(A[-1])))


def margin(marginals: np.ndarray, chosen: int, other: np.ndarray) -> float:
    """How much more the best path through any ``other`` pose (bool mask) costs than the chosen
    path (``inf`` when there is none)."""
    if not np.any(other):
        return float("inf")
    return float(np.min(marginals[other]) - marginals[chosen])
