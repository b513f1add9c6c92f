"""Gradients that pay: a bounded capture-point margin (margin.py), diagnostics of per-push
gradients (diagnostics.py), bundled (randomised-smoothing) gradients (bundled.py), ROC AUC
(auc.py), and the first measurement's helpers (measure.py)."""
