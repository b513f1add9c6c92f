"""ROC AUC of a score against a binary label, rank-based (Mann-Whitney U), numpy only."""

from __future__ import annotations

import numpy as np


def average_ranks(x: np.ndarray) -> np.ndarray:
    """1-based ranks of x, ties sharing their average rank."""
    x = np.asarray(x, float)
    order = np.argsort(x, kind="mergesort")
    sorted_x = x[order]
    ranks = np.empty(len(x), float)
    i = 0
    while i < len(x):
        j = i
        while j + 1 < len(x) and sorted_x[j + 1] == sorted_x[i]:
            j += 1
        ranks[order[i:j + 1]] = 0.5 * (i + j) + 1.0
        i = j + 1
    return ranks


def roc_auc(score, label) -> float:
    """P(score of a positive > score of a negative), ties counting 1/2. NaN when one class is
    empty. Scores must be finite (ValueError otherwise)."""
    score = np.asarray(score, float)
    label = np.asarray(label, bool)
    if not np.all(np.isfinite(score)):
        raise ValueError("roc_auc: non-finite scores")
    n_pos, n_neg = int(label.sum()), int((~label).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    r = average_ranks(score)
    u = r[label].sum() - n_pos * (n_pos + 1) / 2.0
    return float(u / (n_pos * n_neg))


def roc_curve(score, label) -> tuple[np.ndarray, np.ndarray]:
    """(false positive rate, true positive rate) at every threshold, from (0, 0) to (1, 1)."""
    score = np.asarray(score, float)
    label = np.asarray(label, bool)
    thresholds = np.concatenate([[np.inf], np.sort(np.unique(score))[::-1]])
    tpr = np.array([np.mean(score[label] >= t) for t in thresholds])
    fpr = np.array([np.mean(score[~label] >= t) for t in thresholds])
    return fpr, tpr
