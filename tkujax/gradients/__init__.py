"""Gradients of a fall: a bounded capture-point margin (margin.py), diagnostics of per-push
gradients (diagnostics.py), bundled (randomised-smoothing) gradients (bundled.py) and ROC AUC
(auc.py). The first measurement's study is tkujax.studies.gradient_measure."""
