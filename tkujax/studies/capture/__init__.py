"""Capture-region studies (`tkujax capture`): where must the swing foot land to survive a push.

  theory.py     LIP capture point after a push, Koolen et al.'s one-step region with step time,
                theory's J_1
  region.py     empirical regions from a [step] sweep: area, centroid, overlays, controller gap
  optimize.py   gradient-optimal step targets through MJX (optax)
  figures.py    small-multiple region panels, J_1 per direction
  run.py        run_capture: sweep -> analysis -> figures -> summary.md
"""

from tkujax.studies.capture.capture_command import run_capture

__all__ = ["run_capture"]
